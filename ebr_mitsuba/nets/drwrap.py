"""The Dr.Jit fast renderer called from torch through ``dr.wrap``, with gradients into torch.

:func:`ebr_mitsuba.render.render` (one shading point per pixel, point light + SG environment,
the BRDF of ``docs/conventions.md``) is wrapped with ``@dr.wrap(source="torch", target="drjit")``:
torch tensors go in zero-copy (DLPack), the render runs as Dr.Jit kernels, and ``loss.backward()``
in torch propagates through the Dr.Jit AD graph into the torch map (and lobe) tensors. This is the
renderer of the rendering losses and of the cascade's photo renders wherever the environment is
involved; the point-light-only torch mirror :mod:`.torch_brdf` is tested against it.

Shapes at this boundary:

==================  ==================  ============================================================
argument            shape               meaning
==================  ==================  ============================================================
``maps``            :class:`~.maps.Maps`  (B, C, H, W) torch maps (any float dtype; rendered float32)
``lobes``           sequence of B       per batch element a (K_b, 7) tensor of lobes
                    tensors or None     ``[axis xyz, λ, μ rgb]`` (the ``sg`` rows of
                                        :class:`~ebr_mitsuba.data.dataset.GeneratedDataset`);
                                        None or K_b = 0: no environment
``shots``           Shot or B shots     camera, point light and intensity of each render
                                        (:class:`ebr_mitsuba.geometry.Shot`)
returns             (B, 3, H, W)        radiance, float32, on the maps' device
==================  ==================  ============================================================

Helpers: :func:`lobes_from_padded` turns the data set's padded ``sg``/``sg_mask`` into that list,
:func:`lobes_from_env` an :class:`~ebr_mitsuba.sgenv.SGEnvironment` into one (K, 7) tensor.
:func:`point_light_renderer` makes the ``render(maps, camera, light)`` callable of
:func:`ebr_mitsuba.nets.losses.rendering_loss` (point light, no environment).

Each batch element is one render call (lobe counts differ per element); the per-call camera,
light and intensity are opaque in the kernels, so one compiled kernel serves every call of the
same shapes. Float64 inputs are cast to float32 first (a float64 tensor would silently switch the
Dr.Jit computation to float64). CUDA tensors go through host memory when the Mitsuba variant is
an LLVM one (gradients still flow; the copy is the price).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

from ..errors import InputError
from ..geometry import DEFAULT_FLASH_INTENSITY, Shot
from ..sgenv import SGEnvironment
from .maps import Maps

LOBE_COLUMNS = 7  # axis xyz, sharpness, amplitude rgb


def _require_variant():
    import mitsuba as mi

    if mi.variant() is None:
        from ..variant import ensure_variant

        ensure_variant()
    return mi


def _drjit_device() -> str:
    mi = _require_variant()
    return "cuda" if mi.variant().startswith("cuda") else "cpu"


def lobes_from_env(env: SGEnvironment | None, device=None) -> torch.Tensor:
    """An SG environment as one (K, 7) float32 tensor ``[axis, λ, μ]`` (K = 0 for None)."""
    if env is None or env.num_lobes == 0:
        return torch.zeros((0, LOBE_COLUMNS), dtype=torch.float32, device=device)
    rows = np.concatenate(
        [
            np.asarray(env.axis, np.float32),
            np.asarray(env.sharpness, np.float32)[:, None],
            np.asarray(env.amplitude, np.float32),
        ],
        axis=1,
    )
    return torch.from_numpy(np.ascontiguousarray(rows)).to(device)


def lobes_from_padded(sg: torch.Tensor, mask: torch.Tensor) -> list[torch.Tensor]:
    """The data set's padded lobes ``sg`` (B, K, 7) and ``sg_mask`` (B, K) as B (K_b, 7) tensors."""
    if sg.ndim != 3 or sg.shape[2] != LOBE_COLUMNS or mask.shape != sg.shape[:2]:
        raise InputError(
            f"lobes_from_padded: sg has shape {tuple(sg.shape)} and sg_mask "
            f"{tuple(mask.shape)}; expected (B, K, 7) and (B, K)"
        )
    return [sg[b][mask[b] > 0.5] for b in range(sg.shape[0])]


def _render_one(normal, diffuse, specular, roughness, lobes, shot: Shot, options):
    """Render one element: (H, W, C) Dr.Jit tensors (inside the wrap) → (H, W, 3) TensorXf."""
    import drjit as dr
    import mitsuba as mi

    from ..render import DrLobes, DrMaps, render

    maps = DrMaps(normal, diffuse, specular, roughness)
    if lobes is None:
        dr_lobes = DrLobes(mi.Vector3f(), mi.Float(), mi.Color3f())
    else:
        flat = lobes.array
        k = dr.width(flat) // LOBE_COLUMNS
        idx = dr.arange(mi.UInt32, k) * LOBE_COLUMNS

        def col(c):
            return dr.gather(mi.Float, flat, idx + c)

        dr_lobes = DrLobes(mi.Vector3f(col(0), col(1), col(2)), col(3), mi.Color3f(col(4), col(5), col(6)))
    return render(maps, dr_lobes, shot, options)


def _wrapped(shot: Shot, options, with_lobes: bool) -> Callable:
    import drjit as dr

    if with_lobes:

        @dr.wrap(source="torch", target="drjit")
        def fn(normal, diffuse, specular, roughness, lobes):
            return _render_one(normal, diffuse, specular, roughness, lobes, shot, options)
    else:

        @dr.wrap(source="torch", target="drjit")
        def fn(normal, diffuse, specular, roughness):
            return _render_one(normal, diffuse, specular, roughness, None, shot, options)

    return fn


def _hwc(t: torch.Tensor, device: str) -> torch.Tensor:
    """(C, H, W) → contiguous float32 (H, W, C) on the Dr.Jit device."""
    return t.permute(1, 2, 0).to(device=device, dtype=torch.float32).contiguous()


def render_maps(
    maps: Maps, lobes: Sequence[torch.Tensor | None] | None, shots: Shot | Sequence[Shot], options=None
) -> torch.Tensor:
    """Differentiable render of a batch of torch maps: (B, 3, H, W) radiance (see the module docstring).

    ``options``: :class:`ebr_mitsuba.render.RenderOptions` (default: closed-form SG environment).
    Gradients flow into ``maps`` and into the lobe tensors.
    """
    from ..render import RenderOptions

    options = options or RenderOptions()
    batch = maps.normal.shape[0]
    shot_list = [shots] * batch if isinstance(shots, Shot) else list(shots)
    lobe_list = [None] * batch if lobes is None else list(lobes)
    if len(shot_list) != batch or len(lobe_list) != batch:
        raise InputError(
            f"render_maps: {batch} maps but {len(shot_list)} shots and {len(lobe_list)} lobe "
            f"sets; give one shot (or B) and B lobe sets"
        )
    device = _drjit_device()
    out = []
    for b in range(batch):
        args = [
            _hwc(getattr(maps, name)[b], device) for name in ("normal", "diffuse", "specular", "roughness")
        ]
        lb = lobe_list[b]
        if lb is not None:
            if lb.ndim != 2 or lb.shape[1] != LOBE_COLUMNS:
                raise InputError(
                    f"render_maps: lobes of element {b} have shape {tuple(lb.shape)}; expected (K, 7)"
                )
            if lb.shape[0] == 0:
                lb = None
        if lb is None:
            image = _wrapped(shot_list[b], options, False)(*args)
        else:
            image = _wrapped(shot_list[b], options, True)(
                *args, lb.to(device=device, dtype=torch.float32).contiguous()
            )
        out.append(image.permute(2, 0, 1))
    return torch.stack(out).to(maps.normal.device)


def point_light_renderer(intensity: float = DEFAULT_FLASH_INTENSITY, options=None) -> Callable:
    """``render(maps, camera (B, 3), light (B, 3)) -> (B, 3, H, W)``: the maps under one isotropic
    point light of ``intensity`` W/sr per element, no environment, through Dr.Jit (for
    :func:`ebr_mitsuba.nets.losses.rendering_loss`)."""
    from ..render import view_shot

    def render(maps: Maps, camera: torch.Tensor, light: torch.Tensor) -> torch.Tensor:
        cams = camera.detach().to("cpu", torch.float64).reshape(-1, 3).tolist()
        lights = light.detach().to("cpu", torch.float64).reshape(-1, 3).tolist()
        shots = [view_shot(c, l, intensity, env=False) for c, l in zip(cams, lights)]
        return render_maps(maps, None, shots, options)

    return render


__all__ = ["LOBE_COLUMNS", "lobes_from_env", "lobes_from_padded", "point_light_renderer", "render_maps"]
