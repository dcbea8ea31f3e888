"""The five-light fixed-view "dual loss" estimator (``docs/conventions.md``, "Pipeline").

Input: ``L = 5`` photos of the sample from the near camera, each lit by one point light of
:data:`ebr_mitsuba.geometry.FIVE_LIGHT_POSITIONS` (no environment), stacked as
``(B, L, 3, H, W)``, linear radiance. Output: :class:`~.maps.Maps`.

Architecture::

    log(x + ε) ─▶ (B, 3, L, H, W) ─▶ 3 × [Conv3d k3, stride (2,1,1), LeakyReLU 0.2]
                  features 16, 32, 32; depth L=5 → 3 → 2 → 1, folded into channels
               ─▶ U-Net: ``levels`` stride-2 4×4 convs (64, 128, 256, 512, 512, …, features),
                  LeakyReLU 0.2, batch norm (not on the first and the innermost conv);
                  4×4 stride-2 transposed convs back up with skip concatenation, batch norm,
                  LeakyReLU 0.2, dropout in the four coarsest decoder layers
               ─▶ sigmoid outputs

Output parameterisation (``DualLossConfig.output``), all channels through a sigmoid ``s``:

* ``diffuse_specular``: normal (3), diffuse (3), roughness (1), specular (3) — 10 channels;
* ``basecolor_metallic``: normal (3), base colour (3), roughness (1), metallic (1) — 8 channels,
  converted by :func:`basecolor_metallic_to_diffuse_specular`:
  ``diffuse = base·(1 − m)``, ``F₀ = 0.04·(1 − m) + base·m``.

Normals: ``n = normalise(2 s_x − 1, 2 s_y − 1, s_z + 1e-3)`` (unit, ``n_z > 0``).
Inputs are padded (edge replication) to a multiple of ``2^levels`` and the output cropped back.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import InputError
from ..materials import DIELECTRIC_F0
from ..typedconfig import config, from_dict, option
from .maps import Maps
from .transforms import LOG_EPS, NORMAL_Z_MIN, log_input

OUTPUT_MODES = {"diffuse_specular": 10, "basecolor_metallic": 8}


def basecolor_metallic_to_diffuse_specular(basecolor: torch.Tensor, metallic: torch.Tensor):
    """``(diffuse, specular) = (base·(1 − m), lerp(0.04, base, m))``.

    ``basecolor``: (B, 3, H, W) in [0, 1]; ``metallic``: (B, 1, H, W) in [0, 1].
    """
    diffuse = basecolor * (1.0 - metallic)
    specular = DIELECTRIC_F0 * (1.0 - metallic) + basecolor * metallic
    return diffuse, specular


@config
class DualLossConfig:
    """Options of :class:`DualLossNet`."""

    num_lights: int = option(5, "images per sample (depth L)", minimum=1)
    levels: int = option(8, "U-Net down-samplings (256² → 1²)", minimum=1)
    width_scale: float = option(1.0, "multiplies every feature count", above=0)
    output: str = option(
        "diffuse_specular", "diffuse_specular or basecolor_metallic", choices=tuple(OUTPUT_MODES)
    )
    dropout: float = option(0.5, "dropout in coarse decoder layers", minimum=0.0, below=1.0)
    dropout_layers: int = option(4, "how many coarse decoder layers", minimum=0)
    merge_features: tuple[int, ...] = option((16, 32, 32), "3-D conv features", minimum=1, nonempty=True)
    log_eps: float = option(LOG_EPS, "ε of log(x + ε) inputs", above=0)

    def features(self, base: int) -> int:
        return max(1, round(base * self.width_scale))

    @classmethod
    def from_dict(cls, data: Mapping, where: str = "dual_loss", *, key: str = "") -> DualLossConfig:
        return from_dict(cls, data, where, key=key)


class DualLossNet(nn.Module):
    """Five-light images ``(B, L, 3, H, W)`` → :class:`~.maps.Maps` (see the module docstring)."""

    def __init__(self, config: DualLossConfig | None = None):
        super().__init__()
        self.config = c = config or DualLossConfig()
        merge = []
        ch, depth = 3, c.num_lights
        for f in c.merge_features:
            out = c.features(f)
            merge += [nn.Conv3d(ch, out, 3, stride=(2, 1, 1), padding=1), nn.LeakyReLU(0.2)]
            ch, depth = out, (depth - 1) // 2 + 1
        self.merge = nn.Sequential(*merge)
        feats = [c.features(min(64 * 2**i, 512)) for i in range(c.levels)]
        self.down = nn.ModuleList()
        in_ch = ch * depth
        for i, f in enumerate(feats):
            layers = [] if i == 0 else [nn.LeakyReLU(0.2)]
            layers.append(nn.Conv2d(in_ch, f, 4, stride=2, padding=1, bias=i in (0, c.levels - 1)))
            if 0 < i < c.levels - 1:
                layers.append(nn.BatchNorm2d(f))
            self.down.append(nn.Sequential(*layers))
            in_ch = f
        self.up = nn.ModuleList()
        for i in range(c.levels - 1, 0, -1):  # coarse → fine; output at level i − 1 resolution
            dec_in = feats[i] if i == c.levels - 1 else 2 * feats[i]
            layers = [
                nn.LeakyReLU(0.2),
                nn.ConvTranspose2d(dec_in, feats[i - 1], 4, stride=2, padding=1, bias=False),
                nn.BatchNorm2d(feats[i - 1]),
            ]
            if (c.levels - 1 - i) < c.dropout_layers and c.dropout > 0:
                layers.append(nn.Dropout(c.dropout))
            self.up.append(nn.Sequential(*layers))
        last_in = feats[0] if c.levels == 1 else 2 * feats[0]
        self.out = nn.Sequential(
            nn.LeakyReLU(0.2), nn.ConvTranspose2d(last_in, OUTPUT_MODES[c.output], 4, stride=2, padding=1)
        )

    def forward(self, images: torch.Tensor) -> Maps:
        c = self.config
        if images.ndim != 5 or images.shape[1] != c.num_lights or images.shape[2] != 3:
            raise InputError(
                f"DualLossNet: input has shape {tuple(images.shape)}; expected (B, {c.num_lights}, 3, H, W)"
            )
        b, _, _, height, width = images.shape
        x = log_input(images, c.log_eps).transpose(1, 2)  # (B, 3, L, H, W)
        multiple = 2**c.levels
        pad_h, pad_w = (-height) % multiple, (-width) % multiple
        if pad_h or pad_w:
            x = F.pad(x, (0, pad_w, 0, pad_h, 0, 0), mode="replicate")
        x = self.merge(x)
        x = x.reshape(b, -1, *x.shape[-2:])
        skips = []
        for layer in self.down:
            x = layer(x)
            skips.append(x)
        for k, layer in enumerate(self.up):
            x = layer(x if k == 0 else torch.cat([x, skips[-1 - k]], dim=1))
        x = self.out(x if c.levels == 1 else torch.cat([x, skips[0]], dim=1))
        s = torch.sigmoid(x[..., :height, :width])
        n = torch.cat([2.0 * s[:, 0:2] - 1.0, s[:, 2:3] + NORMAL_Z_MIN], dim=1)
        normal = n / torch.linalg.vector_norm(n, dim=1, keepdim=True)
        roughness = s[:, 6:7]
        if c.output == "diffuse_specular":
            return Maps(normal, s[:, 3:6], s[:, 7:10], roughness)
        diffuse, specular = basecolor_metallic_to_diffuse_specular(s[:, 3:6], s[:, 7:8])
        return Maps(normal, diffuse, specular, roughness)
