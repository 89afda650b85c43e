"""One-line messages for pydantic validation errors (scenario and recording files)."""
from __future__ import annotations

import reprlib
from typing import Any, Mapping

from pydantic import ValidationError


def _loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in ("box", "cylinder") or str(part).startswith("function-"):
            continue
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def validation_line(source: str, exc: ValidationError, example: str, missing_hints: Mapping[str, str] | None = None) -> str:
    """The first problem of a pydantic ``ValidationError`` as one line: ``source`` (the file), the field
    and the fix; ``example`` names where the format is shown (e.g. a shipped file); ``missing_hints``
    ``{field: what to write}`` makes the fix for a missing field concrete."""
    err = exc.errors()[0]
    loc = _loc(tuple(err.get("loc", ())))
    kind = err.get("type", "")
    if kind == "extra_forbidden":
        return f"{source}: unknown field '{loc}'; remove it or correct its spelling (the format: {example})"
    if kind == "missing":
        hint = (missing_hints or {}).get(loc)
        return f"{source}: field '{loc}' is missing; add it{', ' + hint if hint else ''} (the format: {example})"
    msg = err.get("msg", "invalid").replace("Value error, ", "")
    got_s = short_repr(err.get("input"))
    got_s = f" (got {got_s})" if len(got_s) <= 60 else ""
    return f"{source}: field '{loc}': {msg}{got_s}; fix that field (the format: {example})"


#: a repr of bounded work and length, whatever the input (a huge or self-repeating YAML value)
_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxstring, _REPR.maxother, _REPR.maxlong = 3, 50, 50, 40
_REPR.maxlist = _REPR.maxtuple = _REPR.maxdict = _REPR.maxset = 6


def short_repr(value: Any) -> str:
    """``repr(value)`` cut short (a few items per level, a few levels, 50 characters per string): bounded work
    and length for messages about any input."""
    return _REPR.repr(value)
