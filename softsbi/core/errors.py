"""Exception hierarchy of softsbi.

Every error softsbi raises on purpose derives from :class:`SoftsbiError`, so a caller
(or the CLI) can catch one type and print a single clear message. Each message names
the problem and the fix.
"""
from __future__ import annotations

import difflib
import os
import re
from pathlib import Path
from typing import Iterable


class SoftsbiError(Exception):
    """Base class of all deliberate softsbi errors."""


class SoftsbiWarning(UserWarning):
    """An input softsbi accepts but that is likely a mistake (the CLI prints it as one ``warning:`` line)."""


class PluginNotFound(SoftsbiError, KeyError):
    """A simulator / effect / observer / estimator / executor name is not registered."""

    def __init__(self, kind: str, name: str, available: Iterable[str]):
        available = sorted(available)
        close = difflib.get_close_matches(name, available, n=1)
        hint = f" Did you mean '{close[0]}'?" if close else ""
        msg = (f"unknown {kind} '{name}'.{hint} Installed {kind}s: "
               f"{', '.join(available) or '(none)'}. Run `softsbi plugins` to list them.")
        super().__init__(msg)
        self.kind, self.name, self.available = kind, name, available

    def __str__(self) -> str:  # KeyError would otherwise repr() the message
        return self.args[0]


class DependencyMissing(SoftsbiError, ImportError):
    """An optional dependency needed by a plugin is not installed."""


class SchemaError(SoftsbiError):
    """A run store or data folder does not have the expected layout or version."""


class PosteriorDamaged(SchemaError):
    """A round's posterior in a run store is missing, unreadable or does not match its checksum.

    Attributes:
        problem: what is wrong, without the fix (the message is ``"<problem>; <fix>"``).
    """

    def __init__(self, problem: str, fix: str):
        super().__init__(f"{problem}; {fix}")
        self.problem = problem


class ObservedDamaged(PosteriorDamaged):
    """A run store's ``observed`` group (the recording as the fit observed it) is missing or cannot be read; it can
    be rebuilt from the recording (``problem`` names what is wrong)."""


class DataError(SoftsbiError, ValueError):
    """Observed data is missing, malformed or non-finite."""


class ShapeError(SoftsbiError, ValueError):
    """An array does not have the documented shape."""


class ParameterError(SoftsbiError, ValueError):
    """A parameter is unknown, outside its bounds, or not supported by a backend."""


class PosteriorError(SoftsbiError, RuntimeError):
    """A posterior cannot be sampled (no mass inside the prior box, or a truncation region too small)."""


class EnvironmentFault(SoftsbiError, RuntimeError):
    """The machine cannot run a simulation at all (an engine or system library that cannot load).

    Not a failed simulation: a fit stops the round with this message and stores nothing as
    failed, so the same command resumes once the environment is fixed.
    """


class RenderingUnavailable(EnvironmentFault):
    """Rendering was asked for but no off-screen OpenGL back-end works; the message names the fix."""


class SimulationFailed(SoftsbiError, RuntimeError):
    """A simulation diverged or produced an implausible state."""


def closest(name: str, choices: Iterable[str]) -> str:
    """Return " Did you mean 'x'?" for the closest choice, or an empty string."""
    close = difflib.get_close_matches(name, list(choices), n=1)
    return f" Did you mean '{close[0]}'?" if close else ""


class EffectFault(RuntimeError):
    """An effect plugin's code gave an unusable value during a rollout (e.g. a non-finite force). Not a
    :class:`SoftsbiError`: the rollout is a failed simulation whose reason names the effect (a parameter region
    may trigger it), and the command goes on."""


class PluginError(SoftsbiError, TypeError):
    """A plugin is malformed: wrong base class, duplicate name, unknown hook."""


class StorageError(SoftsbiError, OSError):
    """The disk refused a write: full, over quota, read-only or not permitted (``errno`` kept)."""

    def __str__(self) -> str:
        return self.strerror or super().__str__()


#: errno values that mean "the storage refused the write" (not a bug): what each needs from the user
STORAGE_ERRNOS = {28: "no space left on the device", 122: "disk quota exceeded",
                  27: "file too large (over the file system's or the process's file-size limit)",
                  30: "the file system is read-only", 13: "permission denied", 1: "operation not permitted"}
#: numpy's short write (``ndarray.tofile`` inside ``numpy.save``) carries no errno: the disk filled up mid-file
_SHORT_WRITE = re.compile(r"^\d+ requested and \d+ written$")


def storage_error(exc: BaseException, where: object = None, resumable: bool = False,
                  out_flag: str | None = "--out") -> StorageError | None:
    """One clear line for an ``OSError`` the storage raised (ENOSPC, EDQUOT, EFBIG, EROFS, EACCES, EPERM, and
    numpy's short write, which has no errno and is read as ENOSPC).

    Args:
        exc: the exception caught.
        where: the run directory or output path being written (named in the message).
        resumable: the command resumes where it stopped when re-run (finished work is kept).
        out_flag: the command's flag that chooses where it writes (named in the fix), None when it has none
            (``view`` and ``calibrate`` write into the run directory).

    Returns:
        a :class:`StorageError` to raise instead, or None when ``exc`` is not such an error.
    """
    if not isinstance(exc, OSError) or isinstance(exc, SoftsbiError):
        return None
    errno = exc.errno
    if errno is None and _SHORT_WRITE.match(str(exc)):
        errno = 28
    if errno not in STORAGE_ERRNOS:
        return None
    what = STORAGE_ERRNOS[errno]
    target = where if where is not None else exc.filename
    named = f" writing '{target}'" if target is not None else ""
    if errno in (28, 122, 27):
        fix = "free space" + (f" (or choose {out_flag} on another disk)" if out_flag else "") + \
            ", then re-run the same command"
    elif out_flag:
        fix = f"choose a writable {out_flag} (or copy the run directory to one and point {out_flag} at the copy)"
    else:
        fix = "copy the run directory to a writable place and run the command on the copy"
    if resumable:
        fix += "; finished simulations are kept and the run resumes"
    return StorageError(errno, f"{what}{named}; {fix}")


def as_path(value: object, argument: str, example: str) -> Path:
    """``value`` as a :class:`~pathlib.Path`, for a public function's path argument.

    Args:
        value: what the caller passed (``str`` or ``os.PathLike``).
        argument: the call and argument, e.g. ``"open_run(run_dir)"``; example: a valid call, for the message.

    Raises:
        ParameterError: ``value`` is not a path (e.g. ``None``): one line naming the argument and the fix.
    """
    if isinstance(value, (str, os.PathLike)) and str(value):
        return Path(value)
    raise ParameterError(f"{argument} must be a folder path (str or pathlib.Path), got {value!r}; e.g. {example}")
