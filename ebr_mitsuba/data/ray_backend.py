"""Running ``ebr generate`` on a Ray cluster: one Ray task per shard of samples.

Ray is the optional extra ``ray`` (``pip install 'ebr-mitsuba[ray]'``); without it
:func:`require_ray` raises :class:`~ebr_mitsuba.errors.RuntimeSetupError` (one line, exit 2).

``--ray ADDRESS`` connects to a running cluster (``ray.init(address=ADDRESS)``; ``auto`` finds the
local head started by ``ray start --head``), ``--ray local`` starts a private local cluster with
``--workers`` CPUs. When Ray is already initialised in the calling process, that cluster is used.

Each task (1 CPU) sets the variant and one Dr.Jit thread, makes its shard's samples in a private
temporary directory with :func:`ebr_mitsuba.data.generate.make_sample`, and returns each sample
as ``{relative path: bytes}``; the driver writes them atomically into the output directory
(:func:`ebr_mitsuba.data.store.write_files`), so worker nodes need no shared file system for the
output. They do need this package and the config's source files (material directories, maps) at
the same paths. Samples are byte-identical to a local run's.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from ..errors import RuntimeSetupError

INSTALL_HINT = "pip install 'ebr-mitsuba[ray]'"


def require_ray():
    """Import Ray or fail with one line naming the extra."""
    try:
        import ray
    except ImportError:
        raise RuntimeSetupError(f"--ray needs Ray, an optional extra that is not installed: {INSTALL_HINT} "
                                f"(or run without --ray, with --workers N)") from None
    return ray


def _shard_task(variant: str, plan, indices: list[int]) -> list[tuple[int, dict]]:
    """Ray task body: make ``indices`` and return their files."""
    from . import generate, store

    if generate._WORKER.get("variant") != variant:
        generate.init_worker(variant, plan, ".")
        generate._WORKER["variant"] = variant
    out = []
    with tempfile.TemporaryDirectory(prefix="ebr-ray-") as tmp:
        for index in indices:
            directory = generate.make_sample(plan, index, Path(tmp))
            out.append((index, store.read_files(directory)))
    return out


def run_ray(address: str, plan, root: Path, todo: list[int], shard_size: int, workers: int, tick) -> None:
    """Make the samples ``todo`` as Ray tasks of ``shard_size`` samples; ``tick()`` per sample."""
    from . import store

    ray = require_ray()
    started = not ray.is_initialized()
    if started:
        if address == "local":
            ray.init(num_cpus=int(workers), include_dashboard=False, log_to_driver=False)
        else:
            try:
                ray.init(address=address, log_to_driver=False)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise RuntimeSetupError(f"--ray {address}: cannot connect to a Ray cluster ({exc}); start "
                                        f"one with 'ray start --head' or use --ray local") from None
    try:
        task = ray.remote(num_cpus=1, max_retries=2)(_shard_task)
        plan_ref = ray.put(plan)
        shards = [todo[i:i + shard_size] for i in range(0, len(todo), shard_size)]
        pending = [task.remote(plan.variant, plan_ref, shard) for shard in shards]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            try:
                results = ray.get(done[0])
            except ray.exceptions.RayTaskError as exc:  # re-raise the task's own error (one line)
                cause = getattr(exc, "cause", None)
                raise (cause if isinstance(cause, Exception) else exc) from None
            for index, files in results:
                store.write_files(root, index, files)
                tick()
    finally:
        if started:
            ray.shutdown()
