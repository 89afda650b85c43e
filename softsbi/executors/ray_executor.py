"""The ``ray`` executor: simulations as Ray tasks, on this machine or an existing Ray cluster.

Install with ``pip install softsbi[ray]``. Each job is one Ray task (``num_cpus=1``); at most
``workers`` tasks are in flight at a time (default: every CPU of the cluster), results stream
back as they finish (``ray.wait``), and the shared context is put into Ray's object store once
per batch and fetched once per worker process.

Fault tolerance is the same as the ``local`` executor's (see :mod:`softsbi.executors.local`):
a task whose worker process dies (``WorkerCrashedError``, lost node) or that runs longer than
``timeout`` seconds (then cancelled with ``force=True``, which kills its worker) is re-run at
most ``retries`` more times, then yielded as :class:`~softsbi.executors.local.WorkerCrashed` /
:class:`~softsbi.executors.local.SimulationTimeout`. Ray's own task retries are switched off so
the count is softsbi's. An exception raised by the job function is yielded as is.

Note: ``timeout`` is measured from submission; since no more than ``workers`` tasks are in
flight, that is the run time plus the scheduling delay (seconds for a fresh worker process).
"""
from __future__ import annotations

import collections
import os
import socket
import time
from typing import Any, Callable, ClassVar, Iterable, Sequence

from softsbi.core.errors import DependencyMissing, SoftsbiError
from softsbi.executors.local import SimulationTimeout, WorkerCrashed, WorkerFailure, check_options
from softsbi.core.interfaces import Executor
from softsbi.plugins.hookspecs import hookimpl

INSTALL_HINT = "pip install softsbi[ray]  (or: pip install 'ray>=2.9')"

#: worker side: context objects already fetched, by object-ref id
_CONTEXTS: dict[str, Any] = {}


def _import_ray():
    try:
        import ray  # optional: the 'ray' extra
    except ImportError as exc:
        raise DependencyMissing(f"the 'ray' executor needs Ray, which is not installed ({exc}); install it with "
                                f"`{INSTALL_HINT}`, or use --executor local") from None
    return ray


def _run_job(fn: Callable[[Any, Any], Any], ctx_box: list, item: Any) -> Any:
    """Ray task body: ``fn(context, item)``, the context fetched once per worker process."""
    import ray  # optional: the 'ray' extra (a worker process of a Ray cluster)
    ref = ctx_box[0]
    if ref is None:
        return fn(None, item)
    key = ref.hex()
    if key not in _CONTEXTS:
        _CONTEXTS.clear()
        _CONTEXTS[key] = ray.get(ref)
    return fn(_CONTEXTS[key], item)


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fail fast, with the fix, when a ``host:port`` cluster address does not answer."""
    if address in ("auto", "local") or "://" in address:
        return
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise SoftsbiError(f"--ray-address '{address}' is not host:port (e.g. 10.0.0.5:6379), 'auto' or "
                           f"ray://host:10001")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except OSError as exc:
        raise SoftsbiError(f"cannot reach a Ray cluster at --ray-address {address} ({exc}); start one there with "
                           f"`ray start --head --port={port}` (and `ray start --address={address}` on the other "
                           f"machines), check the host/port and firewall, or leave --ray-address out to start Ray "
                           f"on this machine") from None


class RayExecutor(Executor):
    """Simulations as Ray tasks.

    Args:
        workers: simulations in flight at once (default: the cluster's CPU count). When this
            executor starts Ray itself (no ``address``), Ray gets ``num_cpus=workers``.
        address: address of an existing cluster (``host:port`` of its head node, ``auto``, or
            ``ray://host:10001`` for Ray Client); None starts Ray on this machine (or reuses a Ray
            already initialised in this process).
        timeout: per-simulation limit in seconds (None = none), see the module notes.
        retries: re-runs of a simulation whose worker crashed or hung (default 2).
        startup_grace: extra seconds allowed to tasks that may start a fresh worker process (the
            first ``workers`` tasks, and one after each crash or kill).
        runtime_env: Ray runtime environment of the tasks (e.g. ``{"env_vars": {...}}``), or None.

    Raises:
        DependencyMissing: Ray is not installed (the message names ``pip install softsbi[ray]``).
        SoftsbiError: the cluster at ``address`` cannot be reached (the message names the fix).
        ValueError: ``workers < 1``, ``timeout <= 0`` or ``retries < 0``.
    """

    name: ClassVar[str] = "ray"

    def __init__(self, workers: int | None = None, address: str | None = None, timeout: float | None = None,
                 retries: int = 2, runtime_env: dict[str, Any] | None = None, startup_grace: float = 60.0):
        check_options(workers, timeout, retries)
        self.startup_grace = float(startup_grace)
        ray = _import_ray()
        self._ray = ray
        self.address = address
        self.timeout = None if timeout is None else float(timeout)
        self.retries = int(retries)
        self._owns_ray = False
        if not ray.is_initialized():
            if address:
                _check_reachable(address)
            kw: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                  "configure_logging": True, "logging_level": "warning"}
            if address:
                kw["address"] = address
            else:
                kw["num_cpus"] = int(workers) if workers is not None else (os.cpu_count() or 1)
            try:
                ray.init(**kw)
            except (ConnectionError, TimeoutError, RuntimeError) as exc:
                where = f"the Ray cluster at --ray-address {address}" if address else "a local Ray instance"
                raise SoftsbiError(f"could not connect to {where}: {exc}; check that `ray status"
                                   f"{' --address ' + address if address else ''}` works, or use --executor "
                                   f"local") from None
            self._owns_ray = True
        if workers is None:
            workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
        self.workers = int(workers)
        self._fresh = self.workers  # submissions that may land on a fresh worker process
        opts: dict[str, Any] = {"num_cpus": 1, "max_retries": 0, "retry_exceptions": False}
        if runtime_env:
            opts["runtime_env"] = runtime_env
        self._remote = ray.remote(_run_job).options(**opts)
        self._ctx_obj: Any = None
        self._ctx_ref: Any = None
        self.stats = {"crashed": 0, "timed_out": 0}

    def _context_ref(self, context: Any) -> Any:
        if context is None:
            return None
        if self._ctx_ref is None or self._ctx_obj is not context:
            self._ctx_obj, self._ctx_ref = context, self._ray.put(context)
        return self._ctx_ref

    def map_unordered(self, fn: Callable[[Any, Any], Any], items: Sequence[Any],
                      context: Any = None) -> Iterable[tuple[int, Any]]:
        """Yield ``(index, fn(context, items[index]))`` in completion order (see the class notes)."""
        ray = self._ray
        if len(items) == 0:
            return
        box = [self._context_ref(context)]
        queue = collections.deque(range(len(items)))
        attempts = [0] * len(items)
        running: dict[Any, tuple[int, float]] = {}  # ref -> (index, deadline)
        try:
            while queue or running:
                while queue and len(running) < self.workers:
                    i = queue.popleft()
                    attempts[i] += 1
                    deadline = float("inf")
                    if self.timeout is not None:
                        deadline = time.monotonic() + self.timeout + (self.startup_grace if self._fresh > 0 else 0.0)
                    self._fresh = max(0, self._fresh - 1)
                    running[self._remote.remote(fn, box, items[i])] = (i, deadline)
                wait_s = None
                if self.timeout is not None:
                    wait_s = max(0.0, min(t for _, t in running.values()) - time.monotonic())
                done, _ = ray.wait(list(running), num_returns=1, timeout=wait_s, fetch_local=True)
                for ref in done:
                    i, _t = running.pop(ref)
                    try:
                        res = ray.get(ref)
                    except ray.exceptions.RayTaskError as exc:  # fn raised: not retried
                        cause = getattr(exc, "cause", None)
                        yield i, cause if isinstance(cause, BaseException) else exc
                        continue
                    except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError,
                            ray.exceptions.ObjectLostError, ray.exceptions.OwnerDiedError,
                            ray.exceptions.LocalRayletDiedError, ray.exceptions.TaskCancelledError,
                            ray.exceptions.RaySystemError) as exc:
                        self.stats["crashed"] += 1
                        self._fresh += 1
                        failure: WorkerFailure = WorkerCrashed(
                            f"Ray worker running this simulation died ({type(exc).__name__}) on {attempts[i]} "
                            f"attempt(s)", attempts[i])
                    else:
                        yield i, res
                        continue
                    if attempts[i] <= self.retries:
                        queue.appendleft(i)
                    else:
                        yield i, failure
                if self.timeout is not None:
                    now = time.monotonic()
                    for ref, (i, t) in list(running.items()):
                        if now < t:
                            continue
                        self.stats["timed_out"] += 1
                        self._fresh += 1
                        ray.cancel(ref, force=True)  # kills the worker process
                        del running[ref]
                        if attempts[i] <= self.retries:
                            queue.appendleft(i)
                        else:
                            yield i, SimulationTimeout(f"simulation exceeded the {self.timeout:g} s timeout on "
                                                       f"{attempts[i]} attempt(s); its Ray worker was killed",
                                                       attempts[i])
        finally:
            for ref in running:  # the caller stopped early: do not leave work behind
                try:
                    ray.cancel(ref, force=True)
                except Exception:  # noqa: BLE001
                    pass

    def close(self) -> None:
        """Drop the context; shut Ray down if this executor started it."""
        self._ctx_obj = self._ctx_ref = None
        if self._owns_ray and self._ray.is_initialized():
            self._ray.shutdown()
        self._owns_ray = False


@hookimpl
def softsbi_executors():
    return [RayExecutor]
