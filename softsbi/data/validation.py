"""One-line messages for pydantic validation errors (scenario and recording files)."""
from __future__ import annotations

from typing import Mapping

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
    got = err.get("input")
    got_s = "" if isinstance(got, (dict, list)) and len(repr(got)) > 60 else f" (got {got!r})"
    return f"{source}: field '{loc}': {msg}{got_s}; fix that field (the format: {example})"
