"""Helpers shared by the benchmark modules."""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from functools import partial
from pathlib import Path

QUIET_CORES = 0.25  # other processes using less than this many cores on average: a quiet machine

# ``../shared/data`` next to the checkout; ``$EBR_DATA_DIR`` overrides it.
DEFAULT_DATA_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def shared_data_dir() -> Path:
    """The shared assets folder: ``$EBR_DATA_DIR``, else :data:`DEFAULT_DATA_DIR`."""
    return Path(os.environ.get("EBR_DATA_DIR", DEFAULT_DATA_DIR))


def machine() -> str:
    """The machine line of a page: CPU, cores, Mitsuba variant and library versions."""
    from ..variant import describe

    d = describe()
    return (
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} logical cores, "
        f"{d['variant']}, Mitsuba {d['mitsuba']}, Dr.Jit {d['drjit']}, LLVM {d.get('llvm', '-')}"
    )


def median_seconds(fn, repeats: int) -> float:
    """Wall seconds of ``fn()``: the median of ``max(1, repeats)`` calls after one warm-up call
    (kernel compilation, allocator and cache warm-up)."""
    fn()
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _busy_seconds() -> float | None:
    """CPU seconds all processes have spent busy since boot (``/proc/stat``), None off Linux."""
    try:
        with open("/proc/stat") as f:
            fields = [int(x) for x in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    user, nice, system, _idle, _iowait, irq, softirq, steal = fields
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def _own_seconds() -> float:
    """CPU seconds of this process and of its children that have been waited for."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def other_cores(busy: float, own: float, wall: float) -> float:
    """Cores that other processes kept busy on average: (all busy CPU time − ours) / wall time."""
    return max(0.0, busy - own) / wall if wall > 0 else 0.0


class OtherLoad:
    """How much of the machine other processes used while a benchmark ran: the busy CPU time of
    ``/proc/stat`` minus this process's own (threads and waited-for children included). Unlike the
    load average, it does not count the benchmark's own runs."""

    def __init__(self):
        self._busy, self._own, self._wall = _busy_seconds(), _own_seconds(), time.perf_counter()

    def cores(self) -> float | None:
        """Average cores used by other processes since construction (None off Linux)."""
        busy = _busy_seconds()
        if busy is None or self._busy is None:
            return None
        return other_cores(busy - self._busy, _own_seconds() - self._own, time.perf_counter() - self._wall)


def load_sentence(cores: float | None) -> str:
    """The page's sentence about other processes' load during the measurements."""
    if cores is None:
        return "Other processes' load was not measured (no /proc/stat)."
    if cores < QUIET_CORES:
        return f"Other processes used {cores:.2f} cores on average during the runs: a quiet machine."
    return (
        f"Other processes used {cores:.2f} cores on average during the runs: the machine was shared, "
        "rerun on a quiet one for the documented numbers."
    )


def data_set_paths(*variables: str) -> list[Path]:
    """The data sets named in the first of ``variables`` that is set (paths separated by ``:``)."""
    text = next((os.environ[v] for v in variables if os.environ.get(v)), "")
    return [Path(p) for p in text.split(":") if p.strip()]


def validation_sets(var: str) -> list[Path]:
    """A benchmark's validation data sets: those named in ``$var``, else in ``$EBR_VAL_DATA``."""
    return data_set_paths(var, "EBR_VAL_DATA")


def validation_note(var: str, page: str) -> str | None:
    """None when :func:`validation_sets` finds data sets, else the line saying how to name them."""
    return None if validation_sets(var) else f"set ${var} (or $EBR_VAL_DATA); see docs/bench/{page}"


def measure_validation(var: str, page: str, measure, out_dir: Path | str):
    """The common start of a validation benchmark's ``run``: its data sets (:func:`validation_sets`
    of ``$var``; none: an :class:`~ebr_mitsuba.errors.InputError` saying how to name them),
    ``measure(roots)`` timed, and ``out_dir`` made. Returns ``(roots, result, seconds, out_dir)``."""
    from ..errors import InputError

    roots = validation_sets(var)
    if not roots:
        raise InputError(validation_note(var, page))
    t0 = time.perf_counter()
    result = measure(roots)
    seconds = time.perf_counter() - t0
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return roots, result, seconds, out_dir


def validation_captures(roots: list[Path], page: str, limit: int = 0):
    """Every capture of the validation data sets ``roots`` (the first ``limit`` of each when > 0), as
    ``(root, dataset, index, intensity)``: the :class:`~ebr_mitsuba.data.dataset.GeneratedDataset`
    and its known flash intensity. A root that is not a data set of ``ebr generate`` is an
    :class:`~ebr_mitsuba.errors.InputError` pointing at ``page``'s commands."""
    from ..data.dataset import GeneratedDataset
    from ..errors import InputError

    for root in roots:
        if not (root / "dataset.json").is_file():
            raise InputError(f"{root}: not a data set of ebr generate; make it with the commands in {page}")
        ds = GeneratedDataset(root)
        intensity = float(ds.dataset["config"]["capture"]["flash_intensity"])
        for i in range(len(ds) if limit <= 0 else min(limit, len(ds))):
            yield root, ds, i, intensity


def by_data_set(rows: list[dict], roots: list[Path], summarise) -> dict:
    """``summarise(rows)`` per data set (rows by their ``"data"``, the root's name) and over ``"all"``,
    leaving out groups without rows."""
    groups = {r.name: [x for x in rows if x["data"] == r.name] for r in roots}
    groups["all"] = rows
    return {name: summarise(group) for name, group in groups.items() if group}


def variant_score(maps, truth, key: str, pairs, intensity: float, truth_renders) -> dict:
    """One estimate variant scored as ``ebr bench models`` scores it: ``{key: that map's RMSE,
    "mean": the mean per-map RMSE, "rerender": the held-out-light re-render RMSE}`` (``maps`` at the
    truth's size; ``pairs``, ``truth_renders``: :func:`ebr_mitsuba.metrics.rerender_pairs` and the
    truth's :func:`~ebr_mitsuba.metrics.rerenders` under them)."""
    from .. import metrics

    m = metrics.sample_metrics(maps, truth, pairs, intensity, truth_renders)
    return {key: m["per_map_rmse"][key], "mean": m["per_map_rmse"]["mean"], "rerender": m["rerender_rmse"]}


def thumbnail_grid(rows: list[dict], columns, image, title, path: Path, **imshow) -> None:
    """A picture of one row of thumbnails per entry of ``rows`` (labelled with its ``material``) and
    one column per name in ``columns``: ``image(row, column)`` drawn with the ``imshow`` options,
    ``title(row, column)`` above it; saved to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        len(rows), len(columns), figsize=(2.2 * len(columns), 2.25 * len(rows)), squeeze=False
    )
    for ax_row, r in zip(axes, rows):
        for ax, col in zip(ax_row, columns):
            ax.imshow(image(r, col), **imshow)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(title(r, col), fontsize=8)
        ax_row[0].set_ylabel(f"{r['material'][:22]}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def named_runs(var: str, hint: str, required: bool = True) -> list[tuple[str, Path]]:
    """The training runs named in ``$var`` (``NAME=RUN_DIR`` separated by ``;``), in order, each
    with ``RUN_DIR/model.pt``; an :class:`~ebr_mitsuba.errors.InputError` ending in ``hint`` for a
    malformed entry, or for none at all when ``required``."""
    from ..errors import InputError

    spec = os.environ.get(var, "").strip()
    out = []
    for part in filter(None, (p.strip() for p in spec.split(";"))):
        name, sep, path = part.partition("=")
        run = Path(path.strip())
        if not sep or not name.strip() or not (run / "model.pt").is_file():
            raise InputError(f"${var}: '{part}' is not NAME=RUN_DIR with RUN_DIR/model.pt; {hint}")
        out.append((name.strip(), run))
    if required and not out:
        raise InputError(f"${var} names no run; {hint}")
    return out


def _sample_record(sample: Path) -> dict:
    return json.loads((sample / "sample.json").read_text())


def lobes_emitter(sample: Path, record: dict | None = None):
    """``(emitter factory, lobes)`` of the SG lobes of the environment sample ``sample`` was
    rendered under (its ``env.json``: the environment itself, or the lobes fitted to its HDR map),
    in photo units (× the sample's exposure); None when it has none. ``record``: its
    ``sample.json``, when already read."""
    from ..scene import sg_emitter_dict
    from ..sgenv import SGEnvironment

    record = _sample_record(sample) if record is None else record
    env = record.get("env") or {}
    if not env.get("lobes"):
        return None
    lobes = SGEnvironment.load(sample / env.get("file", "env.json"))
    return partial(sg_emitter_dict, lobes, float(record["camera"]["exposure"])), lobes


def truth_emitter(sample: Path):
    """``(emitter factory, description)`` of the environment sample ``sample`` was rendered under,
    in photo units (× the sample's exposure); None for a dark sample."""
    from ..data.renderers import rotated_envmap_dict

    record = _sample_record(sample)
    env, exposure = record.get("env") or {}, float(record["camera"]["exposure"])
    if env.get("type") == "equirect":
        path, rotation, scale = env["map"]["path"], float(env["rotation"]), float(env["scale"]) * exposure
        return (lambda: rotated_envmap_dict(path, rotation, scale)), f"{env['map']['name']} (HDR map)"
    made = lobes_emitter(sample, record)
    if made is not None:
        factory, lobes = made
        return factory, f"{lobes.num_lobes} SG lobes"
    return None
