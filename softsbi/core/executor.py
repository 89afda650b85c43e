"""Built-in executors: where simulations run.

``local`` runs jobs in a pool of worker processes on this machine (one per core by
default; ``workers=1`` runs in-process, which is easiest to debug). Worker processes use
the ``spawn`` start method, so they never inherit torch's thread pools from the driver.
"""
from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
from typing import Any, Callable, ClassVar, Iterable, Sequence

from .interfaces import Executor
from ..plugins.hookspecs import hookimpl

_CONTEXT: Any = None


def _init_worker(context: Any) -> None:
    global _CONTEXT
    _CONTEXT = context
    # simulations are single-threaded; keep BLAS from oversubscribing the cores
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def _call(fn: Callable[[Any, Any], Any], item: Any) -> Any:
    return fn(_CONTEXT, item)


class LocalExecutor(Executor):
    """A process pool on this machine.

    Args:
        workers: number of worker processes (default: ``os.cpu_count()``); 1 runs in-process.

    Raises:
        ValueError: ``workers < 1``.
    """

    name: ClassVar[str] = "local"

    def __init__(self, workers: int | None = None):
        workers = (os.cpu_count() or 1) if workers is None else int(workers)
        if workers < 1:
            raise ValueError(f"--workers must be >= 1 (got {workers}); use 1 to run simulations in this process")
        self.workers = workers
        self._pool: cf.ProcessPoolExecutor | None = None
        self._context_id: int | None = None

    def _get_pool(self, context: Any) -> cf.ProcessPoolExecutor:
        if self._pool is None or self._context_id != id(context):
            self.close()
            self._pool = cf.ProcessPoolExecutor(max_workers=self.workers, mp_context=mp.get_context("spawn"),
                                                initializer=_init_worker, initargs=(context,))
            self._context_id = id(context)
        return self._pool

    def map_unordered(self, fn: Callable[[Any, Any], Any], items: Sequence[Any],
                      context: Any = None) -> Iterable[tuple[int, Any]]:
        if self.workers == 1:
            for i, item in enumerate(items):
                try:
                    yield i, fn(context, item)
                except Exception as exc:  # noqa: BLE001 - reported to the caller per item
                    yield i, exc
            return
        pool = self._get_pool(context)
        futures = {pool.submit(_call, fn, item): i for i, item in enumerate(items)}
        try:
            for fut in cf.as_completed(futures):
                i = futures[fut]
                try:
                    yield i, fut.result()
                except cf.process.BrokenProcessPool as exc:
                    # a worker died (segfault, OOM kill): restart the pool for later batches
                    self.close()
                    yield i, exc
                except Exception as exc:  # noqa: BLE001
                    yield i, exc
        finally:
            for fut in futures:
                fut.cancel()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


@hookimpl
def softsbi_executors():
    return [LocalExecutor]
