"""One writer per run directory: an advisory file lock (``filelock``) held for the whole fit.

The lock is an OS-level lock on ``RUN/run.lock``: it is released when the holding process ends,
even by SIGKILL, so a killed fit never leaves a stale lock. The holder's pid and start time are
written next to it (``RUN/run.lock.json``) so that a second writer can say who holds it.
"""
from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
from pathlib import Path
from typing import Iterator

from filelock import FileLock, Timeout

from softsbi.core.errors import SoftsbiError


class RunLocked(SoftsbiError):
    """Another process is writing this run directory."""


class RunDirError(SoftsbiError):
    """The run directory cannot be created or written (a file, read-only, no space)."""


@contextlib.contextmanager
def run_lock(run_dir: str | Path) -> Iterator[None]:
    """Hold the run directory's write lock for the ``with`` block (creating the directory).

    Raises:
        RunLocked: another process holds it; the message names its pid, since when, and the fix.
        RunDirError: the path is a file, or the directory cannot be created or written.
    """
    run_dir = Path(run_dir)
    try:
        if run_dir.exists() and not run_dir.is_dir():
            raise RunDirError(f"--out '{run_dir}' is a file, not a run directory; choose a folder path")
        run_dir.mkdir(parents=True, exist_ok=True)
        lock = FileLock(str(run_dir / "run.lock"), timeout=0)
        info = run_dir / "run.lock.json"
        lock.acquire()
    except Timeout:
        try:
            holder = json.loads(info.read_text())
            who = f"pid {holder.get('pid')}, since {holder.get('since')}"
        except (OSError, ValueError):
            who = "pid unknown"
        raise RunLocked(f"run directory '{run_dir}' is being written by another softsbi process ({who}); wait "
                        f"for it to finish (then the same command resumes) or fit into another --out") from None
    except OSError as exc:  # after Timeout, which is an OSError (TimeoutError) too
        raise RunDirError(f"cannot write the run directory '{run_dir}' ({exc.strerror or exc}); choose a writable "
                          f"--out (or free space / fix its permissions)") from None
    try:
        info.write_text(json.dumps({"pid": os.getpid(), "since": _dt.datetime.now().isoformat(timespec="seconds")}))
        yield
    finally:
        lock.release()
