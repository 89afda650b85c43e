"""Built-in executors: where simulations run, and how worker failures are survived.

``local`` runs jobs in a pool of worker processes on this machine (one per core by
default; ``workers=1`` runs in-process in the Python API, which is easiest to debug, and in a
worker process of its own under the ``softsbi`` command, so that a crashing simulator fails its
simulation, not the command: :data:`softsbi.executors.ISOLATE_ONE_WORKER`). Worker processes use
the ``spawn`` start method, so they never inherit torch's thread pools from the driver.

Workers do not re-run the calling script. ``spawn`` normally imports the driver's ``__main__``
(a user's ``python my_fit.py``) in every worker, so a script without an ``if __name__ ==
"__main__":`` guard would run its own fit again in each worker (measured: the README's Python
example saved as a file hung, its workers stopping on the run's lock). softsbi's jobs and
contexts are importable from softsbi and its plugins, so a worker starts from them alone; only
when the job function or the context refers to something defined in ``__main__`` is the script
imported as usual (and then it needs the guard, as with any ``spawn`` pool).

A worker that dies *while starting* (before its first handshake: an import error in a plugin,
a context that cannot be unpickled) ran no job: its job is handed on without being charged an
attempt, and after ``STARTUP_FAILURES`` such deaths in a row with no worker started,
:class:`WorkerStartupError` stops the batch with one line instead of retrying forever.

Fault tolerance (shared by every executor of softsbi, see also
:mod:`softsbi.executors.ray_executor`):

* a job whose worker process *dies* (``os._exit``, segfault, OOM kill) or *hangs* longer
  than ``timeout`` seconds is re-run, at most ``retries`` more times, on a fresh worker;
* after that it is given up: :class:`WorkerCrashed` or :class:`SimulationTimeout` (both
  :class:`WorkerFailure`) is yielded in place of its result, and the batch goes on;
* an exception *raised by the job function* is not retried (it would raise again): the
  exception object itself is yielded.

The local pool hands one job at a time to each worker over its own pipe, so the driver
always knows which job a dead or hung worker was running: only that job is charged an
attempt, only that worker is replaced, and the other workers keep their work.
"""
from __future__ import annotations

import collections
import contextlib
import multiprocessing as mp
import multiprocessing.connection as mpc
import os
import pickle
import signal
import sys
import time
import types
from typing import Any, Callable, ClassVar, Iterable, Sequence

from softsbi import executors
from softsbi.core.defaults import RETRIES
from softsbi.core.errors import SoftsbiError
from softsbi.core.interfaces import Executor
from softsbi.plugins.hookspecs import hookimpl


class WorkerFailure(RuntimeError):
    """A job was given up after its worker crashed or hung on every attempt.

    Yielded (not raised) by :meth:`Executor.map_unordered` in place of the job's result;
    ``str(exc)`` is the reason stored with the failed simulation. Not a ``SoftsbiError``:
    it fails one simulation, never the fit.

    Attributes:
        attempts: how many times the job was started.
    """

    def __init__(self, message: str, attempts: int = 1):
        super().__init__(message)
        self.attempts = attempts


class WorkerCrashed(WorkerFailure):
    """The worker process running the job died (signal, ``os._exit``, lost node)."""


class SimulationTimeout(WorkerFailure):
    """The job ran longer than the executor's ``timeout`` (its worker was killed)."""


class WorkerStartupError(SoftsbiError):
    """Worker processes die while starting, before they can run any job.

    Raised (not yielded) by :meth:`LocalExecutor.map_unordered` after :data:`STARTUP_FAILURES` such
    deaths in a row: no simulation can run, so the fit stops; every result stored so far is kept.
    """


class ExecutorOptionError(SoftsbiError, ValueError):
    """An executor option (workers, timeout, retries) has an invalid value."""


def check_options(workers: int | None, timeout: float | None, retries: int) -> None:
    """Validate the options common to all executors.

    Raises:
        ExecutorOptionError (a ValueError): ``workers < 1``, ``timeout <= 0`` or ``retries < 0``.
    """
    if workers is not None and int(workers) < 1:
        raise ExecutorOptionError(f"--workers must be >= 1 (got {workers}); use 1 to run simulations in this "
                                  f"process")
    if timeout is not None and not float(timeout) > 0:
        raise ExecutorOptionError(f"the per-simulation timeout must be > 0 seconds (got {timeout}); leave it "
                                  f"unset for none")
    if int(retries) < 0:
        raise ExecutorOptionError(f"retries must be >= 0 (got {retries})")


#: worker deaths before the handshake, in a row, after which a batch stops (WorkerStartupError)
STARTUP_FAILURES = 3
#: the first message of a worker: it has started and unpickled its context
_READY = "softsbi-worker-ready"
#: a message ``(_NEW_CONTEXT, context)`` to an idle worker: later jobs run with ``context`` (a pool's workers are
#: started once and serve batches of different contexts: a fit's rounds, its evaluation, a check's phases)
_NEW_CONTEXT = "softsbi-worker-context"

# ----------------------------------------------------------------------------------------
# worker side

def _worker_main(conn: mpc.Connection, context: Any) -> None:
    """Loop of one worker process: send :data:`_READY`, then receive ``(i, fn, item)`` and send
    ``(i, ok, result)`` until told to stop (``None``) or the pipe closes."""
    # simulations are single-threaded; keep BLAS from oversubscribing the cores
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    # Ctrl-C in a terminal reaches the whole process group: the driver stops the command and kills its busy
    # workers, so a worker never reports the interrupt as a failed simulation
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        conn.send(_READY)
    except (OSError, ValueError):
        return
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        if msg[0] == _NEW_CONTEXT:
            context = msg[1]
            continue
        i, fn, item = msg
        try:
            out = (i, True, fn(context, item))
        except BaseException as exc:  # noqa: BLE001 - reported to the driver per item
            out = (i, False, exc)
        try:
            conn.send(out)
        except Exception as exc:  # noqa: BLE001 - unpicklable result or exception
            conn.send((i, False, RuntimeError(f"job {i}: its result could not be sent back: "
                                              f"{type(exc).__name__}: {exc}; original: {out[2]!r}"[:2000])))


def refers_to_main(*objects: Any) -> bool:
    """Whether pickling ``objects`` refers to the driver's ``__main__`` module (a job function or
    context defined in the user's script), which a worker can only unpickle by importing the script.

    Conservative: ``True`` also when the objects cannot be pickled or merely hold the text
    ``"__main__"``; then workers start the way plain ``spawn`` starts them.
    """
    try:
        return b"__main__" in pickle.dumps(objects, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:  # noqa: BLE001 - unpicklable: let multiprocessing report it as usual
        return True


@contextlib.contextmanager
def _main_script_hidden():
    """While a worker process starts, show ``spawn`` a ``__main__`` without a file or module name,
    so that the worker does not import (and run) the caller's script."""
    main = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        if main is None:
            del sys.modules["__main__"]
        else:
            sys.modules["__main__"] = main


class _Worker:
    def __init__(self, ctx: Any, context: Any, import_main: bool = True):
        self.conn, child = ctx.Pipe(duplex=True)
        self.proc = ctx.Process(target=_worker_main, args=(child, context), daemon=True)
        with contextlib.nullcontext() if import_main else _main_script_hidden():
            self.proc.start()
        child.close()
        self.ready = False  # the worker's handshake has arrived
        self.job: int | None = None
        self.started = 0.0
        self.deadline = float("inf")
        self.jobs = 0  # jobs handed to this worker so far

    def kill(self) -> None:
        try:
            self.conn.close()
        except OSError:
            pass
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join(5)

    def stop(self) -> None:
        try:
            self.conn.send(None)
        except (OSError, ValueError):
            pass
        self.proc.join(2)
        self.kill()


class LocalExecutor(Executor):
    """A pool of worker processes on this machine, surviving crashed and hung workers.

    Args:
        workers: number of worker processes (default: ``os.cpu_count()``).
        timeout: per-job limit in seconds (None = none); a job running longer has its worker
            killed and counts as a failed attempt.
        retries: how many times a job whose worker crashed or hung is re-run (default 2).
        in_process: run jobs in this process, one after the other (default: ``workers == 1`` and
            no ``timeout``, unless :data:`softsbi.executors.ISOLATE_ONE_WORKER`, which the ``softsbi`` command
            sets); no crash or hang protection then (a crash kills the driver).
        startup_grace: extra seconds allowed to the first job of a fresh worker process, which
            pays for imports and one-time set-up (loading plugins takes seconds).

    Raises:
        ValueError: ``workers < 1``, ``timeout <= 0`` or ``retries < 0``.
    """

    name: ClassVar[str] = "local"

    def __init__(self, workers: int | None = None, timeout: float | None = None, retries: int = RETRIES,
                 in_process: bool | None = None, startup_grace: float = 60.0):
        check_options(workers, timeout, retries)
        self.startup_grace = float(startup_grace)
        self.workers = (os.cpu_count() or 1) if workers is None else int(workers)
        self.timeout = None if timeout is None else float(timeout)
        self.retries = int(retries)
        if in_process is None:
            in_process = self.workers == 1 and self.timeout is None and not executors.ISOLATE_ONE_WORKER
        self.in_process = bool(in_process)
        self._mp = mp.get_context("spawn")
        self._pool: list[_Worker] = []
        self._context: Any = None
        self._import_main = False  # whether the pool's workers imported the caller's __main__
        #: counts since construction: workers started, crashed (startup deaths included), killed on timeout,
        #: died while starting
        self.stats = {"started": 0, "crashed": 0, "timed_out": 0, "startup_failed": 0}

    # -- pool ---------------------------------------------------------------------------
    def _spawn(self) -> _Worker:
        self.stats["started"] += 1
        return _Worker(self._mp, self._context, import_main=self._import_main)

    def _ensure_pool(self, context: Any, import_main: bool = False) -> None:
        """Start the missing workers; a pool already started is kept, and told ``context`` when it changed
        (workers that did not import the caller's script are replaced when ``context`` or the job needs it)."""
        if self._pool and import_main and not self._import_main:
            self.close()
        if not self._pool:  # a pool that is kept keeps how its workers started
            self._import_main = import_main
        changed, self._context = self._context is not context, context
        for w in self._pool if changed else ():
            try:
                w.conn.send((_NEW_CONTEXT, context))
            except (OSError, ValueError):  # died while idle: replaced below, with the new context
                w.kill()
        self._pool = [w for w in self._pool if w.proc.is_alive()]
        while len(self._pool) < self.workers:
            self._pool.append(self._spawn())

    def worker_pids(self) -> list[int]:
        """Process ids of the live workers (for monitoring and benchmarks)."""
        return [w.proc.pid for w in self._pool if w.proc.is_alive()]

    # -- jobs ---------------------------------------------------------------------------
    def map_unordered(self, fn: Callable[[Any, Any], Any], items: Sequence[Any],
                      context: Any = None) -> Iterable[tuple[int, Any]]:
        """Yield ``(index, fn(context, items[index]))`` in completion order.

        A job whose worker crashed or exceeded ``timeout`` on ``1 + retries`` attempts yields
        a :class:`WorkerCrashed` / :class:`SimulationTimeout` instead; an exception raised by
        ``fn`` is yielded as is (not retried).
        """
        if self.in_process:
            for i, item in enumerate(items):
                try:
                    yield i, fn(context, item)
                except Exception as exc:  # noqa: BLE001 - reported to the caller per item
                    yield i, exc
            return
        if len(items) == 0:
            return
        self._ensure_pool(context, import_main=refers_to_main(fn, context))
        queue = collections.deque(range(len(items)))
        attempts = [0] * len(items)
        remaining = len(items)
        startup_deaths = 0  # workers in a row that died before their handshake
        try:
            while remaining:
                for w in self._pool:  # hand one job to every idle worker
                    if w.job is None and queue:
                        i = queue.popleft()
                        try:
                            w.conn.send((i, fn, items[i]))
                        except (OSError, ValueError):  # the worker died while idle
                            queue.appendleft(i)
                            continue
                        attempts[i] += 1
                        w.job, w.started = i, time.monotonic()
                        if self.timeout is not None:
                            w.deadline = w.started + self.timeout + (self.startup_grace if w.jobs == 0 else 0.0)
                        w.jobs += 1
                busy = [w for w in self._pool if w.job is not None]
                wait_s = None
                if self.timeout is not None and busy:
                    wait_s = max(0.0, min(w.deadline for w in busy) - time.monotonic())
                waitables = [w.conn for w in self._pool] + [w.proc.sentinel for w in self._pool]
                mpc.wait(waitables, timeout=wait_s)
                now = time.monotonic()
                for k, w in enumerate(self._pool):
                    i = w.job
                    failure: WorkerFailure | None = None
                    try:
                        has_msg = w.conn.poll()
                    except (OSError, EOFError):
                        has_msg = False
                    if has_msg and not w.ready:
                        try:
                            w.conn.recv()  # the handshake (_READY) is the first message
                        except (EOFError, OSError):  # died while starting
                            w.proc.join(5)
                            has_msg = False
                        else:
                            w.ready = True
                            startup_deaths = 0
                            try:
                                has_msg = w.conn.poll()
                            except (OSError, EOFError):
                                has_msg = False
                    if has_msg:
                        try:
                            j, ok, res = w.conn.recv()
                        except (EOFError, OSError):  # pipe closed: the worker is exiting
                            w.proc.join(5)
                        else:
                            if i is None or j != i:  # stray message: should not happen
                                continue
                            w.job = None
                            remaining -= 1
                            yield i, res  # res is the exception object when not ok
                            continue
                    if not w.proc.is_alive():
                        self.stats["crashed"] += 1
                        code = w.proc.exitcode
                        w.kill()
                        if not w.ready:  # died while starting: its job never ran
                            self.stats["startup_failed"] += 1
                            startup_deaths += 1
                            if startup_deaths >= STARTUP_FAILURES:
                                raise WorkerStartupError(
                                    f"simulation worker processes die while starting ({startup_deaths} in a row, "
                                    f"last exit code {code}{_signal_name(code)}; what they printed is above), so no "
                                    f"simulation can run; fix what they printed (the Python API with workers=1 "
                                    f"shows the error in its own process), then the same command resumes")
                            if i is not None:
                                attempts[i] -= 1
                                queue.appendleft(i)
                            self._pool[k] = self._spawn()
                            continue
                        self._pool[k] = self._spawn()
                        if i is None:
                            continue
                        failure = WorkerCrashed(f"worker process died running this simulation (exit code {code}"
                                                f"{_signal_name(code)}) on {attempts[i]} attempt(s)", attempts[i])
                    elif i is not None and self.timeout is not None and now >= w.deadline:
                        self.stats["timed_out"] += 1
                        w.kill()
                        self._pool[k] = self._spawn()
                        failure = SimulationTimeout(f"simulation exceeded the {self.timeout:g} s timeout on "
                                                    f"{attempts[i]} attempt(s); its worker was killed", attempts[i])
                    if failure is not None and i is not None:
                        if attempts[i] <= self.retries:
                            queue.appendleft(i)  # retry first, on a fresh worker
                        else:
                            remaining -= 1
                            yield i, failure
        finally:
            # the caller stopped early (or raised): kill workers still busy so that no
            # stale result reaches a later batch
            for k, w in enumerate(self._pool):
                if w.job is not None:
                    w.kill()
                    self._pool[k] = None  # type: ignore[call-overload]
            self._pool = [w for w in self._pool if w is not None]

    def close(self) -> None:
        """Stop all workers (idle ones exit cleanly, busy ones are killed)."""
        for w in self._pool:
            if w.job is None:
                w.stop()
            else:
                w.kill()
        self._pool = []
        self._context = None


def _signal_name(code: int | None) -> str:
    if code is None or code >= 0:
        return ""
    try:
        return f", {signal.Signals(-code).name}"
    except ValueError:
        return ""


@hookimpl
def softsbi_executors():
    return [LocalExecutor]
