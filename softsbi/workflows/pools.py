"""One started pool of workers per command: the batches of a command share their executor.

A command runs many batches of simulations: a fit's rounds, its evaluation and its best fit; the phases of
``check`` and ``diagnose``; a diagnosis's refits. Starting a local pool costs seconds (each worker process imports
softsbi, its plugins and the simulator before its first job), so a pool per batch spent more time starting workers
than simulating on small fits. Inside :func:`shared_executors`, which every workflow that runs batches enters (an
inner one joins the outer), :func:`executor` gives one executor per plugin and options, started once and closed when
the outermost block ends; outside one it gives a fresh executor, closed when its ``with`` ends.
"""
from __future__ import annotations

import contextlib
import json
from typing import Any, Iterator, Mapping

from softsbi.core.interfaces import Executor
from softsbi.plugins import registry

#: the executors of the running command by ``[plugin, workers, options]`` (None: no command is sharing them)
_shared: dict[str, Executor] | None = None


@contextlib.contextmanager
def shared_executors() -> Iterator[None]:
    """Share executors inside this block (and every block nested in it); close them when it ends."""
    global _shared
    if _shared is not None:
        yield
        return
    _shared = {}
    try:
        yield
    finally:
        started, _shared = _shared, None
        for exe in started.values():
            exe.close()


@contextlib.contextmanager
def executor(name: str, workers: int | None, options: Mapping[str, Any] | None = None) -> Iterator[Executor]:
    """The executor plugin ``name`` with ``workers`` and ``options``: the command's shared one inside
    :func:`shared_executors`, else a fresh one closed when the ``with`` ends.

    Raises:
        Whatever the plugin's constructor raises for bad options.
    """
    def made() -> Executor:
        return registry().executor(name)(workers=workers, **dict(options or {}))

    if _shared is None:
        exe = made()
        try:
            yield exe
        finally:
            exe.close()
        return
    key = json.dumps([name, workers, dict(options or {})], sort_keys=True, default=str)
    if key not in _shared:
        _shared[key] = made()
    yield _shared[key]
