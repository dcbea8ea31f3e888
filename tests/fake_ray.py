"""A stand-in for the part of Ray that ``ebr_mitsuba.data.ray_backend`` uses, so that the Ray path
runs in ``make test`` without Ray installed.

Tasks run in a ``spawn`` process pool (fresh interpreters, as Ray's workers are; the task, its
arguments and results are pickled across), ``num_cpus`` processes for a local cluster, two for an
address (``auto`` and ``fake://…`` connect; any other address raises ``ConnectionError``, as Ray
does when no cluster answers). ``put`` keeps the value in this process; ``get`` of a failed task
raises :class:`exceptions.RayTaskError` with the task's exception as ``cause``. ``calls`` records
``init``/``shutdown`` and the options of every ``remote``.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures

calls: list[tuple] = []
_pool: ProcessPoolExecutor | None = None


class exceptions:  # noqa: N801 - mirrors the module ray.exceptions
    class RayTaskError(Exception):
        def __init__(self, cause: BaseException):
            super().__init__(f"task failed: {cause!r}")
            self.cause = cause


class ObjectRef:
    def __init__(self, future: Future):
        self.future = future


def is_initialized() -> bool:
    return _pool is not None


def init(address: str | None = None, num_cpus: int | None = None, **options) -> None:
    global _pool
    if address is not None and address != "auto" and not address.startswith("fake://"):
        raise ConnectionError(f"could not find a Ray cluster at {address}")
    calls.append(("init", address, num_cpus))
    _pool = ProcessPoolExecutor(num_cpus or 2, mp_context=multiprocessing.get_context("spawn"))


def shutdown() -> None:
    global _pool
    calls.append(("shutdown",))
    if _pool is not None:
        _pool.shutdown(cancel_futures=True)
        _pool = None


def put(value) -> ObjectRef:
    future = Future()
    future.set_result(value)
    return ObjectRef(future)


class RemoteFunction:
    def __init__(self, function, options: dict):
        self.function, self.options = function, options

    def remote(self, *args) -> ObjectRef:
        """Submit the task; ObjectRef arguments are resolved first, as Ray resolves top-level ones."""
        if _pool is None:
            raise RuntimeError("fake ray: call ray.init() first")
        values = [a.future.result() if isinstance(a, ObjectRef) else a for a in args]
        return ObjectRef(_pool.submit(self.function, *values))


def remote(**options):
    calls.append(("remote", options))
    return lambda function: RemoteFunction(function, options)


def wait(refs: list[ObjectRef], num_returns: int = 1) -> tuple[list[ObjectRef], list[ObjectRef]]:
    wait_futures([r.future for r in refs], return_when=FIRST_COMPLETED)
    ready = [r for r in refs if r.future.done()][:num_returns]
    return ready, [r for r in refs if r not in ready]


def get(ref: ObjectRef):
    try:
        return ref.future.result()
    except Exception as exc:
        raise exceptions.RayTaskError(exc) from exc


def failing_task(message: str, shard: list[int]):
    """A task that raises (for the error path): ``ValueError(message shard)``."""
    raise ValueError(f"{message} {shard}")
