"""What every command shares when it runs: :func:`guard` (errors, Ctrl-C and SIGTERM as one line or one JSON
error) and :func:`json_done` (the ``--json`` epilogue)."""
from __future__ import annotations

import contextlib
import functools
import inspect
import os
import sys
import warnings
from typing import Any, Callable

import typer

from softsbi.cli.output import Output, json_error
from softsbi.core.errors import SoftsbiError, SoftsbiWarning, storage_error


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the command is, so that it stops as after Ctrl-C: finished work kept, one line."""


#: commands running in this process (:func:`guard`): where a SIGTERM stops a command rather than the process
_running = 0


def terminate(signum: int, frame: Any) -> None:
    """The SIGTERM handler of the ``softsbi`` command: raise :class:`Terminated` inside a command (:func:`guard`);
    outside one (the options being parsed, or Python shutting down after the command ended: its exit handlers)
    end the process at once with exit code 143, its output flushed, as SIGTERM's default does, never with a
    traceback from where the signal landed."""
    if _running:
        raise Terminated()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(143)


def json_done(o: Output, doc: Any) -> bool:
    """The epilogue every command shares: under ``--json`` write ``doc`` as the command's one JSON document and
    return True (the command returns; nothing else goes to stdout); otherwise False (the command prints its
    tables and sentences)."""
    if o.as_json:
        o.emit_json(doc)
    return o.as_json


def _show_warning(default, message, category, filename, lineno, file=None, line=None) -> None:
    """A :class:`~softsbi.core.errors.SoftsbiWarning` as one ``warning:`` line on stderr; other warnings as
    ``default`` (Python's ``warnings.showwarning``) shows them."""
    if issubclass(category, SoftsbiWarning):
        Output().err.print(f"warning: {message}", soft_wrap=True)
    else:
        default(message, category, filename, lineno, file, line)


def _fail(as_json: bool, exc: BaseException, code: int) -> typer.Exit:
    """Say ``exc`` in one line on stderr (a JSON error on stdout under ``--json``); the exit with ``code``."""
    if as_json:
        sys.stdout.write(json_error(exc) + "\n")
    else:
        Output().error(str(exc))
    return typer.Exit(code)


def _out_flag(fn: Callable[..., Any]) -> str | None:
    """``"--out"`` when the command ``fn`` has that option (a disk that refuses a write may be fixed by choosing
    another folder), else None (the command writes into a run it is given)."""
    for p in inspect.signature(fn).parameters.values():
        decls = getattr(p.default, "param_decls", None)
        if decls is not None and ("--out" in decls or (not decls and p.name == "out")):
            return "--out"
    return None


def guard(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Run a command: a SoftsbiError prints one line (or a JSON error under ``--json``) and exits 2;
    Ctrl-C says how to resume; under ``--json`` any other error is a JSON error with exit 1. A disk that refuses a
    write is one line whose fix names ``--out`` only when the command has it."""
    out_flag = _out_flag(fn)

    @functools.wraps(fn)
    def wrapper(*a, **kw):
        global _running
        as_json = bool(kw.get("as_json"))
        _running += 1
        try:
            with warnings.catch_warnings():
                warnings.showwarning = functools.partial(_show_warning, warnings.showwarning)
                return fn(*a, **kw)
        except (typer.Exit, typer.Abort):
            raise
        except SoftsbiError as exc:
            raise _fail(as_json, exc, 2) from None
        except KeyboardInterrupt as stop:
            what = "terminated (SIGTERM)" if isinstance(stop, Terminated) else "interrupted"
            exc = KeyboardInterrupt(f"{what}; finished simulations are kept: re-run the same command to resume")
            raise _fail(as_json, exc, 143 if isinstance(stop, Terminated) else 130) from None
        except Exception as exc:
            err = storage_error(exc, out_flag=out_flag)  # a full or read-only disk is the machine's state, not a bug
            if err is not None:
                raise _fail(as_json, err, 2) from None
            if as_json:
                raise _fail(True, exc, 1) from None
            raise
        finally:
            _running -= 1
    return wrapper
