"""The JSON form of the typed results (:mod:`softsbi.core.results`) and the one atomic JSON writer every result file
goes through.

:func:`to_json` / :func:`from_json` convert any result, nested ones included, from their type hints alone; the
JSON carries a schema version (:data:`SCHEMA`) and older schemas' renamed fields are read through :data:`RENAMED`.
:func:`write_json_atomic` / :func:`read_json` write and read a JSON object so that a kill leaves the old file or the
new one and a damaged file is named with the command that writes it again.
"""
from __future__ import annotations

import collections.abc
import contextlib
import dataclasses
import json
import os
import types
import typing
from enum import Enum
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from softsbi.core.errors import STORAGE_ERRNOS, SoftsbiError

#: schema version of the JSON form of these results (3: ``Gain``'s ``difference`` and ``se`` lost their ``_m``: the
#: diagnosis score has no unit; files of older schemas are read through :data:`RENAMED`)
SCHEMA = 3

#: fields renamed since an older schema, per dataclass: ``{class name: {old name: new name}}``; :func:`from_json`
#: reads an old file's fields under their new names
RENAMED: dict[str, dict[str, str]] = {"Gain": {"difference_m": "difference", "se_m": "se"}}

#: fields added since an older schema, per dataclass: ``{class name: fill(data) -> data}`` fills an old file's
#: missing fields (after :data:`RENAMED`); :mod:`softsbi.core.results` registers a check's words on its regions and
#: phases (``_legacy_check``) and each compare row's ``metric`` (``_legacy_row``)
UPGRADED: dict[str, typing.Callable[[dict[str, Any]], dict[str, Any]]] = {}


def to_json(obj: Any) -> Any:
    """A result (or any nesting of dataclasses, tuples, mappings, numpy scalars) as plain JSON values; the
    top-level dataclass gets ``"schema": SCHEMA`` and ``"type"``."""
    out = _plain(obj)
    if dataclasses.is_dataclass(obj) and isinstance(out, dict):
        out = {"schema": SCHEMA, "type": type(obj).__name__, **out}
    return out


def _plain(obj: Any) -> Any:
    if isinstance(obj, Enum):
        return obj.value
    if dataclasses.is_dataclass(obj):
        return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def from_json(cls: type, data: Any) -> Any:
    """Rebuild a ``cls`` (a dataclass of :mod:`softsbi.core.results`) from :func:`to_json`'s form.

    Raises:
        ValueError: the data were written with a newer schema, or are not a ``cls``.
    """
    if isinstance(data, Mapping) and int(data.get("schema", SCHEMA)) > SCHEMA:
        raise ValueError(f"written by a newer softsbi (schema {data['schema']} > {SCHEMA}): upgrade softsbi")
    return _build(cls, data)


def _build(tp: Any, data: Any) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        if data is None:
            return None
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        return _build(inner[0], data)
    if dataclasses.is_dataclass(tp):
        if not isinstance(data, Mapping):
            raise ValueError(f"expected a {tp.__name__} object, got {type(data).__name__}")
        hints = typing.get_type_hints(tp)
        renamed = RENAMED.get(tp.__name__, {})
        data = {renamed.get(k, k): v for k, v in data.items()}
        if tp.__name__ in UPGRADED:
            data = UPGRADED[tp.__name__](data)
        return tp(**{f.name: _build(hints[f.name], data[f.name]) for f in dataclasses.fields(tp) if f.name in data})
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_build(args[0], v) for v in data)
        return tuple(_build(a, v) for a, v in zip(args, data))
    # typing's generic aliases name their abstract origin (``Mapping[...]`` -> collections.abc.Mapping)
    if isinstance(origin, type) and issubclass(origin, collections.abc.Mapping):
        args = typing.get_args(tp)
        return {k: (_build(args[1], v) if args else v) for k, v in data.items()}
    if isinstance(origin, type) and issubclass(origin, collections.abc.Sequence) and origin is not str:
        args = typing.get_args(tp)
        items = [(_build(args[0], v) if args else v) for v in data]
        return items if origin is list else tuple(items)
    if isinstance(tp, type) and issubclass(tp, Enum):
        return tp(data)
    if tp in (int, float) and data is not None:
        return tp(data)
    return data


def check_result_path(path: str | Path) -> Path:
    """Refuse, before any work, a result file (a JSON result or a figure) that cannot be replaced because a folder
    (or anything but a file) stands at ``path``; every command checks each file it will write before its work.

    Raises:
        ResultUnwritable: one line naming ``path`` and the fix.
    """
    path = Path(path)
    if path.exists() and not path.is_file():
        raise ResultUnwritable(21, f"'{path}' is a folder, not a file, so it cannot be written; move or remove "
                                   f"that folder, then re-run the same command")
    return path


def write_json_atomic(path: str | Path, doc: Any) -> None:
    """Write the JSON value ``doc`` to ``path`` atomically: the text goes to ``path.tmp``, is flushed to disk and
    then renamed over ``path``, so a kill leaves the old file or the new one, never half of one. On any failure the
    ``.tmp`` file is removed and ``path`` is left as it was.

    Raises:
        ResultUnwritable: the file cannot be written (full disk, read-only, a folder in its place); one line
            naming the file and the fix.
        TypeError, ValueError: ``doc`` is not JSON-serialisable (a bug; nothing is written).
    """
    path = Path(path)
    text = json.dumps(doc, indent=2)
    tmp = path.with_name(path.name + ".tmp")
    try:
        check_result_path(path)
        with open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError) and not isinstance(exc, ResultUnwritable):
            raise ResultUnwritable(exc.errno, f"cannot write '{path}' ({_why(exc)}); {_fix(exc)}") from None
        raise


def _why(exc: OSError) -> str:
    return STORAGE_ERRNOS.get(exc.errno) or exc.strerror or str(exc)


def _fix(exc: OSError) -> str:
    if exc.errno in (28, 122, 27):
        return "free space on that disk, then re-run the same command"
    if exc.errno in (21, 20):
        return "move or remove what stands in its place, then re-run the same command"
    return "make its folder writable (or copy the run directory to a writable place), then re-run the same command"


def write_result(path: str | Path, result: Any) -> None:
    """Write a result's JSON form (:func:`to_json`) to ``path`` atomically (:func:`write_json_atomic`)."""
    write_json_atomic(path, to_json(result))


def read_json(path: str | Path, rewrite: str, required: tuple[str, ...] = ()) -> dict[str, Any]:
    """Read a JSON object written by :func:`write_json_atomic`.

    Args:
        rewrite: the command that writes the file again (named in the error), e.g. ``"`softsbi check RUN`"``.
        required: keys the object must have.

    Raises:
        ResultDamaged: the file cannot be read, is empty, cut short, not JSON, not an object or lacks a
            ``required`` key; one line naming the file and ``rewrite`` (for a folder in the file's place: after
            moving or removing it, since no command writes over a folder).
    """
    path = Path(path)
    if path.is_dir():
        raise ResultDamaged(path, "a folder, not a file", f"moving or removing that folder, then {rewrite},"
                            if rewrite else "moving or removing that folder, then re-running the command that wrote it,")
    try:
        text = path.read_text()
        if not text.strip():
            raise ValueError("it is empty")
        data = json.loads(text)
        if not isinstance(data, dict):
            raise ValueError(f"it holds a JSON {type(data).__name__}, not an object")
        missing = [k for k in required if k not in data]
        if missing:
            raise ValueError(f"it lacks {', '.join(repr(k) for k in missing)}")
    except json.JSONDecodeError as exc:
        raise ResultDamaged(path, f"not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})",
                            rewrite) from None
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise ResultDamaged(path, getattr(exc, "strerror", None) or str(exc), rewrite) from None
    return data


def read_result(path: Path, cls: type, name: str, what: str, rewrite: str) -> Any:
    """The typed result ``cls`` stored at ``path`` by :func:`write_result`; ``name`` and ``what`` name it in the
    errors ("no {name} at ...", "not {what}: ...", e.g. "diagnosis", "a diagnosis"), ``rewrite`` is the command that
    writes it again.

    Raises:
        SoftsbiError: no such file. ResultDamaged: as :func:`read_json` (a ``schema`` key required), or the object
            is not a ``cls``: one line naming the file and ``rewrite``.
    """
    if not path.exists():
        raise SoftsbiError(f"no {name} at '{path}'; {rewrite} writes it")
    data = read_json(path, rewrite, ("schema",))
    try:
        return from_json(cls, data)
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise ResultDamaged(path, f"not {what}: {e}", rewrite) from e


class ResultUnwritable(SoftsbiError, OSError):
    """A result file cannot be written (``errno`` kept); the message names the file and the fix."""

    def __str__(self) -> str:
        return self.strerror or super().__str__()


class ResultDamaged(SoftsbiError):
    """A stored JSON result cannot be read.

    Attributes:
        path: the file. problem: what is wrong with it (without the fix).
    """

    def __init__(self, path: Path, problem: str, rewrite: str):
        super().__init__(f"'{path}' is damaged ({problem}); {rewrite} writes it again")
        self.path, self.problem = Path(path), problem
