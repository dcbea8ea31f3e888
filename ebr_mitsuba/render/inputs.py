"""Differentiable inputs of the fast renderer: SVBRDF map tensors, SG lobes and render options.

Shapes at this boundary (Dr.Jit arrays of the current Mitsuba variant, float32):

==============  =======================  ==================================================
field           type / shape             meaning
==============  =======================  ==================================================
``normal``      ``mi.TensorXf`` (H,W,3)  tangent-space normals (renormalised, z clamped to
                                         ≥ 1e-4, inside the renderer)
``diffuse``     ``mi.TensorXf`` (H,W,3)  linear RGB albedo d
``specular``    ``mi.TensorXf`` (H,W,3)  linear RGB F₀ s
``roughness``   ``mi.TensorXf`` (H,W) or roughness r (α = r², r clamped to [0.03, 1]
                (H,W,1)                  inside the BRDF only)
``axis``        ``mi.Vector3f`` (K)      lobe axes ξ (normalised inside the renderer, so an
                                         unconstrained 3-vector can be optimised)
``sharpness``   ``mi.Float`` (K)         λ > 0, used as given
``amplitude``   ``mi.Color3f`` (K)       RGB μ ≥ 0, used as given
==============  =======================  ==================================================

Row 0 of every map is the top of the sample (world +y), column 0 its left edge (−x): the sample
grid (:func:`ebr_mitsuba.geometry.pixel_positions`). Every field may carry
gradients (``dr.enable_grad``); the renderer never detaches them.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import ConfigError, InputError
from ..exemplar import EXEMPLAR_DIFFUSE, EXEMPLAR_SPECULAR
from ..sgenv import SGEnvironment
from ..svbrdf import SVBRDF

MODES = ("sg", "quadrature")
FRESNEL_MODES = ("schlick", "none")


def _tensor_shape(t, name: str) -> tuple[int, ...]:
    if not isinstance(t, mi.TensorXf):
        raise InputError(
            f"DrMaps: {name} must be a mi.TensorXf (got {type(t).__name__}); "
            f"build it with DrMaps.from_numpy or mi.TensorXf(array)"
        )
    return tuple(int(v) for v in t.shape)


@dataclass
class DrMaps:
    """SVBRDF maps as differentiable Dr.Jit tensors (see the module docstring for shapes)."""

    normal: mi.TensorXf
    diffuse: mi.TensorXf
    specular: mi.TensorXf
    roughness: mi.TensorXf

    def __post_init__(self):
        shape = _tensor_shape(self.normal, "normal")
        if len(shape) != 3 or shape[2] != 3:
            raise InputError(f"DrMaps: normal has shape {shape}; expected (H, W, 3)")
        hw = shape[:2]
        for name in ("diffuse", "specular"):
            s = _tensor_shape(getattr(self, name), name)
            if s != (*hw, 3):
                raise InputError(f"DrMaps: {name} has shape {s}; expected {(*hw, 3)} like the normal map")
        s = _tensor_shape(self.roughness, "roughness")
        if s not in (hw, (*hw, 1)):
            raise InputError(f"DrMaps: roughness has shape {s}; expected {hw} or {(*hw, 1)}")

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W)."""
        return int(self.normal.shape[0]), int(self.normal.shape[1])

    @staticmethod
    def from_numpy(svbrdf: SVBRDF) -> DrMaps:
        """Copy a validated :class:`~ebr_mitsuba.svbrdf.SVBRDF` into Dr.Jit tensors (no gradients)."""
        return DrMaps(
            normal=mi.TensorXf(np.ascontiguousarray(svbrdf.normal, dtype=np.float32)),
            diffuse=mi.TensorXf(np.ascontiguousarray(svbrdf.diffuse, dtype=np.float32)),
            specular=mi.TensorXf(np.ascontiguousarray(svbrdf.specular, dtype=np.float32)),
            roughness=mi.TensorXf(np.ascontiguousarray(svbrdf.roughness, dtype=np.float32)),
        )

    @staticmethod
    def uniform(
        height: int,
        width: int,
        diffuse=EXEMPLAR_DIFFUSE,
        specular=EXEMPLAR_SPECULAR,
        roughness=0.5,
        normal=(0.0, 0.0, 1.0),
    ) -> DrMaps:
        """A spatially constant material (by default the exemplar material of
        :mod:`ebr_mitsuba.exemplar`, roughness 0.5)."""
        return DrMaps.from_numpy(SVBRDF.uniform(height, width, diffuse, specular, roughness, normal))

    def params(self) -> dict[str, mi.TensorXf]:
        """The four tensors by name (for an optimiser)."""
        return {
            "normal": self.normal,
            "diffuse": self.diffuse,
            "specular": self.specular,
            "roughness": self.roughness,
        }

    def detach(self) -> DrMaps:
        return DrMaps(*(dr.detach(t) for t in (self.normal, self.diffuse, self.specular, self.roughness)))


def _as_vector(value, kind, name: str):
    """Accept a Dr.Jit 3-vector of K lanes or a (K, 3) tensor (converted differentiably)."""
    if isinstance(value, mi.TensorXf):
        if value.ndim != 2 or value.shape[1] != 3:
            raise InputError(f"DrLobes: {name} tensor has shape {tuple(value.shape)}; expected (K, 3)")
        return dr.unravel(kind, value.array)
    if isinstance(value, (mi.Vector3f, mi.Color3f, mi.Point3f)):
        return kind(value)
    raise InputError(
        f"DrLobes: {name} must be a {kind.__name__} or a (K, 3) mi.TensorXf (got {type(value).__name__})"
    )


@dataclass
class DrLobes:
    """K spherical-Gaussian lobes as differentiable Dr.Jit arrays (world frame, z-up).

    ``axis`` and ``amplitude`` may also be given as (K, 3) ``mi.TensorXf`` (converted with
    ``dr.unravel``, gradients flow back to the tensor); ``sharpness`` as a (K,) tensor.
    """

    axis: mi.Vector3f
    sharpness: mi.Float
    amplitude: mi.Color3f

    def __post_init__(self):
        self.axis = _as_vector(self.axis, mi.Vector3f, "axis")
        self.amplitude = _as_vector(self.amplitude, mi.Color3f, "amplitude")
        if isinstance(self.sharpness, mi.TensorXf):
            if self.sharpness.ndim != 1:
                raise InputError(
                    f"DrLobes: sharpness tensor has shape {tuple(self.sharpness.shape)}; expected (K,)"
                )
            self.sharpness = self.sharpness.array
        if not isinstance(self.sharpness, mi.Float):
            raise InputError(f"DrLobes: sharpness must be a mi.Float (got {type(self.sharpness).__name__})")
        k = dr.width(self.axis)
        if dr.width(self.sharpness) != k or dr.width(self.amplitude) != k:
            raise InputError(
                f"DrLobes: {k} axes, {dr.width(self.sharpness)} sharpness values and "
                f"{dr.width(self.amplitude)} amplitudes; give one of each per lobe"
            )

    @property
    def num_lobes(self) -> int:
        return int(dr.width(self.axis))

    @staticmethod
    def from_numpy(axis, sharpness, amplitude) -> DrLobes:
        """From numpy arrays (K, 3), (K,), (K, 3) (no gradients, no validation)."""
        a = np.asarray(axis, np.float32).reshape(-1, 3)
        m = np.asarray(amplitude, np.float32).reshape(-1, 3)
        return DrLobes(
            mi.Vector3f(a[:, 0], a[:, 1], a[:, 2]),
            mi.Float(np.asarray(sharpness, np.float32).reshape(-1)),
            mi.Color3f(m[:, 0], m[:, 1], m[:, 2]),
        )

    @staticmethod
    def from_env(env: SGEnvironment) -> DrLobes:
        """Copy a validated :class:`~ebr_mitsuba.sgenv.SGEnvironment` (no gradients)."""
        return DrLobes.from_numpy(env.axis, env.sharpness, env.amplitude)

    def to_env(self) -> SGEnvironment:
        """Read the lobes back into a validated ``SGEnvironment`` (a host transfer)."""
        if self.num_lobes == 0:
            return SGEnvironment.empty()
        return SGEnvironment(self.axis.numpy().T, self.sharpness.numpy(), self.amplitude.numpy().T)

    def params(self) -> dict:
        return {"axis": self.axis, "sharpness": self.sharpness, "amplitude": self.amplitude}

    def detach(self) -> DrLobes:
        return DrLobes(dr.detach(self.axis), dr.detach(self.sharpness), dr.detach(self.amplitude))


@dataclass(frozen=True)
class RenderOptions:
    """Knobs of :func:`ebr_mitsuba.render.render` (one place for the defaults).

    ====================  =========  ========  ===================================================
    name                  type       default   meaning
    ====================  =========  ========  ===================================================
    ``mode``              str        ``sg``    environment term: ``sg`` (closed form) or
                                               ``quadrature`` (fixed-pattern MIS estimate)
    ``spp``               int        64        quadrature directions per pixel (half BRDF-,
                                               half lobe-sampled; the BRDF gets the odd one)
    ``env_scale``         float      1.0       factor on the environment term
    ``irradiance_nodes``  int        16        Gauss–Legendre nodes of ``sg_irradiance``
                                               (``sg`` mode's diffuse part)
    ``fresnel``           str        schlick   ``schlick`` or ``none`` (F = F₀)
    ``max_lanes``         int        2**21     quadrature: (pixel × direction) lanes per chunk;
                                               bounds memory, not the result
    ``seed``              int        0         quadrature: selects the deterministic pattern
    ``irradiance_table``  int        0         ``sg`` mode, per-pixel normals: 0 evaluates the
                                               diffuse irradiance per (pixel, lobe) pair; R > 0
                                               tabulates it once on an R×R hemi-octahedral grid
                                               of normals and interpolates (bilinear), about 10×
                                               faster (:func:`~.env_sg.irradiance_table`)
    ``lobe_loop``         bool       False     ``sg`` mode: sum the lobes in a symbolic loop per
                                               point (one kernel, no scatter) instead of the
                                               flat (point, lobe) pair kernel; same values and
                                               gradients, 1.2–2.8× faster for images of
                                               megapixels (:func:`~.env_sg.sg_environment`)
    ``window``            tuple      None      ``(row0, col0, full_h, full_w)``: the maps are that
                                               block of a larger grid (:mod:`.points`); None: the
                                               whole grid
    ====================  =========  ========  ===================================================
    """

    mode: str = "sg"
    spp: int = 64
    env_scale: float = 1.0
    irradiance_nodes: int = 16
    fresnel: str = "schlick"
    max_lanes: int = 1 << 21
    seed: int = 0
    irradiance_table: int = 0
    lobe_loop: bool = False
    window: tuple[int, int, int, int] | None = None

    def __post_init__(self):
        if self.mode not in MODES:
            raise ConfigError(f"render options: mode {self.mode!r} is unknown; use one of {', '.join(MODES)}")
        if self.fresnel not in FRESNEL_MODES:
            raise ConfigError(
                f"render options: fresnel {self.fresnel!r} is unknown; use one of {', '.join(FRESNEL_MODES)}"
            )
        if self.window is not None:
            if len(tuple(self.window)) != 4 or any(int(v) != v or v < 0 for v in self.window):
                raise ConfigError(
                    f"render options: window must be (row0, col0, full_h, full_w), "
                    f"non-negative integers (got {self.window!r})"
                )
            object.__setattr__(self, "window", tuple(int(v) for v in self.window))
        if isinstance(self.irradiance_table, (int, np.integer)) and 0 < self.irradiance_table < 2:
            raise ConfigError(
                f"render options: irradiance_table must be 0 or >= 2 (got {self.irradiance_table})"
            )
        for name, lo in (
            ("spp", 1),
            ("irradiance_nodes", 1),
            ("max_lanes", 1),
            ("seed", 0),
            ("irradiance_table", 0),
        ):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < lo:
                raise ConfigError(f"render options: {name} must be an integer >= {lo} (got {value!r})")
        if not np.isfinite(self.env_scale) or self.env_scale < 0:
            raise ConfigError(f"render options: env_scale must be finite and >= 0 (got {self.env_scale!r})")
