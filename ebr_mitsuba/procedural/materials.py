"""Procedural SVBRDF families: seeded, deterministic, tileable map sets (numpy only).

``make_material(family, seed, size=256, **params)`` returns an :class:`~ebr_mitsuba.svbrdf.SVBRDF`
of ``size × size`` pixels covering the sample square. Every parameter left out (``None``) is drawn
from ``np.random.default_rng(seed)``; the draws happen in a fixed order whether or not a
parameter is given, so overriding one parameter leaves the others as the seed chose them. The same
(family, seed, size, params) gives bit-identical maps; the same seed at another size gives the same
pattern (finer octaves skipped at small sizes). All maps tile seamlessly.

Physical ranges: dielectric F₀ is grey, ((n−1)/(n+1))² for n in 1.4–1.65 (0.028–0.06); metals
have a coloured F₀ from :data:`METALS` and a diffuse albedo ≤ 0.03 (grime only); normals come
from a height field in world units (the sample is 2 units wide) by central differences
(:mod:`.normals`), so their tilt does not depend on the resolution.

Families (parameters; ``color`` values are linear RGB triples in [0, 1]):

==========  =================================================================================
family      parameters (default: drawn from the seed)
==========  =================================================================================
tiles       ``style`` "tiles" | "bricks"; ``rows`` (int, tiles per side, 3–8 tiles / 6–14 bricks,
            even); ``grout`` (grout width / tile height, 0.03–0.25); ``color``;
            ``roughness`` (tile surface: glazed 0.08–0.3, bricks 0.6–0.9)
wood        ``planks`` (int, boards across, 1–6); ``rings`` (int, growth rings across the sample, 8–30);
            ``species`` "light" | "oak" | "walnut" | "cherry"; ``roughness`` (finish, 0.2–0.7)
metal       ``metal`` (a :data:`METALS` name); ``finish`` "brushed" | "scratched" | "hammered";
            ``scratches`` (int, 0–80); ``roughness`` (base, 0.08–0.55); ``tarnish`` (0–0.45: F₀ ×
            (1 − tarnish), oxidised or dull metal darker than the clean metal's F₀)
leather     ``cells`` (int, pebbles per side, 14–36); ``color``; ``depth`` (pebble height scale,
            0.4–1.5); ``roughness`` (0.35–0.7)
plaster     ``style`` "trowel" | "stucco" | "orange_peel"; ``color`` (paint);
            ``roughness`` (0.55–0.95); ``bump`` (height scale, 0.3–1.5)
fabric      ``threads`` (int, threads per side, 12–40, even); ``weave`` "plain" | "twill";
            ``warp_color``; ``weft_color``; ``roughness`` (0.7–1.0); twill rounds ``threads`` up to a
            multiple of 4 so the pattern tiles
marble      ``stone`` "carrara" | "marquina" | "verde" | "rosa" | "travertine"; ``veins``
            (int, vein bands per side, 1–4); ``turbulence`` (1–5); ``roughness`` (polish, 0.04–0.25)
painted     (paint chipping off metal, with rust) ``metal``; ``color`` (paint); ``coverage``
            (painted fraction, 0.3–0.9); ``rust`` (rusty fraction of the bare metal, 0–0.7)
==========  =================================================================================
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence

import numpy as np

from ..errors import InputError
from ..svbrdf import SVBRDF
from .color import hsv_to_rgb
from .noise import fbm, gradient_noise, grid, smoothstep, worley
from .normals import normals_from_height

#: Normal-incidence reflectance F₀ (linear sRGB) of metals, from physicallybased.info
#: (api.physicallybased.info/v2/materials, CC0; "color" of the metalness-1 entries, Gold's red
#: clipped from 1.059 to 1). Hard-coded so the toolkit does not need that file at run time.
METALS: dict[str, tuple[float, float, float]] = {
    "aluminum": (0.916, 0.923, 0.924),
    "brass": (0.910, 0.778, 0.423),
    "chromium": (0.654, 0.685, 0.701),
    "copper": (0.932, 0.623, 0.522),
    "gold": (1.000, 0.773, 0.307),
    "iron": (0.530, 0.513, 0.494),
    "nickel": (0.697, 0.641, 0.563),
    "platinum": (0.765, 0.730, 0.676),
    "silver": (0.991, 0.985, 0.974),
    "stainless_steel": (0.669, 0.639, 0.598),
    "titanium": (0.441, 0.400, 0.361),
    "zinc": (0.808, 0.844, 0.865),
}

# Dielectric albedo anchors (linear sRGB) from the same source: Brick, Terracotta, Marble,
# Concrete, Porcelain. The other palette entries are hand-picked, plausible linear albedos.
_BRICK = (0.262, 0.095, 0.061)
_TERRACOTTA = (0.555, 0.212, 0.11)
_MARBLE = (0.83, 0.791, 0.753)
_PORCELAIN = (0.745, 0.745, 0.723)

_TILE_COLORS = [
    _PORCELAIN,
    (0.75, 0.64, 0.48),
    (0.05, 0.12, 0.45),
    (0.05, 0.33, 0.34),
    (0.24, 0.38, 0.22),
    _TERRACOTTA,
    (0.03, 0.03, 0.03),
    (0.6, 0.4, 0.05),
]
_BRICK_COLORS = [_BRICK, _TERRACOTTA, (0.45, 0.33, 0.18), (0.25, 0.24, 0.22)]
_WOOD = {  # species: (early wood, late wood) albedo
    "light": ((0.56, 0.40, 0.22), (0.40, 0.25, 0.12)),
    "oak": ((0.42, 0.26, 0.12), (0.22, 0.12, 0.05)),
    "walnut": ((0.17, 0.09, 0.045), (0.07, 0.035, 0.018)),
    "cherry": ((0.36, 0.13, 0.065), (0.19, 0.06, 0.03)),
}
_LEATHER_COLORS = [
    (0.02, 0.02, 0.02),
    (0.09, 0.045, 0.02),
    (0.35, 0.18, 0.08),
    (0.18, 0.03, 0.03),
    (0.02, 0.03, 0.08),
    (0.2, 0.2, 0.2),
]
_PAINT_COLORS = [
    (0.8, 0.8, 0.78),
    (0.82, 0.76, 0.62),
    (0.5, 0.5, 0.5),
    (0.6, 0.5, 0.35),
    (0.45, 0.55, 0.7),
    (0.4, 0.5, 0.35),
    (0.55, 0.3, 0.18),
    (0.7, 0.45, 0.45),
]
_MARBLE_STONES = {  # stone: (base, vein) albedo
    "carrara": (_MARBLE, (0.25, 0.25, 0.27)),
    "marquina": ((0.02, 0.02, 0.022), (0.7, 0.7, 0.68)),
    "verde": ((0.02, 0.1, 0.05), (0.5, 0.6, 0.5)),
    "rosa": ((0.6, 0.35, 0.3), (0.82, 0.72, 0.66)),
    "travertine": ((0.55, 0.45, 0.32), (0.33, 0.24, 0.14)),
}
_RUST = ((0.35, 0.12, 0.04), (0.16, 0.05, 0.02))


def _f0(ior: float) -> float:
    return ((ior - 1.0) / (ior + 1.0)) ** 2


class _Params:
    """Draws every parameter from the seed in a fixed order; a given value replaces the draw."""

    def __init__(self, family: str, rng: np.random.Generator):
        self.family = family
        self.rng = rng

    def _bad(self, name, value, what):
        return InputError(f"procedural material '{self.family}': {name}={value!r} is invalid; give {what}")

    def number(self, name, given, lo, hi, draw=None):
        a, b = draw if draw is not None else (lo, hi)
        drawn = float(self.rng.uniform(a, b))
        if given is None:
            return drawn
        try:
            val = float(given)
        except (TypeError, ValueError):
            raise self._bad(name, given, f"a number in [{lo}, {hi}]") from None
        if not (lo <= val <= hi):
            raise self._bad(name, given, f"a number in [{lo}, {hi}]")
        return val

    def integer(self, name, given, lo, hi, draw=None, even=False):
        a, b = draw if draw is not None else (lo, hi)
        drawn = int(self.rng.integers(a, b + 1))
        if even:
            drawn += drawn % 2
        if given is None:
            return drawn
        ok = isinstance(given, (int, np.integer)) and not isinstance(given, bool) and lo <= given <= hi
        if not ok or (even and given % 2):
            raise self._bad(name, given, f"{'an even' if even else 'an'} integer in [{lo}, {hi}]")
        return int(given)

    def choice(self, name, given, options: Sequence[str], p=None):
        drawn = options[int(self.rng.choice(len(options), p=p))]
        if given is None:
            return drawn
        if given not in options:
            raise self._bad(name, given, "one of " + ", ".join(options))
        return given

    def color(self, name, given, palette: Sequence[Sequence[float]], jitter: float = 0.1):
        base = np.asarray(palette[int(self.rng.integers(len(palette)))], dtype=np.float64)
        drawn = np.clip(base * (1.0 + jitter * self.rng.uniform(-1.0, 1.0, 3)), 0.0, 1.0)
        if given is None:
            return drawn
        try:
            val = np.asarray(given, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            val = np.zeros(0)
        if val.shape != (3,) or not np.all((val >= 0) & (val <= 1)):
            raise self._bad(name, given, "a linear RGB triple with values in [0, 1]")
        return val


def _svbrdf(height, diffuse, specular, roughness, source) -> SVBRDF:
    return SVBRDF(
        normal=normals_from_height(height, wrap=True),
        diffuse=np.clip(diffuse, 0.0, 1.0).astype(np.float32),
        specular=np.clip(specular, 0.0, 1.0).astype(np.float32),
        roughness=np.clip(roughness, 0.0, 1.0).astype(np.float32),
        source=source,
    )


def _grey(value, shape) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=np.float64)[..., None], (*shape, 3)) + np.zeros(3)


# -- families ----------------------------------------------------------------------------------


def tiles(rng, size, *, style=None, rows=None, grout=None, color=None, roughness=None, source=""):
    """Ceramic tiles or bricks in running bond, separated by recessed, rough grout."""
    p = _Params("tiles", rng)
    style = p.choice("style", style, ("tiles", "bricks"))
    bricks = style == "bricks"
    rows = p.integer("rows", rows, 2, 32, draw=(6, 13) if bricks else (3, 8), even=bricks)
    grout = p.number("grout", grout, 0.0, 0.5, draw=(0.03, 0.08) if bricks else (0.06, 0.25))
    color = p.color("color", color, _BRICK_COLORS if bricks else _TILE_COLORS, jitter=0.15)
    roughness = p.number("roughness", roughness, 0.0, 1.0, draw=(0.6, 0.9) if bricks else (0.08, 0.3))
    grout_color = rng.uniform(0.25, 0.6) * (1.0 + 0.05 * rng.uniform(-1, 1, 3))
    columns = max(1, rows // 2) if bricks else rows
    per_tile = rng.uniform(-1.0, 1.0, size=(rows, columns, 4))
    u, v = grid(size)
    max_freq = size / 2
    surface = fbm(u, v, rng, freq=8, octaves=5, max_freq=max_freq)
    blotch = fbm(u, v, rng, freq=3, octaves=3, max_freq=max_freq)
    sand = fbm(u, v, rng, freq=32, octaves=3, kind="value", max_freq=max_freq)

    ry = v * rows
    row = np.floor(ry).astype(np.int64) % rows
    cx = u * columns + np.where(bricks & (row % 2 == 1), 0.5, 0.0)
    col = np.floor(cx).astype(np.int64) % columns
    fx = cx - np.floor(cx)
    fy = ry - np.floor(ry)
    aspect = rows / columns  # tile width / tile height
    edge = np.minimum(np.minimum(fx, 1.0 - fx) * aspect, np.minimum(fy, 1.0 - fy))  # tile heights
    half = 0.5 * grout
    bevel = 0.04 + 0.3 * grout
    mask = smoothstep(half, half + bevel, edge)
    tile_h = 2.0 / rows  # world units
    rand = per_tile[row, col]

    bump_tile = (0.004 if bricks else 0.0008) * surface
    height = tile_h * (0.06 * mask + 0.02 * (1 - mask) * sand) + mask * (bump_tile + 0.004 * rand[..., 3])
    tile_rgb = color * (
        1.0
        + (0.25 if bricks else 0.08) * rand[..., :3].mean(-1, keepdims=True)
        + 0.06 * rand[..., :3]
        + (0.15 if bricks else 0.04) * blotch[..., None]
    )
    grout_rgb = grout_color * (1.0 + 0.25 * sand[..., None])
    diffuse = mask[..., None] * tile_rgb + (1 - mask[..., None]) * grout_rgb
    spec_tile = _f0(1.5 if bricks else 1.55)
    specular = _grey(mask * spec_tile + (1 - mask) * _f0(1.5), mask.shape)
    rough_tile = roughness * (1.0 + 0.15 * rand[..., 3] + (0.1 if bricks else 0.05) * surface)
    rough = mask * rough_tile + (1 - mask) * (0.9 + 0.05 * sand)
    return _svbrdf(height, diffuse, specular, rough, source)


def wood(rng, size, *, planks=None, rings=None, species=None, roughness=None, source=""):
    """Planks of wood: warped growth rings, fibre streaks, pores and seams between boards."""
    p = _Params("wood", rng)
    planks = p.integer("planks", planks, 1, 16, draw=(1, 6))
    rings = p.integer("rings", rings, 1, 80, draw=(8, 30))
    species = p.choice("species", species, tuple(_WOOD))
    roughness = p.number("roughness", roughness, 0.0, 1.0, draw=(0.2, 0.7))
    tint = 1.0 + 0.08 * rng.uniform(-1, 1, 3)
    per_plank = rng.uniform(0.0, 1.0, size=(planks, 3))
    bend = rng.uniform(1.5, 4.0)  # how many ring periods the grain wanders
    u, v = grid(size)
    max_freq = size / 2
    warp = fbm(u, v, rng, freq=(1, 2), octaves=3, max_freq=max_freq)
    wobble = fbm(u, v, rng, freq=(3, 12), octaves=3, max_freq=max_freq)
    fibre = fbm(u, v, rng, freq=(2, 48), octaves=3, max_freq=max_freq)
    pores = gradient_noise(u, v, (24, 160), rng) if 160 <= max_freq else np.zeros_like(u)
    tone = fbm(u, v, rng, freq=(1, 4), octaves=2, max_freq=max_freq)

    pv = v * planks
    plank = np.floor(pv).astype(np.int64) % planks
    fv = pv - np.floor(pv)
    offs = per_plank[plank]
    w = rings * v + bend * (warp + offs[..., 2]) + 0.3 * wobble + offs[..., 0] * rings
    ring = w - np.floor(w)
    late = smoothstep(0.6, 0.96, ring) * (1.0 - smoothstep(0.96, 1.0, ring))
    early, late_rgb = (np.asarray(c) for c in _WOOD[species])
    shade = 1.0 + 0.12 * fibre + 0.1 * (offs[..., 1] - 0.5) + 0.08 * tone
    diffuse = (early * (1 - late[..., None]) + late_rgb * late[..., None]) * shade[..., None] * tint
    pore = smoothstep(0.45, 0.8, pores) * (0.4 + 0.6 * late)
    diffuse *= (1.0 - 0.35 * pore)[..., None]
    seam = 1.0 - smoothstep(0.0, 0.012 * planks, np.minimum(fv, 1.0 - fv)) if planks > 1 else 0.0 * u
    diffuse *= (1.0 - 0.6 * seam)[..., None]
    height = 0.0008 * late + 0.0008 * fibre - 0.0012 * pore - 0.012 * seam
    specular = _grey(np.full(u.shape, _f0(1.5)), u.shape)
    rough = roughness * (1.0 + 0.25 * pore + 0.1 * fibre) + 0.3 * seam
    return _svbrdf(height, diffuse, specular, rough, source)


def _segments(u, v, rng, count, size):
    """Periodic thin scratches: returns (size, size) groove depth in [0, 1].

    Each scratch is evaluated only in its (wrapped) bounding box, 5 widths beyond its ends.
    """
    out = np.zeros_like(u)
    main = rng.uniform(0.0, np.pi)
    params = rng.uniform(0.0, 1.0, size=(count, 5))
    width = 1.2 / size  # about one pixel
    for cu, cv, a, length, depth in params:
        angle = main + 0.35 * (a - 0.5) if a < 0.8 else np.pi * a  # mostly one direction
        ca, sa = np.cos(angle), np.sin(angle)
        half = 0.03 + 0.2 * length
        reach_u = half * abs(ca) + 5 * width
        reach_v = half * abs(sa) + 5 * width
        cols = np.arange(int(np.floor((cu - reach_u) * size)), int(np.ceil((cu + reach_u) * size)) + 1)
        rows = np.arange(int(np.floor((cv - reach_v) * size)), int(np.ceil((cv + reach_v) * size)) + 1)
        cols = np.unique(cols % size)
        rows = np.unique(rows % size)
        win = np.ix_(rows, cols)
        du = (u[win] - cu + 0.5) % 1.0 - 0.5
        dv = (v[win] - cv + 0.5) % 1.0 - 0.5
        t = np.clip(du * ca + dv * sa, -half, half)
        dist = np.hypot(du - t * ca, dv - t * sa)
        taper = 1.0 - (t / half) ** 2
        out[win] = np.maximum(out[win], (0.3 + 0.7 * depth) * taper * np.exp(-0.5 * (dist / width) ** 2))
    return out


def metal(rng, size, *, metal=None, finish=None, scratches=None, roughness=None, tarnish=None, source=""):
    """Bare metal, brushed, scratched or hammered; coloured F₀, near-black diffuse (grime)."""
    p = _Params("metal", rng)
    name = p.choice("metal", metal, tuple(METALS))
    finish = p.choice("finish", finish, ("brushed", "scratched", "hammered"))
    scratches = p.integer("scratches", scratches, 0, 400, draw=(0, 80))
    roughness = p.number("roughness", roughness, 0.0, 1.0, draw=(0.08, 0.55))
    tarnish = p.number("tarnish", tarnish, 0.0, 0.9, draw=(0.0, 0.45))
    u, v = grid(size)
    max_freq = size / 2
    brush = fbm(u, v, rng, freq=(1, 64), octaves=3, max_freq=max_freq)
    grime = fbm(u, v, rng, freq=3, octaves=5, max_freq=max_freq)
    dent_cells = int(rng.integers(6, 14))
    dents = worley(u, v, dent_cells, rng, jitter=0.9)
    scratch = _segments(u, v, rng, scratches, size)

    grime_mask = smoothstep(0.25, 0.7, grime)
    f0 = np.asarray(METALS[name]) * (1.0 - tarnish) * (1.0 - 0.25 * grime_mask[..., None])
    diffuse = _grey(0.03 * grime_mask, u.shape) * np.array([1.0, 0.9, 0.8])
    if finish == "brushed":
        height = 0.0008 * brush
        rough = roughness * (1.0 + 0.3 * brush)
    elif finish == "hammered":
        height = 0.12 * (2.0 / dent_cells) * np.minimum(dents.f1, 1.0) ** 2  # bowls around points
        rough = roughness * (1.0 + 0.2 * (dents.f2 - dents.f1))
    else:
        height = 0.0002 * brush
        rough = np.full(u.shape, roughness)
    height = height - 0.002 * scratch
    rough = rough + 0.15 * scratch + 0.25 * grime_mask
    return _svbrdf(height, diffuse, f0, rough, source)


def leather(rng, size, *, cells=None, color=None, depth=None, roughness=None, source=""):
    """Pebbled leather: warped cellular pebbles with darker, rougher creases between them."""
    p = _Params("leather", rng)
    cells = p.integer("cells", cells, 2, 128, draw=(14, 36))
    color = p.color("color", color, _LEATHER_COLORS, jitter=0.2)
    depth = p.number("depth", depth, 0.0, 5.0, draw=(0.4, 1.5))
    roughness = p.number("roughness", roughness, 0.0, 1.0, draw=(0.35, 0.7))
    u, v = grid(size)
    max_freq = size / 2
    wu = fbm(u, v, rng, freq=4, octaves=3, max_freq=max_freq)
    wv = fbm(u, v, rng, freq=4, octaves=3, max_freq=max_freq)
    c = worley(u + 0.5 / cells * wu, v + 0.5 / cells * wv, cells, rng, jitter=0.9)
    c2 = worley(u + 0.5 / cells * wv, v + 0.5 / cells * wu, 2 * cells + 1, rng, jitter=0.9)
    fine = fbm(u, v, rng, freq=64, octaves=2, max_freq=max_freq)
    mottle = fbm(u, v, rng, freq=5, octaves=4, max_freq=max_freq)

    border = c.f2 - c.f1  # 0 on the crease between pebbles
    dome = 1.0 - (1.0 - np.minimum(border / 0.7, 1.0)) ** 2  # rounded pebble profile
    sub = 1.0 - (1.0 - np.minimum((c2.f2 - c2.f1) / 0.5, 1.0)) ** 2
    crease = 1.0 - smoothstep(0.0, 0.2, border)
    cell_size = 2.0 / cells
    height = depth * cell_size * (0.12 * dome + 0.03 * sub + 0.004 * fine)
    diffuse = color * ((1.0 - 0.35 * crease) * (1.0 + 0.15 * mottle) * (0.9 + 0.1 * sub))[..., None]
    specular = _grey(np.full(u.shape, _f0(1.45)) * (1.0 - 0.3 * crease), u.shape)
    rough = roughness * (1.0 + 0.35 * crease + 0.08 * fine)
    return _svbrdf(height, diffuse, specular, rough, source)


def plaster(rng, size, *, style=None, color=None, roughness=None, bump=None, source=""):
    """Painted plaster: trowelled swirls, knock-down stucco plateaus or orange-peel paint."""
    p = _Params("plaster", rng)
    style = p.choice("style", style, ("trowel", "stucco", "orange_peel"))
    color = p.color("color", color, _PAINT_COLORS, jitter=0.08)
    roughness = p.number("roughness", roughness, 0.0, 1.0, draw=(0.55, 0.95))
    bump = p.number("bump", bump, 0.0, 5.0, draw=(0.3, 1.5))
    u, v = grid(size)
    max_freq = size / 2
    broad = fbm(u, v, rng, freq=3, octaves=6, max_freq=max_freq)
    blobs = fbm(u, v, rng, freq=6, octaves=5, max_freq=max_freq)
    peel = fbm(u, v, rng, freq=24, octaves=3, max_freq=max_freq)
    stain = fbm(u, v, rng, freq=2, octaves=4, max_freq=max_freq)

    if style == "trowel":
        height = 0.01 * broad + 0.004 * np.abs(blobs)
        flat = smoothstep(0.0, 0.3, np.abs(blobs))
    elif style == "stucco":
        flat = smoothstep(0.0, 0.08, blobs)
        height = 0.012 * flat + 0.002 * peel
    else:
        flat = 0.5 + 0.5 * peel
        height = 0.003 * peel + 0.002 * broad
    height = bump * height
    diffuse = color * (1.0 + 0.05 * stain + 0.03 * blobs)[..., None]
    specular = _grey(np.full(u.shape, _f0(1.5)), u.shape)
    rough = roughness * (1.0 - 0.15 * flat + 0.05 * peel)
    return _svbrdf(height, diffuse, specular, rough, source)


def _dyed(rng) -> np.ndarray:
    hsv = np.array([rng.uniform(), rng.uniform(0.3, 0.9), rng.uniform(0.05, 0.6)])
    return hsv_to_rgb(hsv)


def fabric(
    rng, size, *, threads=None, weave=None, warp_color=None, weft_color=None, roughness=None, source=""
):
    """Woven cloth (plain or 2/2 twill) of round threads with fibre streaks; rough, low F₀."""
    p = _Params("fabric", rng)
    threads = p.integer("threads", threads, 2, 512, draw=(12, 40), even=True)
    weave = p.choice("weave", weave, ("plain", "twill"))
    warp_drawn = _dyed(rng)
    same = rng.uniform() < 0.5
    weft_drawn = warp_drawn * rng.uniform(0.6, 0.9) if same else _dyed(rng)
    warp_color = p.color("warp_color", warp_color, [warp_drawn], jitter=0.0)
    weft_color = p.color("weft_color", weft_color, [weft_drawn], jitter=0.0)
    roughness = p.number("roughness", roughness, 0.0, 1.0, draw=(0.7, 1.0))
    if weave == "twill" and threads % 4:
        threads += 2  # the twill repeat is 4 threads: keep the pattern tileable
    u, v = grid(size)
    max_freq = size / 2
    fibre_u = fbm(u, v, rng, freq=(threads // 2, 4 * threads), octaves=2, max_freq=max_freq)
    fibre_v = fbm(u, v, rng, freq=(4 * threads, threads // 2), octaves=2, max_freq=max_freq)
    slub = fbm(u, v, rng, freq=4, octaves=3, max_freq=max_freq)

    x = u * threads
    y = v * threads
    ci = np.floor(x).astype(np.int64)  # warp thread (runs along v) index
    rj = np.floor(y).astype(np.int64)  # weft thread (runs along u) index
    fx = x - ci
    fy = y - rj
    over = (ci + rj) % 2 == 0 if weave == "plain" else (ci - rj) % 4 < 2
    sign = np.where(over, 1.0, -1.0)
    prof_x = np.sqrt(np.clip(1.0 - (2.0 * fx - 1.0) ** 2, 0.0, 1.0))
    prof_y = np.sqrt(np.clip(1.0 - (2.0 * fy - 1.0) ** 2, 0.0, 1.0))
    z_warp = 0.5 * prof_x + 0.35 * sign * np.sin(np.pi * fy) + 0.05 * fibre_v
    z_weft = 0.5 * prof_y - 0.35 * sign * np.sin(np.pi * fx) + 0.05 * fibre_u
    on_warp = smoothstep(-0.05, 0.05, z_warp - z_weft)
    thread = 2.0 / threads
    height = 0.25 * thread * np.maximum(z_warp, z_weft)
    shade_warp = (0.55 + 0.45 * prof_x) * (1.0 + 0.15 * fibre_v)
    shade_weft = (0.55 + 0.45 * prof_y) * (1.0 + 0.15 * fibre_u)
    diffuse = (
        on_warp[..., None] * warp_color * shade_warp[..., None]
        + (1 - on_warp[..., None]) * weft_color * shade_weft[..., None]
    )
    diffuse *= (1.0 + 0.08 * slub)[..., None]
    specular = _grey(np.full(u.shape, _f0(1.45)), u.shape)
    rough = roughness * (1.0 + 0.05 * (fibre_u + fibre_v))
    return _svbrdf(height, diffuse, specular, rough, source)


def marble(rng, size, *, stone=None, veins=None, turbulence=None, roughness=None, source=""):
    """Polished marble: turbulent sine veins (a main and a finer system) over a clouded base."""
    p = _Params("marble", rng)
    stone = p.choice("stone", stone, tuple(_MARBLE_STONES))
    veins = p.integer("veins", veins, 1, 16, draw=(1, 4))
    turbulence = p.number("turbulence", turbulence, 0.0, 10.0, draw=(1.0, 5.0))
    roughness = p.number("roughness", roughness, 0.0, 1.0, draw=(0.04, 0.25))
    ku, kv = [int(k) for k in rng.integers(0, 3, size=2)]
    ku = ku if (ku or kv) else 1
    sharp = rng.uniform(6.0, 30.0)
    u, v = grid(size)
    max_freq = size / 2
    turb = fbm(u, v, rng, freq=2, octaves=7, max_freq=max_freq)
    turb2 = fbm(u, v, rng, freq=4, octaves=6, max_freq=max_freq)
    cloud = fbm(u, v, rng, freq=3, octaves=5, max_freq=max_freq)
    grain = fbm(u, v, rng, freq=64, octaves=2, kind="value", max_freq=max_freq)

    t1 = veins * (ku * u + kv * v) + 0.35 * turbulence * turb
    t2 = 3 * veins * (kv * u - ku * v) + 0.5 * turbulence * turb2
    vein1 = (1.0 - np.abs(np.sin(np.pi * t1))) ** sharp
    vein2 = (1.0 - np.abs(np.sin(np.pi * t2))) ** (2.0 * sharp)
    vein = np.clip(vein1 + 0.5 * vein2, 0.0, 1.0)
    base, vein_rgb = (np.asarray(c) for c in _MARBLE_STONES[stone])
    base_rgb = base * (1.0 + 0.12 * cloud + 0.03 * grain)[..., None]
    diffuse = base_rgb * (1 - vein[..., None]) + vein_rgb * vein[..., None]
    height = -0.0005 * vein + 0.0001 * grain
    specular = _grey(np.full(u.shape, _f0(1.6)), u.shape)
    rough = roughness * (1.0 + 0.5 * vein + 0.1 * grain)
    return _svbrdf(height, diffuse, specular, rough, source)


def painted(rng, size, *, metal=None, color=None, coverage=None, rust=None, source=""):
    """Paint chipping off metal: glossy paint (dielectric), bare metal edges, rough rust patches."""
    p = _Params("painted", rng)
    name = p.choice("metal", metal, ("iron", "stainless_steel", "aluminum", "zinc", "copper"))
    color = p.color("color", color, _PAINT_COLORS + _TILE_COLORS[2:5], jitter=0.1)
    coverage = p.number("coverage", coverage, 0.0, 1.0, draw=(0.3, 0.9))
    rust = p.number("rust", rust, 0.0, 1.0, draw=(0.0, 0.7))
    paint_rough = rng.uniform(0.2, 0.55)
    u, v = grid(size)
    max_freq = size / 2
    chip = fbm(u, v, rng, freq=4, octaves=7, max_freq=max_freq)
    rust_n = fbm(u, v, rng, freq=6, octaves=6, max_freq=max_freq)
    pits = fbm(u, v, rng, freq=48, octaves=2, max_freq=max_freq)

    # thresholds from the noise's empirical spread (≈ ±0.35): map the fraction to a level
    level = np.quantile(chip, 1.0 - coverage) if 0.0 < coverage < 1.0 else (-9.0 if coverage >= 1 else 9.0)
    paint = smoothstep(level - 0.01, level + 0.01, chip)
    rlevel = np.quantile(rust_n, 1.0 - rust) if 0.0 < rust < 1.0 else (-9.0 if rust >= 1 else 9.0)
    rusty = (1.0 - paint) * smoothstep(rlevel - 0.05, rlevel + 0.05, rust_n)
    bare = (1.0 - paint) * (1.0 - rusty)
    rust_rgb = (
        np.asarray(_RUST[0]) * (1 - smoothstep(-0.3, 0.3, pits))[..., None]
        + np.asarray(_RUST[1]) * smoothstep(-0.3, 0.3, pits)[..., None]
    )
    diffuse = paint[..., None] * color * (1.0 + 0.04 * pits)[..., None] + rusty[..., None] * rust_rgb
    spec = (paint[..., None] + rusty[..., None]) * _f0(1.5) + bare[..., None] * np.asarray(METALS[name])
    height = 0.003 * paint - 0.001 * rusty * (0.5 + 0.5 * pits) + 0.0002 * pits
    rough = paint * paint_rough + rusty * 0.85 + bare * (0.3 + 0.1 * pits)
    return _svbrdf(height, diffuse, spec, rough, source)


#: Family name → generator ``f(rng, size, **params) -> SVBRDF`` (see the module docstring).
FAMILIES: dict[str, Callable[..., SVBRDF]] = {
    "tiles": tiles,
    "wood": wood,
    "metal": metal,
    "leather": leather,
    "plaster": plaster,
    "fabric": fabric,
    "marble": marble,
    "painted": painted,
}


def family_parameters(family: str) -> tuple[str, ...]:
    """Names of the parameters a family accepts."""
    gen = _family(family)
    return tuple(
        name
        for name, par in inspect.signature(gen).parameters.items()
        if par.kind is inspect.Parameter.KEYWORD_ONLY and name != "source"
    )


def _family(family: str):
    gen = FAMILIES.get(family)
    if gen is None:
        raise InputError(
            f"unknown procedural material family {family!r}; choose one of {', '.join(FAMILIES)}"
        )
    return gen


def make_material(family: str, seed: int, size: int = 256, **params) -> SVBRDF:
    """A ``size × size`` SVBRDF of ``family`` drawn from ``seed`` (see the module docstring).

    Raises :class:`InputError` for an unknown family (listing the families), an unknown parameter
    (listing the family's parameters), a bad value, a negative seed or a size outside [4, 8192].
    """
    gen = _family(family)
    allowed = family_parameters(family)
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        raise InputError(
            f"procedural material '{family}': unknown parameter(s) {', '.join(unknown)}; "
            f"it accepts {', '.join(allowed)}"
        )
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"procedural material '{family}': seed {seed!r} must be an integer >= 0")
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 4 <= size <= 8192:
        raise InputError(f"procedural material '{family}': size {size!r} must be an integer in [4, 8192]")
    rng = np.random.default_rng(int(seed))
    return gen(rng, int(size), source=f"procedural:{family}:{int(seed)}", **params)
