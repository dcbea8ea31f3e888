"""Generating a data set from a config: one process, a pool of processes, or a Ray cluster.

:func:`generate` does, in order:

1. checks the output directory (new, empty, or — with ``resume`` — a data set of the same config
   fingerprint; another config's data set or a non-data-set directory is refused);
2. fits the SG ground truth of every equirect map once (:func:`.sample.prepare_maps`, single-
   threaded and so bit-reproducible, saved in ``envs/`` and reloaded from there);
3. writes ``dataset.json`` and ``config.toml``;
4. makes every missing sample (:func:`make_sample`: draw → clean renders → camera simulation →
   atomic write) — in this process (``workers=1``), in a ``spawn`` pool of ``workers`` processes,
   or as Ray tasks of ``shard_size`` samples each (:mod:`.ray_backend`), following the worker
   protocol of :mod:`.workers`. Every worker renders with one Dr.Jit thread: the renders are then
   bit-identical whichever worker makes a sample (the fast renderer's scatter-adds depend on the
   thread count otherwise);
5. writes ``index.json`` and appends the run's wall time to ``timing.json`` (the only file that
   differs between runs).

The same config therefore gives byte-identical files (except ``timing.json``) for any worker
count and any sequence of interrupted and resumed runs. Use ``workers`` = number of cores.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import InputError
from ..exemplar import exemplar_material_json
from ..fsutil import atomic_write_text, output_lock, remove_stale_temporaries
from . import ray_backend, store
from . import workers as workers_mod  # (``workers`` is the worker count here)
from .camera import camera_units, photo_linear
from .config import GenerateConfig
from .renderers import render_clean, shots_of
from .sample import Plan, SampleDraw, draw_sample, prepare_maps

DEFAULT_SHARD_SIZE = 4


@dataclass(frozen=True)
class Summary:
    """What a :func:`generate` run did (``seconds`` and rates are wall-clock)."""

    out: str
    count: int
    generated: int
    skipped: int
    seconds: float
    workers: int
    backend: str
    partials_removed: int = 0

    @property
    def samples_per_second(self) -> float:
        return self.generated / self.seconds if self.seconds > 0 else 0.0

    def to_json(self) -> dict:
        return {
            "out": self.out,
            "count": self.count,
            "generated": self.generated,
            "skipped": self.skipped,
            "seconds": round(self.seconds, 3),
            "workers": self.workers,
            "backend": self.backend,
            "samples_per_second": round(self.samples_per_second, 4),
            "samples_per_second_per_worker": round(self.samples_per_second / max(self.workers, 1), 4),
            "partials_removed": self.partials_removed,
        }


# -- one sample ------------------------------------------------------------------------------------


def renderer_record(config: GenerateConfig) -> dict:
    r = config.render
    if r.renderer == "mitsuba":
        return {"name": "mitsuba", "spp": r.spp, "integrator": r.integrator}
    return {"name": "fast", "mode": r.fast_mode, "spp": r.fast_spp}


def sample_meta(plan: Plan, draw: SampleDraw) -> dict:
    """The content of ``sample.json`` (see :mod:`.store`)."""
    from ..geometry import near_shot

    cfg = plan.config
    lay = store.layout(cfg)
    res = cfg.dataset.resolution
    shots = []
    for shot in shots_of(cfg):
        rec = shot.to_json()
        rec["photo"] = lay["photos"][shot.name]
        rec["flash_only"] = lay["flash_only"].get(shot.name)
        rec["in_sample_grid"] = shot.in_sample_grid()
        shots.append(rec)
    env = dict(draw.env.record)
    env.update(lobes=draw.env.sg.num_lobes, file=store.ENV_JSON)
    near = near_shot(False, intensity=cfg.capture.flash_intensity)
    return {
        "format": store.SAMPLE_FORMAT,
        "index": draw.index,
        "seed": [cfg.dataset.seed, draw.index],
        "setup": cfg.capture.setup,
        "resolution": [res, res],
        "renderer": renderer_record(cfg),
        "material": draw.material,
        "env": env,
        "camera": draw.camera.record(),
        "shots": shots,
        "exemplars": {
            "material": exemplar_material_json(),
            "camera": list(near.camera),
            "fov": near.fov,
            "flash_intensity": cfg.capture.flash_intensity,
            "env": [
                {"roughness": r, "file": f} for r, f in zip(cfg.exemplars.env_roughness, lay["env_exemplars"])
            ],
            "point": [
                {"roughness": r, "file": f}
                for r, f in zip(cfg.exemplars.point_roughness, lay["point_exemplars"])
            ],
        },
        "maps": lay["maps"],
        "render_seeds": list(draw.render_seeds),
    }


METER_PERCENTILE = 99.0


def metered(config: GenerateConfig, draw, shots: dict[str, np.ndarray]):
    """``draw`` with the auto exposure of ``[camera].meter`` (the drawn jitter kept): the base
    exposure puts the 99th percentile of the brightest clean shot's largest channel at ``meter``
    (highlight-priority metering: a strongly coloured material clips in no channel before the
    brightest 1 % of its pixels)."""
    meter = config.camera.meter
    if meter <= 0:
        return draw
    level = max(
        float(np.percentile(np.max(np.asarray(v, np.float64), axis=-1), METER_PERCENTILE))
        for v in shots.values()
    )
    jitter = draw.camera.exposure / config.camera.exposure
    exposure = float(meter / max(level, 1e-6) * jitter)
    return dataclasses.replace(draw, camera=dataclasses.replace(draw.camera, exposure=exposure))


def make_sample(plan: Plan, index: int, root: Path) -> Path:
    """Draw, render, camera-simulate and write sample ``index`` under ``root``; returns its directory."""
    draw = draw_sample(plan, index)
    clean = render_clean(plan.config, draw)
    draw = metered(plan.config, draw, clean.shots)
    cam = draw.camera
    rng = np.random.default_rng(cam.noise_seed)
    photos = {name: photo_linear(image, cam, rng) for name, image in clean.shots.items()}
    for name, image in photos.items():
        if not np.all(np.isfinite(image)):
            raise RuntimeError(f"sample {index}: the {name} render has NaN/Inf pixels")
    return store.write_sample(
        Path(root),
        index,
        svbrdf=draw.svbrdf,
        env_sg=draw.env.sg,
        photos=photos,
        flash_only={k: camera_units(v, cam) for k, v in clean.flash_only.items()},
        env_exemplars=[camera_units(v, cam) for v in clean.env_exemplars],
        point_exemplars=[camera_units(v, cam) for v in clean.point_exemplars],
        meta=sample_meta(plan, draw),
        quantize=cam.quantize,
    )


# -- the run -----------------------------------------------------------------------------------------


def _check_out(root: Path, config: GenerateConfig, resume: bool) -> None:
    if not root.exists() or not any(root.iterdir()):
        return
    ds = root / store.DATASET_JSON
    if not ds.is_file():
        if resume and {p.name for p in root.iterdir()} <= {"envs"}:
            return  # killed while fitting the maps, before dataset.json: nothing else was written
        raise InputError(
            f"{root}: exists, is not empty and holds no {store.DATASET_JSON}; choose a new --out or remove it"
        )
    if not resume:
        raise InputError(
            f"{root}: already holds a data set; pass --resume to complete or extend it, or choose a new --out"
        )
    try:
        old = store.read_json(ds)
    except (json.JSONDecodeError, UnicodeDecodeError, OSError):
        raise InputError(f"{ds}: unreadable; the directory is damaged: choose a new --out") from None
    if old.get("fingerprint") != config.fingerprint():
        raise InputError(
            f"{root}: was generated from a different config (fingerprint "
            f"{str(old.get('fingerprint'))[:12]} vs {config.fingerprint()[:12]}); --resume "
            f"needs the same config (only --count may change): choose a new --out"
        )


def dataset_doc(plan: Plan) -> dict:
    """The content of ``dataset.json``."""
    from ..variant import describe

    cfg = plan.config
    return {
        "format": store.DATASET_FORMAT,
        "count": cfg.dataset.count,
        "fingerprint": cfg.fingerprint(),
        "setup": cfg.capture.setup,
        "resolution": [cfg.dataset.resolution] * 2,
        "renderer": renderer_record(cfg),
        "layout": store.layout(cfg),
        "shots": [s.to_json() for s in shots_of(cfg)],
        "env_maps": [m.record() for m in plan.maps.values()],
        "config": cfg.to_json(),
        "generator": {"ebr_mitsuba": __version__, **describe()},
        "nondeterministic_files": [store.TIMING_JSON],
    }


def _append_timing(root: Path, summary: Summary) -> None:
    path = root / store.TIMING_JSON
    runs = []
    if path.is_file():
        try:
            runs = list(json.loads(path.read_text()).get("runs", []))
        except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
            runs = []
    runs.append({"finished": time.strftime("%Y-%m-%dT%H:%M:%S"), **summary.to_json()})
    atomic_write_text(
        path,
        json.dumps({"note": "wall times of the runs; not deterministic, not data", "runs": runs}, indent=1)
        + "\n",
    )


def generate(
    config: GenerateConfig,
    out: str | os.PathLike,
    *,
    workers: int = 1,
    resume: bool = False,
    ray: str | None = None,
    shard_size: int = DEFAULT_SHARD_SIZE,
    progress: bool = True,
    say=None,
) -> Summary:
    """Generate (or, with ``resume``, complete) the data set of ``config`` in ``out`` (module
    docstring). ``ray``: a Ray address, ``"auto"`` or ``"local"`` (start a local cluster of
    ``workers`` CPUs); ``say``: optional callable for status lines. Returns a :class:`Summary`.

    One run per directory: ``out`` is locked (:func:`ebr_mitsuba.fsutil.output_lock`) for the
    run, and a second run into it is refused with :class:`~ebr_mitsuba.errors.BusyError`."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InputError(f"--workers must be an integer >= 1 (got {workers!r})")
    if isinstance(shard_size, bool) or not isinstance(shard_size, int) or shard_size < 1:
        raise InputError(f"--shard-size must be an integer >= 1 (got {shard_size!r})")
    ray_module = ray_backend.require_ray() if ray is not None else None  # fail before anything is written
    root = Path(out)
    if root.exists() and not root.is_dir():
        raise InputError(f"{root}: exists and is not a directory; choose another --out")
    with output_lock(root, "ebr generate"):
        return _generate(
            config,
            root,
            workers=workers,
            resume=resume,
            ray=ray,
            ray_module=ray_module,
            shard_size=shard_size,
            progress=progress,
            say=say,
        )


def _generate(
    config: GenerateConfig,
    root: Path,
    *,
    workers: int,
    resume: bool,
    ray: str | None,
    ray_module,
    shard_size: int,
    progress: bool,
    say,
) -> Summary:
    """:func:`generate` once the arguments are checked and ``root`` is locked (``ray_module``:
    Ray, imported, when ``ray`` is given)."""
    from tqdm import tqdm

    from ..variant import ensure_variant

    _check_out(root, config, resume)
    variant = ensure_variant()
    root.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    partials = store.remove_partials(root)
    for directory in (root, root / "envs"):  # what a killed atomic write left (we hold the lock)
        remove_stale_temporaries(directory, recursive=False)
    plan = Plan(config, prepare_maps(config, root, progress=say), variant)
    atomic_write_text(root / store.DATASET_JSON, store.dumps(dataset_doc(plan)))
    if config.source != "<memory>" and Path(config.source).is_file():
        atomic_write_text(root / store.CONFIG_COPY, Path(config.source).read_text())
    count = config.dataset.count
    todo = [i for i in range(count) if not store.is_complete(root, i)]
    skipped = count - len(todo)
    n_workers = max(1, min(workers, len(todo))) if todo else 1
    backend = "ray" if ray is not None else ("process" if n_workers == 1 else "pool")
    bar = tqdm(
        total=len(todo),
        desc="generate",
        unit="sample",
        disable=None if progress else True,
        dynamic_ncols=True,
        smoothing=0.1,
    )
    t0 = time.perf_counter()

    def collect(shard: list[tuple[int, dict]]) -> None:  # a Ray task's samples
        for index, files in shard:
            store.write_files(root, index, files)
            bar.update(1)

    try:
        if not todo:
            pass
        elif ray is not None:
            task, shared = workers_mod.make_shard, (plan.variant, make_sample, plan)
            ray_backend.run_ray(ray_module, ray, task, shared, todo, shard_size, workers, collect)
        elif n_workers == 1:
            workers_mod.run_in_process(make_sample, plan, root, todo, lambda: bar.update(1))
        else:
            workers_mod.run_pool(make_sample, plan, root, todo, n_workers, lambda: bar.update(1))
    finally:
        bar.close()
    seconds = time.perf_counter() - t0
    store.write_index(root, count, config.fingerprint())
    summary = Summary(str(root), count, len(todo), skipped, seconds, n_workers, backend, partials)
    _append_timing(root, summary)
    if say is not None:
        say(f"set-up (fits, checks) took {t0 - t_start:.1f} s")
    return summary
