"""MVANet: fusion of per-view, per-pixel tokens across the views (attention, or the mean-pool ablation).

Tokens are ``(M, N, D)`` inside (M = B·H·W pixels, N views); :class:`MVANet` takes and returns image
layout. Every block and pooling treats the views alike, so permuting the views permutes
``MVAOutput.per_view`` and leaves ``pooled`` and ``fused`` unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from ..errors import InputError
from .mair_config import FUSIONS
from .mair_views import normalised_weights


def mlp_layers(sizes: list[int]) -> nn.Sequential:
    """``Linear → GELU → … → Linear`` through the widths ``sizes`` (no activation at the end)."""
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(nn.GELU())
    return nn.Sequential(*layers)


class AttentionBlock(nn.Module):
    """Pre-LayerNorm transformer block across the views of each pixel: tokens ``(M, N, D)``.

    ``x + β·proj(softmax(q kᵀ/√d + log w) v)``, then ``x + γ·MLP(LN(x))``; the log-weight bias
    on the keys makes a view of weight 0 invisible and uniform weights neutral; β, γ start at 0.
    """

    def __init__(self, dim: int, heads: int, mlp: int):
        super().__init__()
        self.heads = heads
        self.norm1 = nn.LayerNorm(dim)
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)
        self.norm2 = nn.LayerNorm(dim)
        self.mlp = mlp_layers([dim, mlp, dim])
        self.beta = nn.Parameter(torch.zeros(dim))
        self.gamma = nn.Parameter(torch.zeros(dim))

    def forward(self, x: torch.Tensor, log_w: torch.Tensor) -> torch.Tensor:
        m, n, d = x.shape
        q, k, v = self.qkv(self.norm1(x)).reshape(m, n, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        logits = q @ k.transpose(-1, -2) * (d // self.heads) ** -0.5 + log_w[:, None, None, :]
        o = (torch.softmax(logits, dim=-1) @ v).transpose(1, 2).reshape(m, n, d)
        x = x + self.beta * self.proj(o)
        return x + self.gamma * self.mlp(self.norm2(x))


class MLPBlock(nn.Module):
    """``x + γ·MLP(LN(x))`` per token (no exchange between views): the mean-pooling ablation."""

    def __init__(self, dim: int, mlp: int):
        super().__init__()
        self.norm = nn.LayerNorm(dim)
        self.mlp = mlp_layers([dim, mlp, dim])
        self.gamma = nn.Parameter(torch.zeros(dim))

    def forward(self, x: torch.Tensor, log_w: torch.Tensor) -> torch.Tensor:
        return x + self.gamma * self.mlp(self.norm(x))


class AttentionPool(nn.Module):
    """A learned query per head attends over the N view tokens: ``(M, N, D) → (M, D)``."""

    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.query = nn.Parameter(torch.randn(heads, dim // heads) * (dim // heads) ** -0.5)
        self.norm = nn.LayerNorm(dim)
        self.kv = nn.Linear(dim, 2 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor, log_w: torch.Tensor) -> torch.Tensor:
        m, n, d = x.shape
        k, v = self.kv(self.norm(x)).reshape(m, n, 2, self.heads, d // self.heads).unbind(dim=2)
        logits = torch.einsum("hc,mnhc->mhn", self.query, k) * (d // self.heads) ** -0.5 + log_w[:, None]
        pooled = torch.einsum("mhn,mnhc->mhc", torch.softmax(logits, dim=-1), v)
        return self.proj(pooled.reshape(m, d))


@dataclass
class MVAOutput:
    """What :class:`MVANet` returns: ``per_view`` (B, N, D, H, W) tokens after the blocks (permuted
    with the views); ``pooled`` (B, D, H, W) and ``fused`` (B, F_b, H, W), invariant to their order."""

    per_view: torch.Tensor
    pooled: torch.Tensor
    fused: torch.Tensor


class MVANet(nn.Module):
    """Multi-view attention fusion of per-view, per-pixel tokens.

    ===========  =================  =========================================================
    argument     shape              meaning
    ===========  =================  =========================================================
    tokens       (B, N, C, H, W)    per-view features of each pixel (in :class:`MAIRModel`:
                                    log view 3, SpecNet features F_s, v 3, n 3)
    weights      (B, N, 1, H, W)    per-view weights w ≥ 0, or None (uniform)
    → output     MVAOutput          per-view tokens, pooled and fused features
    ===========  =================  =========================================================

    ``Linear(C → D)``, ``depth`` blocks, a pooling over the views, ``LN → MLP → F_b``. With
    ``fusion="attention"`` the blocks are :class:`AttentionBlock` (views attend to each other) and
    the pooling an :class:`AttentionPool`, both with ``log w`` on the keys; with ``"mean"`` the
    blocks are :class:`MLPBlock` and the pooling the weighted mean ``Σ w_k x_k / Σ w_k`` (the plain
    mean for uniform w).

    ===============  =====  ================================
    parameter        type   meaning
    ===============  =====  ================================
    ``in_features``  int    C
    ``dim``          int    D (divisible by ``heads``)
    ``heads``        int    attention heads
    ``depth``        int    blocks
    ``mlp``          int    MLP hidden width
    ``out_features`` int    F_b
    ``fusion``       str    ``attention`` or ``mean``
    ===============  =====  ================================
    """

    def __init__(
        self,
        in_features: int,
        dim: int = 32,
        heads: int = 4,
        depth: int = 2,
        mlp: int = 64,
        out_features: int = 16,
        fusion: str = "attention",
    ):
        super().__init__()
        if fusion not in FUSIONS:
            raise InputError(f"MVANet: fusion must be one of {', '.join(FUSIONS)}, got {fusion!r}")
        self.in_features, self.fusion = in_features, fusion
        self.embed = nn.Linear(in_features, dim)
        attention = fusion == "attention"
        self.blocks = nn.ModuleList(
            [AttentionBlock(dim, heads, mlp) if attention else MLPBlock(dim, mlp) for _ in range(depth)]
        )
        self.pool = AttentionPool(dim, heads) if attention else None
        self.head = nn.Sequential(nn.LayerNorm(dim), mlp_layers([dim, mlp, out_features]))

    def forward(self, tokens: torch.Tensor, weights: torch.Tensor | None = None) -> MVAOutput:
        if tokens.ndim != 5 or tokens.shape[2] != self.in_features:
            raise InputError(
                f"MVANet: tokens have shape {tuple(tokens.shape)}; expected (B, N, {self.in_features}, H, W)"
            )
        b, n, c, h, w = tokens.shape
        p = normalised_weights(weights, tokens).permute(0, 3, 4, 1, 2).reshape(b * h * w, n)
        x = self.embed(tokens.permute(0, 3, 4, 1, 2).reshape(b * h * w, n, c))
        log_w = torch.log(p)
        for block in self.blocks:
            x = block(x, log_w)
        pooled = self.pool(x, log_w) if self.pool is not None else (p[..., None] * x).sum(dim=1)
        fused = self.head(pooled)

        def image(t):
            return t.reshape(b, h, w, -1).permute(0, 3, 1, 2)

        per_view = x.reshape(b, h, w, n, -1).permute(0, 3, 4, 1, 2)
        return MVAOutput(per_view, image(pooled), image(fused))
