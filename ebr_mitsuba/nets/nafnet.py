"""NAFNet-style encoder–decoder: the backbone of every EBREnv network (``docs/conventions.md``, "Pipeline").

A U-shaped stack of *NAF blocks* (Chen et al. 2022, "Simple Baselines for Image Restoration"):
no nonlinear activation functions, only LayerNorm, convolutions and a multiplicative gate.

One NAF block on a ``c``-channel feature map ``x``::

    y = x + β · conv1x1( SCA( SimpleGate( dwconv3x3( conv1x1_{c→2c}( LN(x) ) ) ) ) )
    z = y + γ · conv1x1( SimpleGate( conv1x1_{c→2c}( LN(y) ) ) )

* ``SimpleGate(a ‖ b) = a ⊙ b`` (split the channels in halves and multiply);
* ``SCA(u) = u ⊙ conv1x1(mean_{H,W}(u))`` — simplified channel attention;
* ``LN`` normalises each pixel's channel vector (:class:`LayerNorm2d`);
* ``β, γ`` are per-channel residual scales initialised to **zero**: every block is the identity at
  initialisation, so a deep stack starts as the shallow intro→ending path and trains stably.

The network: ``conv3x3(in→w)``; per level ``enc_blk_nums[i]`` blocks then a stride-2 2×2 conv
doubling the channels; ``middle_blk_num`` blocks; per level a 1×1 conv + pixel shuffle halving the
channels and doubling the resolution, a skip *addition*, ``dec_blk_nums[i]`` blocks;
``conv3x3(w→out)``. Inputs of any size are padded (edge replication) to a multiple of
``2^levels`` and the output is cropped back, so ``(B, C_in, H, W) → (B, C_out, H, W)`` for every
``H, W ≥ 1``. The output is unconstrained; the caller applies the output activation.

Sizes (:class:`NAFNetSize`):

================  =====  ==============  ======  ==============  ===========
preset            width  enc_blk_nums    middle  dec_blk_nums    parameters*
================  =====  ==============  ======  ==============  ===========
``TINY_SIZE``     4      (1, 1, 1, 1)    1       (1, 1, 1, 1)    76 106
``SMALL_SIZE``    8      (1, 1, 1, 1)    1       (1, 1, 1, 1)    291 150
``MEDIUM_SIZE``   16     (1, 1, 2, 2)    2       (1, 1, 1, 1)    1 754 966
``PAPER_SIZE``    36     (2, 2, 4, 8)    12      (2, 2, 2, 2)    36 861 090
================  =====  ==============  ======  ==============  ===========

\\* for 6 input and 6 output channels; see :func:`parameter_count`.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import ConfigError, InputError
from ..typedconfig import check, config, nested, option


@config
class NAFNetSize:
    """How big a :class:`NAFNet` is (:data:`SIZE_PRESETS` names ``paper`` and ``small``)."""

    width: int = option(36, "channels at full resolution", minimum=1)
    enc_blk_nums: tuple[int, ...] = option(
        (2, 2, 4, 8),
        "NAF blocks per encoder level (one level per entry; each level halves the resolution)",
        minimum=0,
    )
    middle_blk_num: int = option(12, "NAF blocks at the coarsest resolution", minimum=0)
    dec_blk_nums: tuple[int, ...] = option(
        (2, 2, 2, 2), "NAF blocks per decoder level (coarse → fine)", minimum=0
    )

    def __post_init__(self):
        check(self)
        if len(self.enc_blk_nums) != len(self.dec_blk_nums):
            raise ConfigError(
                f"NAFNetSize: enc_blk_nums {self.enc_blk_nums} and dec_blk_nums "
                f"{self.dec_blk_nums} must have the same length (one entry per level)"
            )

    @property
    def levels(self) -> int:
        """Number of resolution halvings; inputs are padded to a multiple of ``2**levels``."""
        return len(self.enc_blk_nums)

    @classmethod
    def from_value(cls, value, where: str = "size") -> NAFNetSize:
        """A preset name (``"paper"``, ``"small"``), a table of fields, or a ``NAFNetSize``."""
        return nested(cls, value, SIZE_PRESETS, where=where, what="network size")


PAPER_SIZE = NAFNetSize(width=36, enc_blk_nums=(2, 2, 4, 8), middle_blk_num=12, dec_blk_nums=(2, 2, 2, 2))
SMALL_SIZE = NAFNetSize(width=8, enc_blk_nums=(1, 1, 1, 1), middle_blk_num=1, dec_blk_nums=(1, 1, 1, 1))
TINY_SIZE = NAFNetSize(width=4, enc_blk_nums=(1, 1, 1, 1), middle_blk_num=1, dec_blk_nums=(1, 1, 1, 1))
MEDIUM_SIZE = NAFNetSize(width=16, enc_blk_nums=(1, 1, 2, 2), middle_blk_num=2, dec_blk_nums=(1, 1, 1, 1))
# the points of the size curve (``ebr bench sizes``, docs/bench/sizes.md), smallest first
SIZE_PRESETS = {"tiny": TINY_SIZE, "small": SMALL_SIZE, "medium": MEDIUM_SIZE, "paper": PAPER_SIZE}


class LayerNorm2d(nn.Module):
    """LayerNorm over the channels of each pixel: ``(x − mean_c) / sqrt(var_c + eps) · w + b``.

    Shape: ``(B, C, H, W) → (B, C, H, W)``.
    """

    def __init__(self, channels: int, eps: float = 1e-6):
        super().__init__()
        self.eps = eps
        self.weight = nn.Parameter(torch.ones(channels))
        self.bias = nn.Parameter(torch.zeros(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mean = x.mean(dim=1, keepdim=True)
        centred = x - mean
        var = centred.square().mean(dim=1, keepdim=True)
        y = centred * torch.rsqrt(var + self.eps)
        return y * self.weight[None, :, None, None] + self.bias[None, :, None, None]


class SimpleGate(nn.Module):
    """Split the channels in two halves and multiply them: ``(B, 2C, H, W) → (B, C, H, W)``."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        a, b = x.chunk(2, dim=1)
        return a * b


class SimplifiedChannelAttention(nn.Module):
    """``u ⊙ conv1x1(global_average_pool(u))``; shape ``(B, C, H, W) → (B, C, H, W)``."""

    def __init__(self, channels: int):
        super().__init__()
        self.proj = nn.Conv2d(channels, channels, 1)

    def forward(self, u: torch.Tensor) -> torch.Tensor:
        return u * self.proj(u.mean(dim=(2, 3), keepdim=True))


class NAFBlock(nn.Module):
    """One NAF block (see the module docstring); identity at initialisation (β = γ = 0)."""

    def __init__(self, channels: int, expand: int = 2):
        super().__init__()
        inner = channels * expand
        self.norm1 = LayerNorm2d(channels)
        self.expand = nn.Conv2d(channels, inner, 1)
        self.depthwise = nn.Conv2d(inner, inner, 3, padding=1, groups=inner)
        self.gate = SimpleGate()
        self.attention = SimplifiedChannelAttention(inner // 2)
        self.project = nn.Conv2d(inner // 2, channels, 1)
        self.norm2 = LayerNorm2d(channels)
        self.ffn_in = nn.Conv2d(channels, inner, 1)
        self.ffn_out = nn.Conv2d(inner // 2, channels, 1)
        self.beta = nn.Parameter(torch.zeros(1, channels, 1, 1))
        self.gamma = nn.Parameter(torch.zeros(1, channels, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.project(self.attention(self.gate(self.depthwise(self.expand(self.norm1(x))))))
        y = x + self.beta * h
        h = self.ffn_out(self.gate(self.ffn_in(self.norm2(y))))
        return y + self.gamma * h


def _blocks(channels: int, count: int) -> nn.Sequential:
    return nn.Sequential(*[NAFBlock(channels) for _ in range(count)])


class NAFNet(nn.Module):
    """NAFNet encoder–decoder ``(B, in_channels, H, W) → (B, out_channels, H, W)`` (raw outputs).

    ``size`` is a :class:`NAFNetSize` (``PAPER_SIZE``, ``SMALL_SIZE`` or custom).
    """

    def __init__(self, in_channels: int, out_channels: int, size: NAFNetSize = PAPER_SIZE):
        super().__init__()
        if in_channels < 1 or out_channels < 1:
            raise ConfigError(f"NAFNet: channel counts must be positive, got {in_channels} → {out_channels}")
        self.in_channels = in_channels
        self.out_channels = out_channels
        self.size = size
        width = size.width
        self.intro = nn.Conv2d(in_channels, width, 3, padding=1)
        self.encoders = nn.ModuleList()
        self.downs = nn.ModuleList()
        c = width
        for count in size.enc_blk_nums:
            self.encoders.append(_blocks(c, count))
            self.downs.append(nn.Conv2d(c, 2 * c, 2, stride=2))
            c *= 2
        self.middle = _blocks(c, size.middle_blk_num)
        self.ups = nn.ModuleList()
        self.decoders = nn.ModuleList()
        for count in size.dec_blk_nums:
            self.ups.append(nn.Sequential(nn.Conv2d(c, 2 * c, 1, bias=False), nn.PixelShuffle(2)))
            c //= 2
            self.decoders.append(_blocks(c, count))
        self.ending = nn.Conv2d(width, out_channels, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim != 4 or x.shape[1] != self.in_channels:
            raise InputError(
                f"NAFNet: input has shape {tuple(x.shape)}; expected (B, {self.in_channels}, H, W)"
            )
        height, width = x.shape[-2:]
        multiple = 2**self.size.levels
        pad_h = (-height) % multiple
        pad_w = (-width) % multiple
        if pad_h or pad_w:
            x = F.pad(x, (0, pad_w, 0, pad_h), mode="replicate")
        h = self.intro(x)
        skips = []
        for encoder, down in zip(self.encoders, self.downs):
            h = encoder(h)
            skips.append(h)
            h = down(h)
        h = self.middle(h)
        for up, decoder, skip in zip(self.ups, self.decoders, reversed(skips)):
            h = decoder(up(h) + skip)
        return self.ending(h)[..., :height, :width]


def parameter_count(module: nn.Module) -> int:
    """Number of trainable scalars in ``module``."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)
