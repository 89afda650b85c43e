"""Plugin manager: loads every module of the ``softsbi`` entry-point group.

Use :func:`registry` for name -> class look-ups::

    reg = registry()
    sim = reg.simulator("mujoco-flex")()
"""
from __future__ import annotations

import functools
import warnings
import importlib.metadata as md
from dataclasses import dataclass, field
from typing import Any

import pluggy

from ..core.errors import PluginNotFound
from . import hookspecs


#: entry points that failed to import: ``{entry point name: error text}``
LOAD_ERRORS: dict[str, str] = {}


def get_plugin_manager(autoload: bool = True) -> pluggy.PluginManager:
    """A fresh manager with the hook specs; ``autoload`` loads the ``softsbi`` entry points.

    A plugin module that fails to import is skipped with a warning (and listed in
    :data:`LOAD_ERRORS` and by ``softsbi plugins``) instead of breaking every command.
    """
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    if autoload:
        for ep in md.entry_points(group=hookspecs.PROJECT):
            if pm.get_plugin(ep.name) is not None or pm.is_blocked(ep.name):
                continue
            try:
                plugin = ep.load()
            except Exception as exc:  # noqa: BLE001 - any import failure of a plugin
                LOAD_ERRORS[ep.name] = f"{type(exc).__name__}: {exc}"
                warnings.warn(f"softsbi plugin '{ep.name}' ({ep.value}) failed to load and is skipped: {exc}",
                              stacklevel=2)
                continue
            pm.register(plugin, name=ep.name)
            dist = getattr(ep, "dist", None)
            _DIST[id(plugin)] = f"{dist.name} {dist.version}" if dist is not None else ep.value
    return pm


_DIST: dict[int, str] = {}


KINDS = {"simulator": "softsbi_simulators", "effect": "softsbi_effects", "observer": "softsbi_observers",
         "estimator": "softsbi_estimators", "executor": "softsbi_executors", "extractor": "softsbi_extractors"}


@dataclass
class Registry:
    """Name -> class tables built from a plugin manager.

    Attributes:
        tables: ``{kind: {name: class}}`` for kinds simulator, effect, observer, estimator, executor,
            extractor.
        origin: ``{(kind, name): "distribution version"}`` of the package that provided each.
    """

    pm: pluggy.PluginManager
    tables: dict[str, dict[str, type]] = field(default_factory=dict)
    origin: dict[tuple[str, str], str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        dists = _entry_point_dists(self.pm)
        for kind, hook in KINDS.items():
            table: dict[str, type] = {}
            for impl in getattr(self.pm.hook, hook).get_hookimpls():
                for cls in impl.function() or []:
                    table[cls.name] = cls
                    self.origin[(kind, cls.name)] = dists.get(impl.plugin, "softsbi (registered in code)")
            self.tables[kind] = table

    def get(self, kind: str, name: str) -> type:
        """Class registered under ``name``; raises :class:`PluginNotFound` with the closest name."""
        table = self.tables[kind]
        if name not in table:
            raise PluginNotFound(kind, name, table)
        return table[name]

    def simulator(self, name: str) -> type:
        return self.get("simulator", name)

    def effect(self, name: str) -> type:
        return self.get("effect", name)

    def observer(self, name: str) -> type:
        return self.get("observer", name)

    def estimator(self, name: str) -> type:
        return self.get("estimator", name)

    def executor(self, name: str) -> type:
        return self.get("executor", name)

    def extractor(self, name: str) -> type:
        return self.get("extractor", name)

    def names(self, kind: str) -> list[str]:
        return sorted(self.tables[kind])

    def describe(self) -> dict[str, list[dict[str, Any]]]:
        """JSON-able listing used by ``softsbi plugins --json``."""
        out: dict[str, list[dict[str, Any]]] = {}
        for kind, table in self.tables.items():
            rows = []
            for name, cls in sorted(table.items()):
                row = {"name": name, "class": f"{cls.__module__}.{cls.__qualname__}",
                       "package": self.origin.get((kind, name), ""),
                       "doc": (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""}
                for attr in ("scenarios", "effects", "backends", "description"):
                    if hasattr(cls, attr) and not callable(getattr(cls, attr)):
                        v = getattr(cls, attr)
                        row[attr] = list(v) if isinstance(v, tuple) else v
                rows.append(row)
            out[kind + "s"] = rows
        return out


def _entry_point_dists(pm: pluggy.PluginManager) -> dict[Any, str]:
    return {plugin: _DIST[id(plugin)] for plugin in pm.get_plugins() if id(plugin) in _DIST}


@functools.lru_cache(maxsize=1)
def registry() -> Registry:
    """The process-wide registry of entry-point plugins (cached)."""
    return Registry(get_plugin_manager(autoload=True))
