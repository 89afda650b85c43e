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
import tempfile
from pathlib import Path
from typing import Iterator

from filelock import FileLock, Timeout

from softsbi.core.errors import SoftsbiError, storage_error


class RunLocked(SoftsbiError):
    """Another process is writing this run directory."""


class RunDirError(SoftsbiError):
    """The run directory cannot be created or written (a file, read-only, no space)."""


def _storage_line(exc: OSError, run_dir: Path, out_flag: str | None) -> SoftsbiError:
    fix = f"choose a writable {out_flag} (or free space / fix its permissions)" if out_flag else \
        "free space or fix its permissions (or copy the run directory to a writable place and run there)"
    return storage_error(exc, run_dir, resumable=True, out_flag=out_flag) or RunDirError(
        f"cannot write the run directory '{run_dir}' ({exc.strerror or exc}); {fix}")


@contextlib.contextmanager
def run_lock(run_dir: str | Path, command: str = "fit", busy: str | None = None,
             out_flag: str | None = "--out") -> Iterator[None]:
    """Hold the run directory's write lock for the ``with`` block (creating the directory).

    Args:
        command: the softsbi command taking the lock (a second writer's message names it).
        busy: what a second writer is told to do (default: wait, or fit into another ``--out``).
        out_flag: the command's flag that chooses the directory, named in the fix of a disk that refuses a write;
            None for a command that writes into a run it is given (``calibrate``).

    Raises:
        RunLocked: another process holds it; the message names its command, pid, since when, and the fix.
        RunDirError: the path is a file, or the directory cannot be created or written.
    """
    run_dir = Path(run_dir)
    try:
        if run_dir.exists() and not run_dir.is_dir():
            raise RunDirError(f"--out '{run_dir}' is a file, not a run directory; choose a folder path")
        created = not run_dir.exists()
        run_dir.mkdir(parents=True, exist_ok=True)
        lock = FileLock(str(run_dir / "run.lock"), timeout=0)
        info = run_dir / "run.lock.json"
        lock.acquire()
    except Timeout:
        try:
            holder = json.loads(info.read_text())
            who = f"`softsbi {holder.get('command', 'fit')}`, pid {holder.get('pid')}, since {holder.get('since')}"
        except (OSError, ValueError, AttributeError):
            who = "pid unknown"
        raise RunLocked(f"run directory '{run_dir}' is being written by another softsbi process ({who}); "
                        + (busy or "wait for it to finish (then the same command resumes) or fit into another --out")
                        ) from None
    except OSError as exc:  # after Timeout, which is an OSError (TimeoutError) too
        if isinstance(exc, SoftsbiError):
            raise
        raise _storage_line(exc, run_dir, out_flag) from None
    try:
        info.write_text(json.dumps({"pid": os.getpid(), "since": _dt.datetime.now().isoformat(timespec="seconds"),
                                    "command": command}))
        yield
    except BaseException as exc:
        if created:
            with contextlib.suppress(OSError):
                _remove_if_only_lock(run_dir, lock)
        err = storage_error(exc, run_dir, resumable=True, out_flag=out_flag)
        if err is not None:  # the disk refused a write mid-run: one line, the run resumes once fixed
            raise err from None
        raise
    finally:
        lock.release()


def _remove_if_only_lock(run_dir: Path, lock: FileLock) -> None:
    """A directory this call created and that still holds nothing but the lock files (the command
    failed before storing anything, e.g. an unknown plugin name) is removed, so no empty run is left."""
    names = {p.name for p in run_dir.iterdir()}
    if names <= {"run.lock", "run.lock.json"}:
        lock.release()
        for n in names:
            (run_dir / n).unlink(missing_ok=True)
        with contextlib.suppress(OSError):
            run_dir.rmdir()


def _is_run(folder: Path) -> bool:
    return (folder / "run.zarr").is_dir()


def _same(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and a.samefile(b))
    except OSError:
        return False


def check_out_apart(out: str | Path, command: str, run: str | Path | None = None,
                    recording: str | Path | None = None) -> Path:
    """Refuse, before any work, an output folder that would mix two runs' files (``diagnose``, ``fit`` and ``demo``
    share this guard).

    Args:
        out: the folder the command writes (``--out``).
        command: the command, named in the message.
        run: the run directory whose results the command writes (``diagnose``: the diagnosed run; ``fit``: ``out``
            itself, which it resumes); None when ``out`` holds runs of its own (``demo``).
        recording: the recording the command reads (``fit --observed``).

    Returns:
        ``Path(out)``.

    Raises:
        RunDirError: ``out`` is the recording folder; ``out``, or a folder above it, is the run directory of another
            fit (a refit folder of a diagnosis included); ``out`` holds the diagnosis of another run. One line naming
            both folders and the fix.
    """
    path = Path(out)
    fix = "choose a folder of its own (a new one, or one outside every run)"
    if recording is not None and _same(path, Path(recording)):
        raise RunDirError(f"--out '{path}' is the recording folder (--observed); {command} would write its run "
                          f"among the recording's files: {fix}")
    for folder in (path, *path.absolute().parents):
        if not _is_run(folder):
            continue
        if run is not None and _same(folder, Path(run)):
            break
        where = "is" if folder == path else f"lies inside '{folder}',"
        raise RunDirError(f"--out '{path}' {where} the run directory of another fit; {command} would write into it "
                          f"and mix the two runs' files: {fix}")
    if run is not None and not _same(path, Path(run)):
        try:
            other = json.loads((path / "diagnosis.json").read_text()).get("run")
        except (OSError, ValueError, AttributeError):
            other = None
        if isinstance(other, str) and Path(other).exists() and not _same(Path(other), Path(run)):
            raise RunDirError(f"--out '{path}' holds the diagnosis of another run ('{other}'); {command} would "
                              f"replace it and mix the two runs' refits: {fix}")
    return path


def check_out_dir(path: str | Path, flag: str = "--out", fix: str = "choose a writable folder") -> Path:
    """Check, before any work, that a command can write into the folder ``path`` (which may not exist yet).

    Args:
        flag: how the command names the folder in its message (``--out``, ``DST``, ``run directory``).
        fix: what to do when it cannot be written.

    Returns:
        ``Path(path)``.

    Raises:
        RunDirError: ``path`` or a folder above it is a file, or the deepest existing folder refuses a
            new file (read-only file system, no permission); one line naming the folder and ``fix``.
    """
    path = Path(path)
    above = next((p for p in (path, *path.absolute().parents) if p.exists()), None)
    if above is None:
        return path
    if not above.is_dir():
        raise RunDirError(f"{flag} '{path}'" + (" is a file" if above == path else f": '{above}' is a file")
                          + "; give a folder")
    try:
        with tempfile.TemporaryFile(dir=above):
            pass
    except OSError as exc:
        raise RunDirError(f"{flag} '{path}' cannot be written ({exc.strerror or exc}); {fix}") from None
    return path
