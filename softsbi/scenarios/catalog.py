"""Where scenarios come from: the files shipped in ``softsbi/scenarios/files/``, the
``softsbi_scenarios`` plugin hook, or any scenario file path (:func:`load_scenario`).

A plugin admits code-defined scenarios with the hook (:mod:`softsbi.plugins.hookspecs`)::

    @hookimpl
    def softsbi_scenarios():
        return {"my-task": build_my_task}      # name -> Scenario, zero-argument callable or file path
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, Callable, Mapping

import yaml

from softsbi.core.errors import DataError, PluginError, closest
from softsbi.core.types import Scenario
from softsbi.plugins import registry
from softsbi.scenarios.spec import load_scenario_file

#: folder of the built-in scenario files (package data)
FILES = Path(__file__).with_name("files")
#: old name -> current name of a renamed built-in scenario (the rope ``wind`` shared its name with the effect)
RENAMED = {"wind": "winding"}


def current_name(name: str) -> str:
    """The current name of a built-in scenario given by an old name (:data:`RENAMED`, with a ``FutureWarning``),
    else ``name``. Runs stored before a rename keep the old name in their scenario; it means the same scenario."""
    if name in RENAMED:
        warnings.warn(f"scenario '{name}' is now called '{RENAMED[name]}'; the old name works for now",
                      FutureWarning, stacklevel=3)
        return RENAMED[name]
    return name


def builtin_files() -> dict[str, Path]:
    """``{name: path}`` of the scenario files shipped with softsbi (``lift``, ``wipe``, ``winding``, ``fling``)."""
    return {p.stem: p for p in sorted(FILES.glob("*.yaml"))}


def plugin_scenarios() -> dict[str, tuple[Any, str]]:
    """``{name: (entry, plugin)}`` from every ``softsbi_scenarios`` hook implementation.

    Raises:
        PluginError: a hook returns something that is not a mapping of names to scenarios, callables or
            paths, or two plugins give the same name.
    """
    reg = registry()
    out: dict[str, tuple[Any, str]] = {}
    for impl in reg.pm.hook.softsbi_scenarios.get_hookimpls():
        who = reg.pm.get_name(impl.plugin)
        got = impl.function()
        if not isinstance(got, Mapping):
            raise PluginError(f"softsbi plugin '{who}': hook softsbi_scenarios returned {type(got).__name__}; it "
                              f"must return a dict {{name: Scenario | zero-argument callable | scenario file path}}")
        for name, entry in got.items():
            if not isinstance(name, str) or not name:
                raise PluginError(f"softsbi plugin '{who}': hook softsbi_scenarios gave the name {name!r}; names "
                                  f"are non-empty strings")
            if not (isinstance(entry, (Scenario, str, Path)) or callable(entry)):
                raise PluginError(f"softsbi plugin '{who}': scenario '{name}' is {type(entry).__name__}; give a "
                                  f"Scenario, a zero-argument callable returning one, or a scenario file path")
            if name in out or name in builtin_files():
                raise PluginError(f"softsbi plugin '{who}': scenario '{name}' is already defined "
                                  f"({'built in' if name in builtin_files() else 'by ' + out[name][1]}); rename it")
            out[name] = (entry, who)
    return out


def list_scenarios() -> list[dict[str, Any]]:
    """Every known scenario: ``[{"name", "source" ("built-in" or the plugin), "file", "description"}]``."""
    rows = []
    for name, p in builtin_files().items():
        desc = (yaml.safe_load(p.read_text()) or {}).get("description", "")
        rows.append({"name": name, "source": "built-in", "file": str(p), "description": desc})
    for name, (entry, who) in sorted(plugin_scenarios().items()):
        rows.append({"name": name, "source": f"plugin {who}",
                     "file": str(entry) if isinstance(entry, (str, Path)) else "",
                     "description": (getattr(entry, "__doc__", "") or "").strip().splitlines()[0]
                     if callable(entry) and getattr(entry, "__doc__", None) else ""})
    return rows


def load_scenario(name_or_path: str | Path | Scenario, transforms: Mapping[str, Any] | None = None) -> Scenario:
    """A scenario by built-in name, plugin name or scenario file path.

    Args:
        name_or_path: ``"lift"`` / ``"wipe"`` / ``"winding"`` / ``"fling"`` (or an old name, :data:`RENAMED`),
            a name a plugin gives, or a ``.yaml`` path (a :class:`Scenario` is returned unchanged).
        transforms: named frames -> scenario frame replacing a file's (a recording's calibration).

    Raises:
        DataError: unknown name (lists the known ones), or an invalid file (file, field and fix).
    """
    if isinstance(name_or_path, Scenario):
        return name_or_path
    files = builtin_files()
    s = str(name_or_path)
    if s in RENAMED and s not in files:
        s = current_name(s)
    if s in files:
        return load_scenario_file(files[s], transforms)
    p = Path(s).expanduser()
    if p.suffix in (".yaml", ".yml") or p.exists() or "/" in s:
        return load_scenario_file(p, transforms)
    plugins = plugin_scenarios()
    if s in plugins:
        entry = plugins[s][0]
        if isinstance(entry, Scenario):
            return entry
        if isinstance(entry, (str, Path)):
            return load_scenario_file(entry, transforms)
        sc = entry()
        if not isinstance(sc, Scenario):
            raise DataError(f"scenario '{s}' of plugin {plugins[s][1]} built {type(sc).__name__}, not a Scenario")
        return sc
    names = sorted(files) + sorted(plugins)
    raise DataError(f"unknown scenario '{s}'.{closest(s, names)} Valid scenarios: {', '.join(names)}; or give a "
                    f"scenario file path (.yaml)")


Builder = Callable[[], Scenario]
