"""A faster inference forward of :class:`ebr_mitsuba.nets.nafnet.NAFNet` for large images (CPU).

:class:`FastNAFNet` computes what ``NAFNet.forward`` computes (eval mode, no gradients; tested
against it in ``tests/test_fullres.py`` to 1e-4 relative), arranged for images of megapixels:

* **channels-last** (B, H, W, C) activations: every 1×1 convolution is one GEMM over the pixels
  (``F.linear`` / ``torch.baddbmm``), the 3×3 depthwise and the strided convolutions run on
  channels-last tensors (oneDNN's fast path; on NCHW tensors with 8–16 channels the same
  convolutions were 4× slower on the 2-core CPU of the estimate bench);
* **folded affine maps**: each LayerNorm's scale and shift is folded into the 1×1 convolution that
  follows it, the residual scales β, γ into the convolution before them, and the simplified
  channel attention (a per-image channel scale) into the projection after it;
* **fused residuals**: the projections write ``x + W·h`` in one GEMM (``baddbmm``), and each
  decoder level adds its pixel-shuffled up-projection into the encoder's skip tensor in place
  (the up-projection's rows reordered so that the shuffle is a strided view, not a copy).

* **LayerNorm as two GEMVs**: the channel mean and variance of each pixel as matrix–vector
  products with ``1/C`` (:func:`_layer_norm_cl`; ``F.layer_norm`` over 8 channels-last channels
  took 76 ms per megapixel on one core, this 59 ms).

A NAF block then makes about 11 passes over its activations instead of about 25. The numbers
are in docs/bench/estimate.md (time per stage, FLOPs per megapixel against this CPU's peak).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ..nets.nafnet import NAFBlock, NAFNet


def _layer_norm_cl(x: torch.Tensor, eps: float) -> torch.Tensor:
    """``F.layer_norm(x, (C,), eps=eps)`` without scale and shift for a contiguous (…, C) tensor:
    ``(x − mean) / sqrt(var + eps)``, the mean and the (biased) variance as GEMVs over the pixels;
    the same values to float32 rounding (tested against ``F.layer_norm``)."""
    c = x.shape[-1]
    rows = x.reshape(-1, c)
    inv_c = torch.full((c,), 1.0 / c, dtype=x.dtype)
    centred = rows - torch.mv(rows, inv_c)[:, None]
    var = torch.mv(centred * centred, inv_c)
    return centred.mul_(var.add_(eps).rsqrt_()[:, None]).view(x.shape)


def _linear_weights(conv: torch.nn.Conv2d) -> tuple[torch.Tensor, torch.Tensor]:
    """A 1×1 convolution as (C_out, C_in) weight and (C_out,) bias (zeros without bias)."""
    w = conv.weight.detach()[:, :, 0, 0].float()
    b = conv.bias.detach().float() if conv.bias is not None else torch.zeros(w.shape[0], dtype=w.dtype)
    return w, b


class _Block:
    """The folded weights of one :class:`NAFBlock` (see the module docstring)."""

    def __init__(self, block: NAFBlock):
        g1, b1 = block.norm1.weight.detach().float(), block.norm1.bias.detach().float()
        w, b = _linear_weights(block.expand)
        self.expand_w, self.expand_b = (w * g1[None, :]).contiguous(), b + w @ b1
        self.eps1, self.eps2 = block.norm1.eps, block.norm2.eps
        self.dw_w = block.depthwise.weight.detach().float()
        self.dw_b = block.depthwise.bias.detach().float()
        self.sca_w, self.sca_b = _linear_weights(block.attention.proj)
        beta = block.beta.detach().float().reshape(-1)
        w, b = _linear_weights(block.project)
        self.project_w, self.project_b = beta[:, None] * w, beta * b
        g2, b2 = block.norm2.weight.detach().float(), block.norm2.bias.detach().float()
        w, b = _linear_weights(block.ffn_in)
        self.ffn_in_w, self.ffn_in_b = (w * g2[None, :]).contiguous(), b + w @ b2
        gamma = block.gamma.detach().float().reshape(-1)
        w, b = _linear_weights(block.ffn_out)
        self.ffn_out_wt, self.ffn_out_b = (gamma[:, None] * w).t().contiguous(), gamma * b
        self.channels = int(g1.numel())

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """(B, H, W, C) contiguous → (B, H, W, C); ``x`` is overwritten (it is the block's input,
        used by nothing else: the residual additions are in-place GEMMs)."""
        bsz, h, w, c = x.shape
        t = F.linear(_layer_norm_cl(x, self.eps1), self.expand_w, self.expand_b)
        t = F.conv2d(t.permute(0, 3, 1, 2), self.dw_w, self.dw_b, padding=1, groups=2 * c)
        t = t.permute(0, 2, 3, 1)  # channels-last storage: a contiguous (B, H, W, 2C) view
        g = t[..., :c] * t[..., c:]
        del t
        scale = F.linear(g.mean(dim=(1, 2)), self.sca_w, self.sca_b)  # (B, C) channel attention
        weight = (self.project_w[None] * scale[:, None, :]).transpose(1, 2)  # (B, C_in, C_out)
        y = x.view(bsz, h * w, c).baddbmm_(g.view(bsz, h * w, c), weight)
        y = y.add_(self.project_b).view(bsz, h, w, c)
        t = F.linear(_layer_norm_cl(y, self.eps2), self.ffn_in_w, self.ffn_in_b)
        g = t[..., :c] * t[..., c:]
        del t
        y.view(-1, c).addmm_(g.view(-1, c), self.ffn_out_wt)
        return y.add_(self.ffn_out_b)


def _conv_cl(x: torch.Tensor, conv: torch.nn.Conv2d) -> torch.Tensor:
    """A spatial convolution of a (B, H, W, C) tensor, returned as (B, H', W', C')."""
    y = F.conv2d(
        x.permute(0, 3, 1, 2),
        conv.weight.detach().float(),
        None if conv.bias is None else conv.bias.detach().float(),
        stride=conv.stride,
        padding=conv.padding,
    )
    return y.permute(0, 2, 3, 1).contiguous()


def _shuffle_rows(up_w: torch.Tensor) -> torch.Tensor:
    """The (4C, C_in) up-projection's rows from PixelShuffle order (c·4 + 2i + j) to (i, j, c)
    order ((2i + j)·C + c), for :func:`_add_shuffled`."""
    c = up_w.shape[0] // 4
    return up_w.reshape(c, 2, 2, -1).permute(1, 2, 0, 3).reshape(4 * c, -1).contiguous()


def _add_shuffled(skip: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """``skip + PixelShuffle(2)(y)`` written into ``skip`` (B, 2H, 2W, C), ``y`` (B, H, W, 4C) in
    the (i, j, c) channel order of :func:`_shuffle_rows`: one strided pass, no shuffled copy."""
    b, h, w, c4 = y.shape
    c = c4 // 4
    skip.view(b, h, 2, w, 2, c).add_(y.view(b, h, w, 2, 2, c).permute(0, 1, 3, 2, 4, 5))
    return skip


class FastNAFNet(torch.nn.Module):
    """``FastNAFNet(net)(x)`` = ``net(x)`` for a :class:`NAFNet` in eval mode, faster on large
    images. Shape: (B, C_in, H, W) → (B, C_out, H, W), any H, W ≥ 1 (padded like the module).
    The weights are folded copies taken at construction (build it after loading the weights)."""

    def __init__(self, net: NAFNet, on_call=None):
        super().__init__()
        if not isinstance(net, NAFNet):
            raise TypeError(f"FastNAFNet needs a NAFNet, got {type(net).__name__}")
        self.net = [net]  # a list: not registered as a submodule
        self.on_call = on_call
        self.encoders = [[_Block(b) for b in enc] for enc in net.encoders]
        self.middle = [_Block(b) for b in net.middle]
        self.decoders = [[_Block(b) for b in dec] for dec in net.decoders]
        self.ups = [_shuffle_rows(_linear_weights(up[0])[0]) for up in net.ups]

    @torch.no_grad()
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        net = self.net[0]
        if x.ndim != 4 or x.shape[1] != net.in_channels:
            raise ValueError(
                f"FastNAFNet: input has shape {tuple(x.shape)}; expected (B, {net.in_channels}, H, W)"
            )
        height, width = x.shape[-2:]
        multiple = 2**net.size.levels
        pad_h, pad_w = (-height) % multiple, (-width) % multiple
        if pad_h or pad_w:
            x = F.pad(x, (0, pad_w, 0, pad_h), mode="replicate")
        h = _conv_cl(x.float().contiguous(memory_format=torch.channels_last).permute(0, 2, 3, 1), net.intro)
        skips = []
        for blocks, down in zip(self.encoders, net.downs):
            for block in blocks:
                h = block(h)
            skips.append(h)
            h = _conv_cl(h, down)
        for block in self.middle:
            h = block(h)
        for up_w, blocks, skip in zip(self.ups, self.decoders, reversed(skips)):
            h = _add_shuffled(skip, F.linear(h, up_w))  # the skip is used once: overwritten
            for block in blocks:
                h = block(h)
        out = _conv_cl(h, net.ending)
        if self.on_call is not None:
            self.on_call()
        return out.permute(0, 3, 1, 2)[..., :height, :width].contiguous()


CASCADE_NETS = ("diffuse_net", "specular_net", "joint_net", "refinement_net")


def fast_cascade(cascade, on_call=None):
    """A view of an :class:`ebr_mitsuba.nets.ebrenv.Cascade` whose NAFNets run through
    :class:`FastNAFNet` (same weights, same ``forward``; the original is not changed).
    ``on_call()``: called after each network pass (progress)."""
    import copy

    view = copy.copy(cascade)
    view._modules = dict(cascade._modules)
    for name in CASCADE_NETS:
        net = view._modules.get(name)
        if isinstance(net, NAFNet):
            view._modules[name] = FastNAFNet(net, on_call)
    return view


def cascade_passes(cascade) -> int:
    """How many NAFNet passes one cascade forward makes (the progress steps of a pass)."""
    return sum(isinstance(getattr(cascade, n, None), NAFNet) for n in CASCADE_NETS)


def multiply_adds(net: torch.nn.Module, x: torch.Tensor) -> int:
    """Multiply-adds of the convolutions and linear layers of one ``net(x)`` forward, counted
    with forward hooks (``C_out · C_in/groups · k_h · k_w`` per output pixel for a convolution,
    ``in · out`` per row for a linear layer); elementwise work is not counted."""
    total = [0]

    def conv_hook(module, inputs, output):
        kh, kw = module.kernel_size
        per_out = module.in_channels // module.groups * kh * kw
        total[0] += int(output.numel()) * per_out

    def linear_hook(module, inputs, output):
        total[0] += int(output.numel()) * module.in_features

    handles = []
    for m in net.modules():
        if isinstance(m, torch.nn.Conv2d):
            handles.append(m.register_forward_hook(conv_hook))
        elif isinstance(m, torch.nn.Linear):
            handles.append(m.register_forward_hook(linear_hook))
    try:
        with torch.no_grad():
            net(x)
    finally:
        for hnd in handles:
            hnd.remove()
    return total[0]


__all__ = ["CASCADE_NETS", "FastNAFNet", "cascade_passes", "fast_cascade", "multiply_adds"]
