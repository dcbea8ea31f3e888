"""The ``svbrdf`` BSDF: the project's one BRDF (:mod:`ebr_mitsuba.brdf`) as a Mitsuba plugin.

Registered by :func:`ebr_mitsuba.ensure_variant`, or by ``import ebr_mitsuba`` after
``mi.set_variant``; the class derives from the variant's ``mi.BSDF``, so this module is imported
(and re-imported) only after a variant is set.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ebr_mitsuba import brdf
from ebr_mitsuba.errors import ConfigError

_variant = mi.variant()

DEFAULT_DIFFUSE = 0.1
DEFAULT_SPECULAR = 0.2
DEFAULT_ROUGHNESS = 0.5

#: Component indices reported in ``BSDFSample3f.sampled_component``.
COMPONENT_GLOSSY = 0
COMPONENT_DIFFUSE = 1


class SVBRDFBSDF(mi.BSDF):
    r"""Diffuse + GGX microfacet reflection with texture maps (``docs/conventions.md``, "BRDF";
    :mod:`ebr_mitsuba.brdf`): ``f(l, v) = d/π + D(h) F(v·h) G(l, v) / (4 (n·l)(n·v))``, α = r², r
    clamped to [0.03, 1].

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Default
         - Meaning
       * - ``normal``
         - texture (RGB)
         - none (flat, +z)
         - Tangent-space normal (OpenGL +Y; x along the surface's u tangent, z out of the surface).
           Give the *signed* vector in [-1, 1]: a ``bitmap`` with ``raw=true`` holding an EXR /
           tensor of normals, or a constant ``<rgb value="x y z"/>``. Normals are renormalised
           (z clamped to ≥ 1e-4 first).
       * - ``normal_encoded``
         - boolean
         - false
         - The ``normal`` texture holds PNG-style ``(n + 1)/2`` values (load it with
           ``raw=true`` so no sRGB decoding happens); decoded as ``2v − 1``.
       * - ``diffuse``
         - texture (RGB) or float
         - 0.1
         - Diffuse albedo d, linear RGB in [0, 1].
       * - ``specular``
         - texture (RGB) or float
         - 0.2
         - Specular reflectance F₀ = s, linear RGB in [0, 1].
       * - ``roughness``
         - texture (1 channel) or float
         - 0.5
         - Roughness r in [0, 1]; α = r² (an RGB texture is read through ``eval_1``).
       * - ``fresnel``
         - string
         - ``schlick``
         - ``schlick``: F = s + (1 − s)(1 − v·h)⁵; ``none``: F = s (matches Mitsuba's
           ``roughconductor(material='none')``, for comparisons).

    The BSDF is one-sided (``FrontSide``): zero when the viewer or the light is below the surface
    (local z ≤ 0) or behind the shading normal. Sampling mixes GGX visible-normal sampling
    (component 0, ``GlossyReflection``) and cosine sampling (component 1, ``DiffuseReflection``),
    picked by the specular/diffuse luminance ratio; ``pdf`` is the mixture density. The
    ``BSDFContext`` type/component masks are not consulted: every call evaluates both lobes.
    Differentiable parameters (``mi.traverse``) are the textures' own (e.g. ``diffuse.data`` of a
    bitmap, ``roughness.value`` of a constant).

    XML (each example is loaded by ``tests/test_docs_xml.py``), with map files (each a
    ``texture`` element of type ``bitmap``; Mitsuba 3 has no shorthand element for it):

    ~~~xml
    <bsdf type="svbrdf" id="material">
        <texture type="bitmap" name="normal">
            <string name="filename" value="normal.exr"/>
            <boolean name="raw" value="true"/>
        </texture>
        <texture type="bitmap" name="diffuse">
            <string name="filename" value="diffuse.exr"/>
            <boolean name="raw" value="true"/>
        </texture>
        <texture type="bitmap" name="specular">
            <string name="filename" value="specular.exr"/>
            <boolean name="raw" value="true"/>
        </texture>
        <texture type="bitmap" name="roughness">
            <string name="filename" value="roughness.exr"/>
            <boolean name="raw" value="true"/>
        </texture>
    </bsdf>
    ~~~

    or with constant values:

    ~~~xml
    <bsdf type="svbrdf">
        <rgb name="diffuse" value="0.1"/>
        <float name="specular" value="0.2"/>
        <float name="roughness" value="0.3"/>
        <string name="fresnel" value="none"/>
    </bsdf>
    ~~~

    ``mi.load_dict``: ``{"type": "svbrdf", "normal": {"type": "bitmap", "data":
    mi.TensorXf(n_hw3), "raw": True}, "roughness": 0.3}``. Note that a bitmap's row 0 is v = 0
    (``docs/conventions.md``, "Geometry and pixel grid": it appears flipped vertically on the
    sample plane).
    """

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        self.normal = props.get_unbounded_texture("normal") if "normal" in props else None
        self.normal_encoded = bool(props.get("normal_encoded", False))
        self.diffuse = props.get_texture("diffuse", DEFAULT_DIFFUSE)
        self.specular = props.get_texture("specular", DEFAULT_SPECULAR)
        self.roughness = props.get_texture("roughness", DEFAULT_ROUGHNESS)
        self.fresnel = str(props.get("fresnel", "schlick"))
        if self.fresnel not in brdf.FRESNEL_MODES:
            raise ConfigError(
                f"svbrdf: 'fresnel' is {self.fresnel!r}; use one of {', '.join(brdf.FRESNEL_MODES)}"
            )
        base = mi.BSDFFlags.FrontSide | mi.BSDFFlags.SpatiallyVarying
        glossy = mi.BSDFFlags.GlossyReflection | base
        diffuse = mi.BSDFFlags.DiffuseReflection | base
        self.m_components = [glossy, diffuse]
        self.m_flags = glossy | diffuse

    def traverse(self, callback):
        flags = mi.ParamFlags.Differentiable
        if self.normal is not None:
            callback.put("normal", self.normal, flags)
        callback.put("diffuse", self.diffuse, flags)
        callback.put("specular", self.specular, flags)
        callback.put("roughness", self.roughness, flags)

    def parameters_changed(self, keys=None):
        pass  # the textures hold all state

    # -- maps ---------------------------------------------------------------------------------
    def shading_normal(self, si, active=True):
        """Unit shading normal (Vector3f) in the local frame of ``si``."""
        if self.normal is None:
            return mi.Vector3f(0.0, 0.0, 1.0)
        value = self.normal.eval(si, active)
        v = mi.Vector3f(value[0], value[1], value[2])
        if self.normal_encoded:
            v = 2.0 * v - 1.0
        return brdf.perturbed_normal(v)

    def _maps(self, si, active):
        n = self.shading_normal(si, active)
        d = self.diffuse.eval(si, active)
        s = self.specular.eval(si, active)
        r = self.roughness.eval_1(si, active)
        return n, d, s, r

    # -- BSDF interface -----------------------------------------------------------------------
    def eval(self, ctx, si, wo, active=True):
        n, d, s, r = self._maps(si, active)
        value = brdf.brdf_eval_cos(n, wo, si.wi, d, s, r, self.fresnel)
        return dr.select(active, value, 0.0)

    def pdf(self, ctx, si, wo, active=True):
        n, d, s, r = self._maps(si, active)
        return dr.select(active, brdf.brdf_pdf(n, wo, si.wi, d, s, r), 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        n, d, s, r = self._maps(si, active)
        value = brdf.brdf_eval_cos(n, wo, si.wi, d, s, r, self.fresnel)
        pdf = brdf.brdf_pdf(n, wo, si.wi, d, s, r)
        return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

    def sample(self, ctx, si, sample1, sample2, active=True):
        n, d, s, r = self._maps(si, active)
        wo, pdf, weight = brdf.brdf_sample(n, si.wi, d, s, r, sample1, sample2)
        if self.fresnel != "schlick":  # brdf_sample's weight uses Schlick Fresnel
            value = brdf.brdf_eval_cos(n, wo, si.wi, d, s, r, self.fresnel)
            weight = value / dr.select(pdf > 0.0, pdf, 1.0)
        ok = active & (pdf > 0.0)
        glossy = sample1 < brdf.specular_probability(d, s)
        bs = dr.zeros(mi.BSDFSample3f, dr.width(wo))
        bs.wo = wo
        bs.pdf = dr.select(ok, pdf, 0.0)
        bs.eta = 1.0
        bs.sampled_type = dr.select(
            glossy,
            mi.UInt32(int(mi.BSDFFlags.GlossyReflection)),
            mi.UInt32(int(mi.BSDFFlags.DiffuseReflection)),
        )
        bs.sampled_component = dr.select(glossy, mi.UInt32(COMPONENT_GLOSSY), mi.UInt32(COMPONENT_DIFFUSE))
        return bs, dr.select(ok, weight, 0.0)

    def eval_diffuse_reflectance(self, si, active=True):
        return self.diffuse.eval(si, active)

    def to_string(self):
        return f"SVBRDF[normal={'map' if self.normal is not None else 'flat'}, fresnel={self.fresnel}]"


def register() -> None:
    mi.register_bsdf("svbrdf", lambda props: SVBRDFBSDF(props))
