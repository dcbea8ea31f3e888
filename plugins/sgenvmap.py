"""The ``sgenvmap`` emitter: an environment made of spherical Gaussians (``docs/conventions.md``,
"Spherical Gaussians").

Registered by :func:`ebr_mitsuba.ensure_variant`, or by ``import ebr_mitsuba`` after
``mi.set_variant``; the class derives from the variant's ``mi.Emitter``, so this module is
imported (and re-imported) only after a variant is set.
"""

from __future__ import annotations

import math
import re

import drjit as dr
import mitsuba as mi
import numpy as np

from ebr_mitsuba import sg
from ebr_mitsuba.brdf import luminance
from ebr_mitsuba.errors import ConfigError, InputError
from ebr_mitsuba.sgenv import SGEnvironment

_variant = mi.variant()

#: Mixtures with at most this many lobes sum their lobes in a Python-unrolled loop (fastest
#: forward, one kernel); larger ones use a symbolic ``dr.while_loop`` (compiles once for any K,
#: supports reverse-mode AD with ``max_iterations=-1``).
UNROLL_MAX_LOBES = 8

DEFAULT_SCENE_RADIUS = 1.0e3

_NUMBER = re.compile(r"[\s,]+")


def _parse_rows(text: str, width: int, name: str) -> np.ndarray:
    """Parse ``"a b c, d e f"`` (lobes separated by commas) into a (K, width) array."""
    if width == 1:
        rows = [[v] for v in _NUMBER.split(text.strip()) if v]
    else:
        rows = [r.split() for r in text.split(",") if r.strip()]
    out = []
    for i, row in enumerate(rows):
        try:
            numbers = [float(v) for v in row]
        except ValueError:
            raise ConfigError(f"sgenvmap: '{name}' lobe {i} is {' '.join(row)!r}; give numbers") from None
        if len(numbers) != width:
            raise ConfigError(
                f"sgenvmap: '{name}' lobe {i} has {len(numbers)} numbers, expected "
                f"{width} (lobes are separated by commas)"
            )
        out.append(numbers)
    return np.asarray(out, dtype=np.float64).reshape(-1, width)


def _inline_array(props, name: str, width: int) -> np.ndarray:
    """An inline lobe property as a (K, width) array: a string, or any array-like (TensorXf,
    Dr.Jit/numpy array, float) holding K·width values row-major."""
    value = props[name]
    if isinstance(value, str):
        return _parse_rows(value, width, name)
    try:
        arr = np.asarray(value.numpy() if hasattr(value, "numpy") else value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(
            f"sgenvmap: '{name}' must be a string or a mi.TensorXf; got {type(value).__name__}"
        ) from None
    if arr.size % width:
        raise ConfigError(f"sgenvmap: '{name}' holds {arr.size} values, not a multiple of {width}")
    return arr.reshape(-1, width)


def environment_from_properties(props) -> SGEnvironment:
    """The :class:`SGEnvironment` described by ``filename`` or by inline ``axis``/``sharpness``/
    ``amplitude`` properties (exactly one of the two forms)."""
    inline = [k for k in ("axis", "sharpness", "amplitude") if k in props]
    if "filename" in props:
        if inline:
            raise ConfigError(
                f"sgenvmap: give either 'filename' or inline lobes, not both (remove {', '.join(inline)})"
            )
        path = str(mi.file_resolver().resolve(str(props["filename"])))
        return SGEnvironment.load(path)
    if len(inline) != 3:
        missing = [k for k in ("axis", "sharpness", "amplitude") if k not in inline]
        raise ConfigError(
            f"sgenvmap: needs 'filename' (an env.json) or all of axis/sharpness/"
            f"amplitude; missing {', '.join(missing)}"
        )
    axis = _inline_array(props, "axis", 3)
    sharp = _inline_array(props, "sharpness", 1)[:, 0]
    amp = _inline_array(props, "amplitude", 3)
    try:
        return SGEnvironment(axis, sharp, amp)
    except InputError as exc:
        raise ConfigError(f"sgenvmap inline lobes: {exc}") from None


def sgenvmap_dict(env: SGEnvironment, scale: float = 1.0, **extra) -> dict:
    """A ``mi.load_dict`` entry for ``env`` (inline lobes as tensors); ``extra`` adds keys such
    as ``id`` or ``scene_radius``.

    The tensors get a leading axis of size 1 ((1, K, 3), (1, K)): Mitsuba's dict loader tries to
    convert any value of length 3 to a colour and prints warnings when K = 3.
    """
    out = {
        "type": "sgenvmap",
        "axis": mi.TensorXf(np.asarray(env.axis, np.float32).reshape(1, -1, 3)),
        "sharpness": mi.TensorXf(np.asarray(env.sharpness, np.float32).reshape(1, -1)),
        "amplitude": mi.TensorXf(np.asarray(env.amplitude, np.float32).reshape(1, -1, 3)),
        "scale": float(scale),
    }
    out.update(extra)
    return out


class SGEnvMap(mi.Emitter):
    r"""Environment emitter ``L(ω) = scale · Σ_k μ_k exp(λ_k (ξ_k·ω − 1))`` (world frame, z-up).

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Default
         - Meaning
       * - ``filename``
         - string
         - —
         - An ``env.json`` (format ``ebr-sg/1``); relative paths resolve like other scene files.
       * - ``axis``
         - string or TensorXf (K, 3)
         - —
         - Inline lobe axes ξ, ``"x y z, x y z, ..."`` (commas between lobes); renormalised.
       * - ``sharpness``
         - string or TensorXf (K,)
         - —
         - Inline sharpness λ > 0, ``"l1, l2, ..."``.
       * - ``amplitude``
         - string or TensorXf (K, 3)
         - —
         - Inline RGB amplitudes μ ≥ 0, ``"r g b, r g b, ..."``.
       * - ``scale``
         - float
         - 1
         - Radiance multiplier.
       * - ``scene_radius``
         - float
         - 1000
         - Radius of a sphere about the origin enclosing the scene. Python emitters cannot see the
           scene bounds (``set_scene`` is not overridable), so shadow rays towards the
           environment have length ``2·max(scene_radius, |p|)`` and ``sample_ray`` emits from a
           disk of this radius.

    Give either ``filename`` or all three inline properties. Tensors may have any shape holding
    K·3 (resp. K) values row-major; a (K, 3) tensor with K = 3 loads correctly but makes Mitsuba's
    dict loader print conversion warnings, which :func:`sgenvmap_dict`'s (1, K, 3) shape avoids.
    Empty strings / (0, 3) tensors give an all-black environment (K = 0). Unknown properties are
    rejected by Mitsuba's loader.

    Differentiable parameters (``mi.traverse``), flat ``mi.Float`` arrays: ``axis`` (3K,
    row-major (K, 3)), ``sharpness`` (K), ``amplitude`` (3K, row-major (K, 3)), ``scale`` (1).
    After an update, ``parameters_changed`` renormalises the axes, checks λ > 0, μ ≥ 0 and
    scale ≥ 0 (``InputError`` otherwise) and rebuilds the lobe-selection distribution; K may
    change (all three arrays together).

    Sampling picks lobe k with probability ∝ ``∫G_k dω · luminance(μ_k)`` and draws a direction
    from its von Mises–Fisher density; the pdf is the mixture ``Σ_k p_k vMF_k(ω)``. Sampled
    directions and pdfs are detached; radiance carries the gradients (as Mitsuba's emitters).
    Evaluation and pdf cost O(K) each; for large K and forward-only renders, rasterising to
    Mitsuba's ``envmap`` is faster.

    XML (each example is loaded by ``tests/test_docs_xml.py``), from a file:

    ~~~xml
    <emitter type="sgenvmap" id="env">
        <string name="filename" value="env.json"/>
        <float name="scale" value="1.0"/>
    </emitter>
    ~~~

    or with inline lobes:

    ~~~xml
    <emitter type="sgenvmap" id="env">
        <string name="axis" value="0 0 1, 0.6 0 0.8"/>
        <string name="sharpness" value="2, 300"/>
        <string name="amplitude" value="0.5 0.5 0.6, 20 18 15"/>
    </emitter>
    ~~~

    ``mi.load_dict``::

        {"type": "sgenvmap", "id": "env",
         "axis": mi.TensorXf(axis_k3), "sharpness": mi.TensorXf(lam_k),
         "amplitude": mi.TensorXf(mu_k3), "scale": 1.0}
        # or sgenvmap_dict(SGEnvironment.load("env.json"), id="env")
    """

    def __init__(self, props):
        mi.Emitter.__init__(self, props)
        env = environment_from_properties(props)
        scale = float(props.get("scale", 1.0))
        if not math.isfinite(scale) or scale < 0:
            raise ConfigError(f"sgenvmap: 'scale' is {scale}; give a finite value >= 0")
        radius = float(props.get("scene_radius", DEFAULT_SCENE_RADIUS))
        if not radius > 0 or not math.isfinite(radius):
            raise ConfigError(f"sgenvmap: 'scene_radius' is {radius}; give a finite value > 0")
        self.m_flags = mi.EmitterFlags.Infinite | mi.EmitterFlags.SpatiallyVarying
        self.scene_radius = mi.Float(radius)
        dr.make_opaque(self.scene_radius)
        self.scale = mi.Float(scale)
        self.axis = mi.Float(np.asarray(env.axis, np.float32).reshape(-1))
        self.sharpness = mi.Float(np.asarray(env.sharpness, np.float32).reshape(-1))
        self.amplitude = mi.Float(np.asarray(env.amplitude, np.float32).reshape(-1))
        self.parameters_changed([])

    # -- parameters ---------------------------------------------------------------------------
    def traverse(self, callback):
        flags = mi.ParamFlags.Differentiable
        callback.put("axis", self.axis, flags)
        callback.put("sharpness", self.sharpness, flags)
        callback.put("amplitude", self.amplitude, flags)
        callback.put("scale", self.scale, flags)

    def parameters_changed(self, keys=None):
        k = dr.width(self.sharpness)
        if dr.width(self.axis) != 3 * k or dr.width(self.amplitude) != 3 * k:
            raise InputError(
                f"sgenvmap: {k} sharpness values need 3·{k} axis and amplitude values; "
                f"got {dr.width(self.axis)} and {dr.width(self.amplitude)}"
            )
        if dr.width(self.scale) != 1:
            raise InputError(f"sgenvmap: 'scale' must hold one value, got {dr.width(self.scale)}")
        scale = float(self.scale.numpy()[0])
        if not math.isfinite(scale) or scale < 0:
            raise InputError(f"sgenvmap: 'scale' is {scale}; give a finite value >= 0")
        self._k = k
        dr.make_opaque(self.scale)
        if k == 0:
            self._black = True
            self._dist = None
            return
        lam = self.sharpness.numpy().astype(np.float64)
        amp = self.amplitude.numpy().astype(np.float64).reshape(k, 3)
        axis = self.axis.numpy().astype(np.float64).reshape(k, 3)
        if not (np.all(np.isfinite(lam)) and np.all(np.isfinite(amp)) and np.all(np.isfinite(axis))):
            raise InputError("sgenvmap: NaN or Inf in the lobe parameters; check the optimiser step")
        if np.any(lam <= 0) or np.any(amp < 0):
            raise InputError(
                "sgenvmap: sharpness must be > 0 and amplitudes >= 0; clamp the "
                "parameters after each optimiser step (e.g. dr.maximum(x, 1e-4))"
            )
        if np.any(np.linalg.norm(axis, axis=1) < 1e-12):
            raise InputError("sgenvmap: a lobe axis has zero length; give non-zero axes")
        index = dr.arange(mi.UInt32, k)
        axis3 = dr.normalize(dr.gather(mi.Vector3f, self.axis, index))
        amp3 = dr.gather(mi.Color3f, self.amplitude, index)
        self._axis3 = axis3
        self._sharp = mi.Float(self.sharpness)
        self._amp3 = amp3
        dr.eval(self._axis3, self._sharp, self._amp3)
        self._axis3_d = dr.detach(self._axis3)
        self._sharp_d = dr.detach(self._sharp)
        # Lobe-selection distribution: energy ∫G dω · luminance(μ), computed with the SG module.
        energy = sg.sg_integral(self._sharp_d, luminance(dr.detach(self._amp3)))
        energy_np = np.asarray(energy.numpy(), np.float64)
        total = float(energy_np.sum())
        if not total > 0:
            self._black = True
            self._dist = None
            return
        self._black = False
        self._dist = mi.DiscreteDistribution(mi.Float(energy_np.astype(np.float32)))
        self._pmf = mi.Float((energy_np / total).astype(np.float32))

    # -- lobe sums ----------------------------------------------------------------------------
    def _sum_lobes(self, term, init, active):
        """``init + Σ_k term(k)`` with ``k`` a UInt32 lobe index (unrolled or symbolic loop)."""
        if self._k <= UNROLL_MAX_LOBES:
            acc = init
            for k in range(self._k):
                acc = acc + term(mi.UInt32(k))
            return acc
        count = self._k

        def body(i, acc):
            return i + 1, acc + term(i)

        _, acc = dr.while_loop(
            (dr.zeros(mi.UInt32, dr.width(init)), init),
            lambda i, acc: active & (i < count),
            body,
            labels=("lobe", "acc"),
            label="sgenvmap",
            max_iterations=-1,
        )
        return acc

    def radiance(self, d, active=True):
        """Radiance (Color3f) arriving from world directions ``d`` (unit Vector3f)."""
        n = dr.width(d)
        if self._k == 0:
            return dr.zeros(mi.Color3f, n)

        def term(k):
            axis = dr.gather(mi.Vector3f, self._axis3, k)
            lam = dr.gather(mi.Float, self._sharp, k)
            amp = dr.gather(mi.Color3f, self._amp3, k)
            return sg.sg_eval(axis, lam, amp, d)

        value = self._sum_lobes(term, dr.zeros(mi.Color3f, n), active)
        return dr.select(active, value * self.scale, 0.0)

    def mixture_pdf(self, d, active=True):
        """Solid-angle density of :meth:`sample_direction` at world directions ``d`` (detached)."""
        n = dr.width(d)
        if self._black:
            return dr.zeros(mi.Float, n)
        d = dr.detach(d)

        def term(k):
            axis = dr.gather(mi.Vector3f, self._axis3_d, k)
            lam = dr.gather(mi.Float, self._sharp_d, k)
            p = dr.gather(mi.Float, self._pmf, k)
            return p * sg.vmf_pdf(axis, lam, d)

        value = self._sum_lobes(term, dr.zeros(mi.Float, n), active)
        return dr.select(active, value, 0.0)

    def _sample_lobes(self, sample, active):
        index, u = self._dist.sample_reuse(sample.x, active)
        axis = dr.gather(mi.Vector3f, self._axis3_d, index, active)
        lam = dr.gather(mi.Float, self._sharp_d, index, active)
        return sg.vmf_sample(axis, lam, mi.Point2f(u, sample.y))

    # -- Emitter interface --------------------------------------------------------------------
    def eval(self, si, active=True):
        return self.radiance(-si.wi, active)

    def sample_direction(self, it, sample, active=True):
        n = dr.width(sample)
        if self._black:
            return dr.zeros(mi.DirectionSample3f, n), dr.zeros(mi.Color3f, n)
        d = self._sample_lobes(sample, active)
        pdf = self.mixture_pdf(d, active)
        ok = active & (pdf > 0.0)
        dist = 2.0 * dr.maximum(self.scene_radius, dr.norm(it.p))
        ds = dr.zeros(mi.DirectionSample3f, n)
        ds.p = it.p + d * dist
        ds.n = -d
        ds.time = it.time
        ds.pdf = dr.select(ok, pdf, 0.0)
        ds.delta = mi.Bool(False)
        ds.emitter = mi.EmitterPtr(self)
        ds.d = d
        ds.dist = dist
        weight = self.radiance(d, ok) / dr.select(ok, pdf, 1.0)
        return ds, dr.select(ok, weight, 0.0)

    def pdf_direction(self, it, ds, active=True):
        return self.mixture_pdf(ds.d, active)

    def eval_direction(self, it, ds, active=True):
        return self.radiance(ds.d, active)

    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        n = dr.width(sample3)
        if self._black:
            return dr.zeros(mi.Ray3f, n), dr.zeros(mi.Color3f, n)
        d = self._sample_lobes(sample3, active)  # towards the environment
        pdf = self.mixture_pdf(d, active)
        ok = active & (pdf > 0.0)
        offset = mi.warp.square_to_uniform_disk_concentric(sample2)
        frame = mi.Frame3f(d)
        origin = (frame.to_world(mi.Vector3f(offset.x, offset.y, 0.0)) + d) * self.scene_radius
        ray = mi.Ray3f(origin, -d, time)
        area = dr.pi * dr.square(self.scene_radius)
        weight = self.radiance(d, ok) * area / dr.select(ok, pdf, 1.0)
        return ray, dr.select(ok, weight, 0.0)

    def sample_wavelengths(self, si, sample, active=True):
        # RGB variants carry no wavelengths; the weight is the radiance arriving along -si.wi.
        return mi.Color0f(), self.radiance(-si.wi, active)

    def sample_position(self, time, sample, active=True):
        return dr.zeros(mi.PositionSample3f, dr.width(sample)), dr.zeros(mi.Float, dr.width(sample))

    def pdf_position(self, ps, active=True):
        return dr.zeros(mi.Float, dr.width(ps.p))

    def bbox(self):
        return mi.ScalarBoundingBox3f()  # an environment occupies no region of space

    def to_string(self):
        return f"SGEnvMap[lobes={self._k}, scene_radius={self.scene_radius[0]:g}]"


def register() -> None:
    mi.register_emitter("sgenvmap", lambda props: SGEnvMap(props))
