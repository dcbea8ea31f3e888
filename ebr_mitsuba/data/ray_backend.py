"""Running ``ebr generate`` on a Ray cluster: one Ray task per shard of samples.

Ray is the optional extra ``ray`` (``pip install 'ebr-mitsuba[ray]'``); without it
:func:`require_ray` raises :class:`~ebr_mitsuba.errors.RuntimeSetupError` (one line, exit 2).

``--ray ADDRESS`` connects to a running cluster (``ray.init(address=ADDRESS)``; ``auto`` finds the
local head started by ``ray start --head``), ``--ray local`` starts a private local cluster with
``--workers`` CPUs. When Ray is already initialised in the calling process, that cluster is used.

Each task (1 CPU, retried twice) runs the callable it is given on its shard — for ``ebr generate``
:func:`ebr_mitsuba.data.workers.make_shard`, which sets the variant and one Dr.Jit thread, makes
the shard's samples in a private temporary directory and returns each as ``{relative path:
bytes}`` — and the driver hands each result to the ``collect`` callable it is given (which writes
the files atomically into the output directory, :func:`ebr_mitsuba.data.store.write_files`), so
worker nodes need no shared file system for the output. They do need this package and the
config's source files (material directories, maps) at the same paths. Samples are byte-identical
to a local run's. This module imports nothing of the package but its errors; ``tests/fake_ray.py``
stands in for Ray in ``make test``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from ..errors import RuntimeSetupError

INSTALL_HINT = "pip install 'ebr-mitsuba[ray]'"


def require_ray():
    """Import Ray or fail with one line naming the extra."""
    try:
        import ray
    except ImportError:
        raise RuntimeSetupError(
            f"--ray needs Ray, an optional extra that is not installed: {INSTALL_HINT} "
            f"(or run without --ray, with --workers N)"
        ) from None
    return ray


def run_ray(
    ray,
    address: str,
    task: Callable,
    shared: tuple,
    items: Sequence,
    shard_size: int,
    workers: int,
    collect: Callable[[object], None],
) -> None:
    """Run ``task(*shared, shard)`` as one Ray task per shard of ``shard_size`` items; ``collect
    (result)`` in this process as each task finishes. ``ray``: the Ray module (:func:`require_ray`);
    ``address``: ``local`` (a private cluster of ``workers`` CPUs) or a cluster address (``auto``:
    the local head); ``shared`` is put in the object store once. A task's error is re-raised as
    itself (one line, not Ray's traceback)."""
    started = not ray.is_initialized()
    if started:
        if address == "local":
            ray.init(num_cpus=int(workers), include_dashboard=False, log_to_driver=False)
        else:
            try:
                ray.init(address=address, log_to_driver=False)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise RuntimeSetupError(
                    f"--ray {address}: cannot connect to a Ray cluster ({exc}); start "
                    f"one with 'ray start --head' or use --ray local"
                ) from None
    try:
        remote = ray.remote(num_cpus=1, max_retries=2)(task)
        refs = [ray.put(value) for value in shared]
        shards = [list(items[i : i + shard_size]) for i in range(0, len(items), shard_size)]
        pending = [remote.remote(*refs, shard) for shard in shards]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            try:
                result = ray.get(done[0])
            except ray.exceptions.RayTaskError as exc:  # re-raise the task's own error (one line)
                cause = getattr(exc, "cause", None)
                raise (cause if isinstance(cause, Exception) else exc) from None
            collect(result)
    finally:
        if started:
            ray.shutdown()
