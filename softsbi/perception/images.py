"""(being written this session: see issue 6)."""
from __future__ import annotations

from ..plugins.hookspecs import hookimpl


@hookimpl
def softsbi_observers():
    return []
