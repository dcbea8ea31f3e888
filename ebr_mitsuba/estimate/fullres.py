"""Full-resolution maps: the cascade over the whole working image, the lighting from the grid.

The networks were trained on whole captures at the model grid G (the flash highlight at the frame
centre, the camera of docs/conventions.md#geometry-and-pixel-grid). An N×N working image (N > G)
is estimated as one capture:

1. **Lighting, once** (:meth:`~ebr_mitsuba.model.predictor.StagedPredictor.predict_lighting`, at
   G): lighting net, SG extraction, exemplar selection. Nothing of it is repeated per tile.
2. **A grid pass** of the cascade (the whole capture at G): the capture's flash scale ``k``
   (least squares of the flash-only image against the coarse maps' flash render, fitted once and
   given to every part; the refinement net's inputs depend on it).
3. **The cascade's inputs at N** (:func:`full_pass_inputs`), each pixel with its true geometry:

   * environment exemplars rendered at N with the fast renderer's closed form, per-pixel view
     directions, at the selected roughness values; their low frequencies corrected to the grid
     exemplars of the model's training render mode (quadrature):
     ``ex_N = sg_N · up((ex_G + ε)/(down(sg_N) + ε))``;
   * point-light exemplars rendered at N (exact);
   * the flash-only image: the lighting net's (at G) for the low frequencies, the photos'
     ``max(flash − no-flash, 0)`` at N for the detail (:func:`detail_merge`);
   * the photos at N.

4. **One pass at N** where memory allows (:data:`PASS_MEMORY` bytes, :func:`pass_bytes`), else
   overlapping tiles (:func:`tile_plan`, raised-cosine blending of :mod:`.tiling`). Every tile
   gets the same lighting, exemplars and flash scale, and its renders (the diffuse flash render of
   the specular image, the photo renders of the refinement net's residuals) shade its pixels at
   their positions in the full frame (``window``), so a tile sees the inputs of the full pass.
   The networks run through :class:`.fastnet.FastNAFNet`.

5. **A scale ensemble** (:func:`ensemble_sizes`): the same pass at N/2 and N/4 (sizes at least
   the grid; the grid pass itself when N ≤ 4G), each upsampled (bilinear) to N; the maps are the
   mean of the passes (normals as vectors, renormalised).
6. **Specular and roughness below the grid's frequency from the grid pass**
   (:func:`low_frequencies_from`): ``up(grid) + ens − up(down(ens))`` for those two maps.

Why 5 and 6 (measured on two 1024² Mitsuba captures, ``procedural:tiles:1`` / ``procedural:3``
and ``procedural:wood:3`` / ``procedural:7``; mean per-map RMSE against the truth). A network
trained at G sees at N = 16G every feature 16× larger than in training. Its diffuse and normal
maps, local properties, gain detail with N (wood: diffuse RMSE 0.045 at 64², 0.020 at 512²), but
specular and roughness are read from the shape of the flash highlight and of the reflections over
the whole frame, which only a pass at the grid sees as in training: the wood's roughness RMSE
grows from 0.083 (64²) to 0.22–0.28 (128²–1024²); on the tiles it varies at random with the
scale (0.30–0.33). The mean of the passes at N, N/2, N/4 removes part of that scatter (tiles at
1024²: 0.123 for the single pass → 0.112) and the grid's low frequencies remove the drift (wood
at 1024²: 0.091 → 0.086 → 0.039); together 1024² is the better estimate on both captures
(tiles 0.121 against 0.122 at 256², wood 0.039 against 0.041). The two smaller passes cost
1/4 + 1/16 of the full one.

Taking all four maps' low frequencies from the grid pass (what the former tiled estimate did)
loses the diffuse gain (tiles at 1024²: 0.125).

Speed (2 cores): the grid pass runs on one torch thread (a 64² pass gains nothing from two, and
on a loaded machine two threads waiting on each other took 3 s instead of 0.1 s); the passes'
maps are upsampled and summed as one (1, 10, N, N) tensor (:class:`_Ensemble`) and checked as an
:class:`~ebr_mitsuba.svbrdf.SVBRDF` once, at the end; importing this module asks PyTorch to put
its large CPU tensors on transparent huge pages (:func:`_huge_pages`).
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from ..imageio import resize_area, upsample_bilinear_fast
from ..model.predictor import Lighting, PassInputs, StagedPredictor
from ..sgenv import SGEnvironment
from ..svbrdf import SVBRDF
from .tiling import DEFAULT_OVERLAP, ramp, tile_starts

IRRADIANCE_TABLE = 64  # RenderOptions.irradiance_table of the cascade's environment renders at N
PASS_MEMORY = 1.5e9  # bytes one full-resolution network pass may take before tiles are used
BYTES_PER_PIXEL_CHANNEL = (
    4 * 14
)  # measured peak of a FastNAFNet pass: ≈ 14 float32 per pixel and width channel
TILE_MULTIPLE = 16  # tile sides are multiples of this (2^levels of the shipped networks' padding)
ENSEMBLE = 3  # pass sizes averaged into the maps: N, N/2, N/4 (at least the grid)
THP_ENV = "THP_MEM_ALLOC_ENABLE"  # PyTorch's switch for transparent huge pages of CPU tensors


def _huge_pages() -> None:
    """Ask PyTorch's CPU allocator for transparent huge pages (``THP_MEM_ALLOC_ENABLE=1``, read
    once when torch is imported; no effect once it is, or where the kernel has THP off). The
    networks at N allocate hundreds of fresh tensors of 32–64 MB: on 4 KB pages each costs 8192
    page faults, half the time of an elementwise pass over it (1 Mpx × 8 channels: 31 ms → 16 ms;
    a 1024² ``predict_maps`` about 10 % less CPU time). An explicit setting is kept."""
    if "torch" not in sys.modules:
        os.environ.setdefault(THP_ENV, "1")


_huge_pages()


@contextlib.contextmanager
def torch_threads(count: int) -> Iterator[None]:
    """torch's intra-op thread count set to ``count`` within the block (restored after)."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def detail_merge(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """``up(low) + high − up(down(high))``, clipped at 0: ``low`` (g, g, C) gives the low
    frequencies, ``high`` (N, N, C) the detail above the grid's frequency (area ``down``, bilinear
    ``up``); with N = g the result is ``low``."""
    n, g = high.shape[:2], low.shape[:2]
    if n == g:
        return np.asarray(low, np.float32)
    up = upsample_bilinear_fast(np.asarray(low, np.float32) - resize_area(high, g), n)
    return np.maximum(up + high, 0.0, out=up)


def env_exemplars_at(env: SGEnvironment | None, roughness, grid_images: np.ndarray, size: int) -> np.ndarray:
    """Environment exemplars (K, N, N, 3) at ``size`` N: the closed-form render at N corrected to
    the grid exemplars ``grid_images`` (K, G, G, 3) in their low frequencies (module docstring)."""
    import drjit as dr

    from ..exemplar.images import exemplar_images
    from ..render import RenderOptions

    k, g = grid_images.shape[0], grid_images.shape[1]
    if env is None or env.num_lobes == 0:
        return np.zeros((k, size, size, 3), np.float32)
    if size == g:
        return np.asarray(grid_images, np.float32)
    with dr.suspend_grad():
        images = exemplar_images(env, list(roughness), size, size, options=RenderOptions(lobe_loop=True))
        sg = np.stack([np.asarray(im.numpy(), np.float32) for im in images])
    for i in range(k):
        eps = 1e-3 * float(np.mean(grid_images[i])) + 1e-12
        ratio = (grid_images[i].astype(np.float64) + eps) / (resize_area(sg[i], (g, g)) + eps)
        sg[i] *= upsample_bilinear_fast(ratio, (size, size))
    return sg


def point_exemplars_at(roughness, size: int) -> np.ndarray:
    """Point-light exemplars (K, N, N, 3) at ``size`` N (the exemplar material under the near
    flash alone, exact; the same renders as :func:`ebr_mitsuba.exemplar.images.point_exemplar_images`
    without building the uniform maps in numpy)."""
    import drjit as dr
    import mitsuba as mi

    from ..exemplar import EXEMPLAR_DIFFUSE, EXEMPLAR_SPECULAR
    from ..geometry import near_shot
    from ..render import DrLobes, DrMaps, render

    count = size * size
    shot = near_shot(True, env=False)

    def const(value: float, channels: int):
        return mi.TensorXf(dr.opaque(mi.Float, float(value), count * channels), (size, size, channels))

    normal = mi.TensorXf(dr.ravel(mi.Vector3f(0.0, 0.0, 1.0) + dr.zeros(mi.Vector3f, count)), (size, size, 3))
    no_lobes = DrLobes.from_env(SGEnvironment.empty())
    out = np.empty((len(roughness), size, size, 3), np.float32)
    with dr.suspend_grad():
        for i, r in enumerate(roughness):
            maps = DrMaps(normal, const(EXEMPLAR_DIFFUSE, 3), const(EXEMPLAR_SPECULAR, 3), const(r, 1))
            out[i] = render(maps, no_lobes, shot).numpy()
    return out


def full_pass_inputs(lighting: Lighting, photos: dict[str, np.ndarray], num_photos: int) -> PassInputs:
    """The cascade's :class:`~ebr_mitsuba.model.predictor.PassInputs` at the photos' size N
    (module docstring, step 3). ``photos``: shot name → (N, N, 3); ``num_photos``: 2 or 4 (the
    cascade's P)."""
    flash = photos["flash"]
    n = flash.shape[0]
    if "noflash" in photos:
        nf = photos["noflash"]
        fo = detail_merge(lighting.flash_only, np.maximum(flash - nf, 0.0))
    else:  # flash-only mode: the flash photo is the flash-only image
        nf = np.zeros_like(flash)
        fo = flash
    env_sel, point_sel = lighting.selection["env"], lighting.selection["point"]
    if env_sel is not None:
        env_images = env_exemplars_at(lighting.env, env_sel.roughness, env_sel.images, n)
    else:
        env_images = np.zeros((3, n, n, 3), np.float32)
    point_images = (
        point_sel.images if n == point_sel.images.shape[1] else point_exemplars_at(point_sel.roughness, n)
    )
    far_fo = None
    shots = [flash, nf]
    if num_photos == 4:
        if "far_flash" in photos and "noflash" in photos:
            far = [photos["far_flash"], photos["far_noflash"]]
            far_fo = detail_merge(lighting.far_flash_only, np.maximum(far[0] - far[1], 0.0))
        else:
            far, far_fo = [np.zeros_like(flash)] * 2, np.zeros_like(flash)
        shots += far
    return PassInputs(nf, fo, env_images, point_images, shots, far_fo)


def pass_bytes(cascade, pixels: int) -> float:
    """Estimated peak memory of one network pass over ``pixels`` pixels (the widest NAFNet of
    the cascade, :data:`BYTES_PER_PIXEL_CHANNEL`)."""
    from .fastnet import CASCADE_NETS

    width = max(
        (getattr(cascade, n).size.width for n in CASCADE_NETS if getattr(cascade, n, None) is not None),
        default=8,
    )
    return float(pixels) * width * BYTES_PER_PIXEL_CHANNEL


def tile_plan(
    n: int, max_side: int, overlap: int = DEFAULT_OVERLAP, multiple: int = TILE_MULTIPLE
) -> tuple[int, list[int]]:
    """``(tile side, tile origins)`` covering [0, n) with tiles of side ≤ ``max_side`` (rounded to
    ``multiple``) overlapping by at least ``overlap``: the fewest tiles per axis, then the
    smallest side that covers with them (so 2048 with max 1100 and overlap 32 is 2 tiles of 1040,
    not 3)."""
    if max_side >= n:
        return n, [0]
    max_side = max(multiple, max_side // multiple * multiple, overlap + multiple)
    count = math.ceil((n - overlap) / (max_side - overlap))
    side = math.ceil((n + (count - 1) * overlap) / count / multiple) * multiple
    side = min(side, n)
    return side, tile_starts(n, side, min(overlap, side - 1))


def release_memory() -> None:
    """Give freed memory back to the system: objects only a reference cycle still holds (a dropped
    refinement level), Dr.Jit's cache of freed buffers, and glibc's heap (``malloc_trim``; after a
    2048² pass glibc held about 1 GB of freed network activations)."""
    import ctypes
    import ctypes.util
    import gc

    import drjit as dr

    gc.collect()
    dr.flush_malloc_cache()
    name = ctypes.util.find_library("c")
    if name and "libc.so" in name:
        try:
            ctypes.CDLL(name).malloc_trim(0)
        except (OSError, AttributeError):  # not glibc: nothing to trim
            pass


def ensemble_sizes(n: int, grid: int, count: int = ENSEMBLE) -> list[int]:
    """The sizes of the passes averaged into the maps at ``n``: ``n``, ``n/2``, … (``count`` sizes,
    halving rounded, each at least the grid), and the grid itself when fewer are left (it is
    computed anyway)."""
    sizes = []
    s = int(n)
    while len(sizes) < count and s >= grid:
        sizes.append(s)
        s = (s + 1) // 2
    if len(sizes) < count and grid not in sizes and grid < n:
        sizes.append(int(grid))
    return sizes


@dataclass
class FullResPrediction:
    """What :func:`predict_maps` returns (the fields of
    :class:`~ebr_mitsuba.model.predictor.Prediction` plus the grid pass, the ensemble and the
    tiling). ``maps``: (N, N); ``grid_maps``: the grid pass (G, G);
    ``members``: the sizes of the passes averaged; ``tiles``: the (row, column) origins of the
    tiles of the full-size pass (one ``(0, 0)`` for a single pass) and ``tile`` their side;
    ``scales``: the flash scales given to every part."""

    maps: SVBRDF
    env: SGEnvironment | None
    env_exemplars: list = field(default_factory=list)
    flash_only: np.ndarray | None = None
    selection: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    grid_maps: SVBRDF | None = None
    tile: int = 0
    tiles: list = field(default_factory=list)
    scales: tuple = ()
    members: list = field(default_factory=list)


class _MapSum:
    """Weighted sums of maps (float32), normals as vectors."""

    def __init__(self, n: int):
        self.acc = {k: np.zeros((n, n, ch), np.float32) for k, ch in _CHANNELS}
        self.wsum = np.zeros((n, n, 1), np.float32)

    def add(self, maps: SVBRDF, i: int = 0, j: int = 0, weight=1.0) -> None:
        t = maps.shape[0]
        sl = (slice(i, i + t), slice(j, j + t))
        for k, _ in _CHANNELS:
            v = getattr(maps, k)
            self.acc[k][sl] += weight * (v[..., None] if v.ndim == 2 else v)
        self.wsum[sl] += weight

    def mean(self, source: str) -> SVBRDF:
        avg = {k: v / self.wsum for k, v in self.acc.items()}
        normal = avg["normal"]
        normal[..., 2] = np.maximum(normal[..., 2], 1e-3)
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        return SVBRDF(
            normal=normal,
            diffuse=np.clip(avg["diffuse"], 0, 1),
            specular=np.clip(avg["specular"], 0, 1),
            roughness=np.clip(avg["roughness"][..., 0], 0, 1),
            source=source,
        )


_CHANNELS = (("normal", 3), ("diffuse", 3), ("specular", 3), ("roughness", 1))


class _Ensemble:
    """The mean of the passes' maps at N (module docstring, step 5), in torch: each member's
    maps as one (1, 10, s, s) tensor (normal, diffuse, specular, roughness), bilinearly upsampled
    to N in one call, normals renormalised, summed; :meth:`mean` as :meth:`_MapSum.mean`. The
    same values as ``_MapSum.add(upsample_maps(maps, n))`` (float32 rounding apart)."""

    def __init__(self, n: int):
        self.n = n
        self.acc = None
        self.count = 0

    def add(self, stacked) -> None:
        """``stacked``: (1, 10, s, s) float32 tensor, diffuse, specular and roughness in [0, 1]."""
        import torch
        import torch.nn.functional as F

        with torch.no_grad():
            if stacked.shape[-1] != self.n:
                stacked = F.interpolate(stacked, size=(self.n, self.n), mode="bilinear", align_corners=False)
                normal = stacked[:, :3]
                normal /= torch.sqrt((normal * normal).sum(dim=1, keepdim=True))
            if self.acc is None:
                self.acc = stacked.clone()
            else:
                self.acc += stacked
        self.count += 1

    def add_maps(self, maps) -> None:
        """A pass's :class:`~ebr_mitsuba.nets.maps.Maps` (batch element 0), clipped as
        ``Maps.to_svbrdf`` clips."""
        import torch

        with torch.no_grad():
            parts = [maps.normal[:1]]
            parts += [getattr(maps, k)[:1].clamp(0, 1) for k in ("diffuse", "specular", "roughness")]
            self.add(torch.cat([p.detach().to("cpu", torch.float32) for p in parts], dim=1))

    def add_svbrdf(self, maps: SVBRDF) -> None:
        import torch

        parts = [maps.normal, maps.diffuse, maps.specular, maps.roughness[..., None]]
        arr = np.concatenate([np.asarray(p, np.float32) for p in parts], axis=-1)
        self.add(torch.from_numpy(np.ascontiguousarray(arr.transpose(2, 0, 1)))[None])

    def mean(self, source: str) -> SVBRDF:
        import torch

        with torch.no_grad():
            avg = self.acc[0] / self.count
            normal = avg[:3]
            normal[2].clamp_(min=1e-3)
            normal /= torch.sqrt((normal * normal).sum(dim=0, keepdim=True))
            avg[3:].clamp_(0, 1)
            hwc = avg.permute(1, 2, 0).contiguous().numpy()
        return SVBRDF(
            normal=hwc[..., 0:3],
            diffuse=hwc[..., 3:6],
            specular=hwc[..., 6:9],
            roughness=hwc[..., 9],
            source=source,
        )


LOW_FREQUENCY_MAPS = ("specular", "roughness")  # their low frequencies come from the grid pass


def low_frequencies_from(grid_maps: SVBRDF, maps: SVBRDF, names=LOW_FREQUENCY_MAPS) -> SVBRDF:
    """``maps`` (N, N) with the maps ``names`` below the grid's frequency taken from ``grid_maps``
    (G, G): ``up(grid) + maps − up(down(maps))`` (area ``down`` to G, bilinear ``up``), clipped
    to [0, 1]; the other maps unchanged."""
    n, g = maps.shape[0], grid_maps.shape[0]
    out = {}
    for name in ("diffuse", "specular", "roughness"):
        m = np.asarray(getattr(maps, name), np.float32)
        if name in names and n != g:
            low = np.asarray(getattr(grid_maps, name), np.float32) - resize_area(m, (g, g))
            m = np.clip(upsample_bilinear_fast(low, (n, n)) + m, 0.0, 1.0)
        out[name] = m
    return SVBRDF(maps.normal, out["diffuse"], out["specular"], out["roughness"], source=maps.source)


def upsample_maps(maps: SVBRDF, size: int) -> SVBRDF:
    """Maps bilinearly upsampled to ``size``² (normals renormalised); unchanged at their size."""
    if maps.shape[0] == size:
        return maps
    normal = upsample_bilinear_fast(maps.normal, (size, size))
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    return SVBRDF(
        normal=normal,
        diffuse=upsample_bilinear_fast(maps.diffuse, (size, size)),
        specular=upsample_bilinear_fast(maps.specular, (size, size)),
        roughness=upsample_bilinear_fast(maps.roughness, (size, size)),
        source=maps.source,
    )


def predict_maps(
    predictor: StagedPredictor,
    lighting: Lighting,
    photos: dict[str, np.ndarray],
    grid_photos: dict[str, np.ndarray],
    *,
    progress: Callable[[int, int, str], None] | None = None,
    pass_memory: float | None = None,
    overlap: int = DEFAULT_OVERLAP,
    ensemble: int | None = None,
) -> FullResPrediction:
    """Maps at the photos' size N from the capture's ``lighting`` (module docstring).

    ``predictor``: the model (a :class:`~ebr_mitsuba.model.predictor.StagedPredictor`: its
    ``cascade``, ``grid_pass_inputs`` and ``cascade_pass``); ``photos`` / ``grid_photos``: shot
    name → (N, N, 3) / (G, G, 3), the same shots at the working size and at the grid; ``progress(done, total,
    what)``: after each step; ``pass_memory``: bytes a network pass may take before tiles are used
    (None: :data:`PASS_MEMORY`; a small value forces tiles); ``overlap``: tile overlap in pixels;
    ``ensemble``: how many pass sizes are averaged (None: :data:`ENSEMBLE`; 1: the full size alone).
    """
    import torch

    from ..model.renders import flash_scale
    from ..render import RenderOptions
    from .fastnet import cascade_passes, fast_cascade

    timings: dict[str, float] = {}
    n = photos["flash"].shape[0]
    g = grid_photos["flash"].shape[0]
    cascade = predictor.cascade
    c = cascade.config
    per_pass = cascade_passes(cascade)
    pass_memory = PASS_MEMORY if pass_memory is None else float(pass_memory)
    max_side = max(int(math.sqrt(pass_memory / max(pass_bytes(cascade, 1), 1e-9))), TILE_MULTIPLE)
    members = ensemble_sizes(n, g, ENSEMBLE if ensemble is None else int(ensemble))
    plans = {s: tile_plan(s, max_side, overlap) for s in members if s != g}
    total = 1 + sum(1 + per_pass * len(starts) ** 2 for _, starts in plans.values())
    done = [0]

    def step(what: str):
        done[0] += 1
        if progress is not None:
            progress(done[0], total, what)

    # Grid pass: the whole capture at the grid, for the capture's flash scale (and a member of the
    # ensemble when the working size is within 4× the grid).
    t0 = time.perf_counter()
    with torch_threads(1):  # module docstring, "Speed"
        far = ("far_flash", "far_noflash") if predictor.takes_far else ()  # a near model: near shots
        g_in = predictor.grid_pass_inputs(
            lighting,
            grid_photos["flash"],
            grid_photos.get("noflash"),
            *(grid_photos.get(k) for k in far),
        )
        g_out = predictor.cascade_pass(g_in, lighting.env)  # the module: faster than FastNAFNet at the grid
        step("grid pass")
        grid_maps = g_out.maps.to_svbrdf(0, source="ebr_mitsuba network (grid pass)")
        dev = g_out.maps.normal.device
        k_near = float(
            flash_scale(g_out.coarse, torch.from_numpy(g_in.flash_only).permute(2, 0, 1)[None].to(dev))[0]
        )
        k_far = None
        if c.num_photos == 4 and g_in.far_flash_only is not None:
            far_fo = torch.from_numpy(g_in.far_flash_only).permute(2, 0, 1)[None].to(dev)
            k_far = float(flash_scale(g_out.coarse, far_fo, far=True)[0])
    scales = (k_near, k_far)
    timings["grid_pass"] = time.perf_counter() - t0

    options = RenderOptions(irradiance_table=IRRADIANCE_TABLE, lobe_loop=True)
    total_maps = _Ensemble(n)
    timings["exemplars"] = timings["full_pass"] = 0.0
    full_tile, full_starts = n, [0]
    for size in members:
        if size == g:
            total_maps.add_svbrdf(grid_maps)
            continue
        tile, starts = plans[size]
        label = "full size" if size == n else f"{size}x{size}"
        t0 = time.perf_counter()
        sized = photos if size == n else {k: resize_area(v, (size, size)) for k, v in photos.items()}
        full_in = full_pass_inputs(lighting, sized, c.num_photos)
        release_memory()  # the renders' buffers go back to the system before the networks run
        timings["exemplars"] += time.perf_counter() - t0
        step(f"exemplars, {label}")
        t0 = time.perf_counter()
        what = label if len(starts) == 1 else f"{label}, tiles"
        view = fast_cascade(cascade, lambda what=what: step(what))
        if len(starts) == 1:
            out = predictor.cascade_pass(
                full_in,
                lighting.env,
                cascade=view,
                window=(0, 0, size, size),
                scales=scales,
                render_options=options,
            )
            total_maps.add_maps(out.maps)
        else:
            w1 = ramp(tile, min(overlap, tile - 1))
            weight = np.outer(w1, w1)[..., None].astype(np.float32)
            tiled = _MapSum(size)
            for i in starts:
                for j in starts:
                    out = predictor.cascade_pass(
                        full_in.crop(i, j, tile, tile),
                        lighting.env,
                        cascade=view,
                        window=(i, j, size, size),
                        scales=scales,
                        render_options=options,
                    )
                    tiled.add(out.maps.to_svbrdf(0), i, j, weight)
            total_maps.add_svbrdf(tiled.mean("ebr_mitsuba network (tiled)"))
        del out, full_in
        release_memory()
        timings["full_pass"] += time.perf_counter() - t0
        if size == n:
            full_tile, full_starts = tile, starts
    result = total_maps.mean(f"ebr_mitsuba network (mean of the passes at {', '.join(map(str, members))})")
    result = low_frequencies_from(grid_maps, result)
    boxes = [(i, j) for i in full_starts for j in full_starts]
    return FullResPrediction(
        result,
        lighting.env,
        lighting.env_exemplars,
        lighting.flash_only,
        dict(lighting.selection),
        timings,
        grid_maps,
        full_tile,
        boxes,
        scales,
        members,
    )


__all__ = [
    "BYTES_PER_PIXEL_CHANNEL",
    "FullResPrediction",
    "IRRADIANCE_TABLE",
    "PASS_MEMORY",
    "ENSEMBLE",
    "LOW_FREQUENCY_MAPS",
    "detail_merge",
    "ensemble_sizes",
    "env_exemplars_at",
    "full_pass_inputs",
    "low_frequencies_from",
    "pass_bytes",
    "release_memory",
    "predict_maps",
    "tile_plan",
    "upsample_maps",
]
