"""Plugin manager: loads every module of the ``softsbi`` entry-point group.

Use :func:`registry` for name -> class look-ups::

    reg = registry()
    sim = reg.simulator("mujoco-flex")()

The registry is strict: a malformed plugin (a hook returning something that is not a class
derived from its kind's ABC, two plugins of one kind with the same name, a misspelled hook)
raises :class:`~softsbi.core.errors.PluginError` when the registry is built, so every command
fails with that one line instead of silently picking one plugin. A plugin module that fails
to *import* is only skipped with a warning (see :data:`LOAD_ERRORS`), and an effect whose code fails when its
parameters are declared (``param_space()`` raises: a bug, a duplicate parameter name, inverted bounds) is set aside
as broken (:attr:`Registry.broken`): looking it up is a PluginError naming the plugin and its file, while every
other plugin keeps working and ``softsbi plugins`` lists it marked.

A class may keep an old name working for a while with ``aliases = ("old-name",)``: looking
it up by an alias returns the class with a :class:`FutureWarning`.

Without a package: the environment variable ``SOFTSBI_PLUGINS`` names plugin modules to load as well,
separated by ``os.pathsep`` (``:``), each an importable module name or the path of a ``.py`` file
(``SOFTSBI_PLUGINS=./my_effects.py softsbi fit ... --effect my-hem``). They register exactly like
entry points; simulation workers inherit the variable and load the same files. A listed module that
cannot be loaded is an error (it was asked for by name), not a warning.
"""
from __future__ import annotations

import functools
import importlib
import importlib.metadata as md
import importlib.util
import inspect
import os
import sys
import traceback
from pathlib import Path
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import pluggy

from softsbi.core.errors import ParameterError, PluginError, PluginNotFound, SoftsbiError, SoftsbiWarning, closest
from softsbi.core.interfaces import Effect, Executor, KeypointExtractor, Observer, PosteriorEstimator, Simulator
from softsbi.core.types import ParamSpace
from softsbi.plugins import hookspecs


#: entry points that failed to import: ``{entry point name: error text}``
LOAD_ERRORS: dict[str, str] = {}


def get_plugin_manager(autoload: bool = True) -> pluggy.PluginManager:
    """A fresh manager with the hook specs; ``autoload`` loads the ``softsbi`` entry points.

    A plugin module that fails to import is skipped with a warning (and listed in
    :data:`LOAD_ERRORS` and by ``softsbi plugins``) instead of breaking every command.

    Raises:
        PluginError: a loaded plugin has a hook implementation whose arguments do not match
            the hook specification (pluggy's ``PluginValidationError``).
    """
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    if autoload:
        for ep in md.entry_points(group=hookspecs.PROJECT):
            if pm.get_plugin(ep.name) is not None or pm.is_blocked(ep.name):
                continue
            try:
                plugin = ep.load()
            except PluginError:
                raise
            except Exception as exc:  # noqa: BLE001 - any import failure of a plugin
                LOAD_ERRORS[ep.name] = f"{type(exc).__name__}: {exc}{_where(exc)}"
                dist = getattr(ep, "dist", None)
                by = f"the package {dist.name}" if dist is not None else "its package"
                warnings.warn(SoftsbiWarning(
                    f"softsbi plugin '{ep.name}' ({ep.value}) failed to load and is skipped: {LOAD_ERRORS[ep.name]}; "
                    f"{_import_fix(exc, f'reinstall or fix {by}', 'uninstall it')}"), stacklevel=2)
                continue
            if pm.is_registered(plugin):  # two entry points naming the same module: load it once
                continue
            dist = getattr(ep, "dist", None)
            _DIST[id(plugin)] = f"{dist.name} {dist.version}" if dist is not None else ep.value
            try:
                pm.register(plugin, name=ep.name)
            except pluggy.PluginValidationError as exc:
                raise PluginError(f"softsbi plugin '{ep.name}' ({ep.value}, {_DIST[id(plugin)]}) is malformed: "
                                  f"{_one_line(exc)}; {_HOOK_FIX}") from None
        _load_env_plugins(pm)
    return pm


#: environment variable naming plugin modules or ``.py`` files to load besides the entry points
PLUGINS_ENV = "SOFTSBI_PLUGINS"


#: the fix of a hook implementation pluggy refuses
_HOOK_FIX = "declare each hook without arguments, as softsbi.plugins.hookspecs does"


def _one_line(exc: BaseException) -> str:
    """``str(exc)`` on one line (pluggy's messages span several)."""
    return " ".join(str(exc).split())


def _where(exc: BaseException, files: Sequence[str] = ()) -> str:
    """``" (line N of FILE)"``: where a plugin's code raised ``exc``: the innermost frame in one of ``files`` (a
    plugin module's), else outside softsbi and Python's import machinery; the line of a SyntaxError; ``""`` when
    unknown."""
    if isinstance(exc, SyntaxError) and exc.filename:
        return f" (line {exc.lineno} of {exc.filename})"
    frames = traceback.extract_tb(exc.__traceback__)
    ours = str(Path(__file__).resolve().parents[1])
    mine = [f for f in frames if f.filename in files] or \
        [f for f in frames if not f.filename.startswith(ours) and not f.filename.startswith("<frozen")]
    return f" (line {mine[-1].lineno} of {mine[-1].filename})" if mine else ""


def _import_fix(exc: BaseException, repair: str, drop: str) -> str:
    """What fixes a plugin whose import raised ``exc``: the missing package it imports installed, else ``repair``;
    or ``drop`` it."""
    if isinstance(exc, ModuleNotFoundError) and exc.name:
        return f"install the package that provides '{exc.name}' (the plugin imports it), or {drop}"
    return f"{repair}, or {drop}"


class _NotFound(Exception):
    """A :data:`PLUGINS_ENV` entry that names no file or module (not a fault of a plugin's code)."""


def _import_plugin(item: str) -> Any:
    """The module named by one entry of :data:`PLUGINS_ENV`: a ``.py`` file (path) or an importable module.

    Raises:
        _NotFound: no such file or module. Anything the module's code raises when it runs."""
    if item.endswith(".py") or os.sep in item:
        path = Path(item).expanduser().resolve()
        if not path.is_file():
            raise _NotFound(f"FileNotFoundError: no such file {str(path)!r}")
        name = f"softsbi_file_plugin_{path.stem}"
        module = sys.modules.get(name)
        if module is not None and getattr(module, "__file__", None) == str(path):
            return module
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            del sys.modules[name]
            raise
        return module
    try:
        return importlib.import_module(item)
    except ModuleNotFoundError as exc:
        if exc.name and (item == exc.name or item.startswith(exc.name + ".")):  # the entry itself, not an import in it
            raise _NotFound(f"ModuleNotFoundError: {exc}") from None
        raise


def _load_env_plugins(pm: pluggy.PluginManager) -> None:
    """Register the modules of :data:`PLUGINS_ENV` (see the module docstring).

    Raises:
        PluginError: an entry cannot be loaded (missing file, import error) or its hooks are malformed.
    """
    for item in (s.strip() for s in os.environ.get(PLUGINS_ENV, "").split(os.pathsep)):
        if not item:
            continue
        try:
            plugin = _import_plugin(item)
        except _NotFound as exc:
            raise PluginError(f"{PLUGINS_ENV}: cannot load '{item}' ({exc}); give an importable module name or the "
                              f"path of a .py file, separated by '{os.pathsep}'") from None
        except Exception as exc:  # noqa: BLE001 - any failure of the code of a plugin the user named
            file = str(Path(item).expanduser().resolve()) if item.endswith(".py") or os.sep in item else ""
            text = exc.msg if isinstance(exc, SyntaxError) else _one_line(exc)  # its line follows
            raise PluginError(f"{PLUGINS_ENV}: plugin '{item}' failed while loading: {type(exc).__name__}: "
                              f"{text}{_where(exc, [file])}; "
                              f"{_import_fix(exc, 'fix its code', f'remove it from {PLUGINS_ENV}')}") from None
        if pm.is_registered(plugin):
            continue
        _DIST[id(plugin)] = f"{PLUGINS_ENV} ({item})"
        try:
            pm.register(plugin, name=f"{PLUGINS_ENV}:{item}")
        except pluggy.PluginValidationError as exc:
            raise PluginError(f"softsbi plugin '{item}' ({PLUGINS_ENV}) is malformed: {_one_line(exc)}; "
                              f"{_HOOK_FIX}") from None


#: ``{id(plugin object): "distribution version"}`` of the entry points loaded by :func:`get_plugin_manager`
_DIST: dict[int, str] = {}


#: kind -> name of the hook that lists the plugin classes of that kind
KINDS = {"simulator": "softsbi_simulators", "effect": "softsbi_effects", "observer": "softsbi_observers",
         "estimator": "softsbi_estimators", "executor": "softsbi_executors", "extractor": "softsbi_extractors"}

#: every hook name (the kinds' hooks plus softsbi_scenarios, whose entries are scenarios, not classes)
HOOKS = (*KINDS.values(), "softsbi_scenarios")
#: kind -> the ABC (softsbi.core.interfaces) every class of that kind derives from
BASES: dict[str, type] = {"simulator": Simulator, "effect": Effect, "observer": Observer,
                          "estimator": PosteriorEstimator, "executor": Executor, "extractor": KeypointExtractor}


@dataclass
class Registry:
    """Name -> class tables built from a plugin manager.

    Attributes:
        pm: the plugin manager the tables are built from.
        tables: ``{kind: {name: class}}`` for kinds simulator, effect, observer, estimator, executor,
            extractor (real names only, no aliases).
        origin: ``{(kind, name): "distribution version"}`` of the package that provided each.
        dists: ``{registered plugin name: "distribution version"}``: who provides a plugin that was
            not loaded through an entry point (plugins registered in code, tests); entry points loaded
            by :func:`get_plugin_manager` are known without it.
        aliases: ``{kind: {old name: name}}`` from the classes' ``aliases`` attributes.
        broken: ``{(kind, name): message}`` of the effects whose ``__init__()`` or ``param_space()`` raised or
            did not return a ParamSpace when the registry was built: left out of ``tables``; looking one up raises
            PluginError with its message (one line naming the plugin, the class, its file and the fault).

    Raises (on construction):
        PluginError: a plugin has a hook implementation with an unknown (misspelled) hook name; a hook
            returns something that is not a class derived from the kind's ABC or has no non-empty
            string ``name``, or has malformed ``aliases``; two different classes of one kind share a
            name or an alias.
    """

    pm: pluggy.PluginManager
    tables: dict[str, dict[str, type]] = field(default_factory=dict)
    origin: dict[tuple[str, str], str] = field(default_factory=dict)
    dists: Mapping[str, str] = field(default_factory=dict)
    aliases: dict[str, dict[str, str]] = field(default_factory=dict)
    broken: dict[tuple[str, str], str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        #: (kind, name) -> (the plugin object that provides the class, the class): for the messages naming them
        self._provider: dict[tuple[str, str], tuple[Any, type]] = {}
        self._check_hook_names()
        for kind, hook in KINDS.items():
            table: dict[str, type] = {}
            aliases: dict[str, str] = {}
            #: every name and alias taken so far -> (class, provider text, is alias)
            taken: dict[str, tuple[type, str, bool]] = {}
            for impl in getattr(self.pm.hook, hook).get_hookimpls():
                dist = self._dist(impl.plugin)
                for cls in self._classes(kind, hook, impl):
                    if table.get(cls.name) is cls:  # the same class twice (one plugin, or two hooks): fine
                        continue
                    provider = f"{dist} ({cls.__module__}.{cls.__qualname__}"
                    labels = [(cls.name, False)] + [(a, True) for a in _aliases_of(cls, self._who(impl.plugin), hook)]
                    for label, is_alias in labels:
                        if label in taken and taken[label][0] is not cls:
                            other_cls, other, other_alias = taken[label]
                            raise PluginError(
                                f"two {kind} plugins are named '{label}': "
                                f"{other}{_as_alias(other_cls, other_alias)}) and "
                                f"{provider}{_as_alias(cls, is_alias)}); uninstall one or rename it")
                        taken[label] = (cls, provider, is_alias)
                        if is_alias:
                            aliases[label] = cls.name
                    table[cls.name] = cls
                    self.origin[(kind, cls.name)] = dist
                    self._provider[(kind, cls.name)] = (impl.plugin, cls)
            self.tables[kind] = table
            self.aliases[kind] = aliases
        self._set_aside_broken_effects()

    def _set_aside_broken_effects(self) -> None:
        """Build each effect's parameter space once; move the effects whose code fails to :attr:`broken`."""
        for name, cls in list(self.tables["effect"].items()):
            try:
                eff = cls()
            except Exception as exc:  # noqa: BLE001 - any fault of a plugin's code (an abstract method left out)
                self.broken[("effect", name)] = self.fault("effect", name, f"making it ({cls.__qualname__}()) raised "
                                                                           f"{type(exc).__name__}: {exc}{_where(exc)}")
                continue
            try:
                space = eff.param_space()
            except Exception as exc:  # noqa: BLE001 - any fault of a plugin's code
                self.broken[("effect", name)] = self.fault("effect", name, f"its param_space() raised "
                                                                           f"{type(exc).__name__}: {exc}")
                continue
            if not isinstance(space, ParamSpace):
                self.broken[("effect", name)] = self.fault(
                    "effect", name, f"its param_space() returned {type(space).__name__}, not a "
                                    f"softsbi.core.types.ParamSpace")
        for kind, name in self.broken:
            del self.tables[kind][name]

    def fault(self, kind: str, name: str, what: str) -> str:
        """One line blaming the ``kind`` plugin class registered as ``name`` for ``what`` (its fault): the plugin
        that provides it, the class and the file it is defined in, and the fix."""
        if (kind, name) not in self._provider:  # not registered here (an instance made in code)
            return f"{kind} '{name}' is broken: {what}; fix the plugin's code"
        plugin, cls = self._provider[(kind, name)]
        path = getattr(sys.modules.get(cls.__module__), "__file__", None)
        where = f"class {cls.__module__}.{cls.__qualname__}" + (f" in {path}" if path else "")
        return (f"{kind} '{name}' ({where}, from {self._dist(plugin)}) is broken: {what}; fix the plugin's code or "
                f"{self._drop(plugin)}")

    def _drop(self, plugin: Any) -> str:
        """How to do without ``plugin``: take it out of :data:`PLUGINS_ENV`, or uninstall its package."""
        return f"remove it from {PLUGINS_ENV}" if self.pm.get_name(plugin).startswith(f"{PLUGINS_ENV}:") else \
            "uninstall it"

    def param_space(self, sim: Simulator, scenario: Any, effects: Sequence[str] = ()) -> ParamSpace:
        """The parameters of a rollout of ``scenario``: ``sim.param_space(scenario)`` then each effect's, in order.

        Args:
            sim: an instance of a registered simulator; scenario: a :class:`~softsbi.core.types.Scenario`;
            effects: effect names.

        Raises:
            PluginNotFound: an unknown effect. PluginError: a :attr:`broken` effect; the simulator's
                ``param_space`` raised (other than a SoftsbiError, which passes: a deliberate refusal); an effect
                declares a parameter name the simulator or an earlier effect has (each names the plugin, its
                class and file).
        """
        try:
            space = sim.param_space(scenario)
        except SoftsbiError:
            raise
        except Exception as exc:  # noqa: BLE001 - any fault of a plugin's code
            raise PluginError(self.fault("simulator", sim.name, f"its param_space(scenario '{scenario.name}') "
                                                                f"raised {type(exc).__name__}: {exc}")) from None
        owner = dict.fromkeys(space.names, f"simulator '{sim.name}'")
        for e in effects:
            own = self.effect(e)().param_space()
            clash = [n for n in own.names if n in owner]
            if clash:
                raise PluginError(self.fault("effect", self.effect(e).name,
                                             f"its parameter '{clash[0]}' is also one of {owner[clash[0]]}'s; "
                                             f"rename it"))
            owner.update(dict.fromkeys(own.names, f"effect '{e}'"))
            space = space + own
        return space

    def create(self, kind: str, name: str, options: Mapping[str, Any], what: str) -> Any:
        """An instance of the ``kind`` plugin ``name`` made with ``options``; ``what`` names it and its option flag in
        the messages (``"simulator 'mujoco-flex' (--backend-opt)"``).

        Raises:
            PluginNotFound, PluginError: as :meth:`get`. SoftsbiError: the plugin's own refusal, as it is.
            ParameterError: its constructor refused the options given (ValueError, TypeError). PluginError: its
                constructor failed otherwise, or without options (names the plugin, its class and file).
        """
        cls = self._lookup(kind, name, stacklevel=3)
        try:
            return cls(**dict(options))
        except SoftsbiError:
            raise
        except (ValueError, TypeError) as exc:
            if options:
                raise ParameterError(f"{what} refused the options {dict(options)}: {exc}; change them") from None
            raise PluginError(self.fault(kind, name, f"making it raised {type(exc).__name__}: {exc}{_where(exc)}")) \
                from None
        except Exception as exc:  # noqa: BLE001 - any fault of a plugin's code
            raise PluginError(self.fault(kind, name, f"making it raised {type(exc).__name__}: {exc}{_where(exc)}")) \
                from None

    # -- construction helpers -------------------------------------------------------------------
    def _dist(self, plugin: Any) -> str:
        name = self.pm.get_name(plugin)
        if name in self.dists:
            return self.dists[name]
        return _DIST.get(id(plugin), "softsbi (registered in code)")

    def _who(self, plugin: Any) -> str:
        """``softsbi plugin 'effects' (softsbi.effects.builtin, softsbi 0.1.0)``."""
        module = getattr(plugin, "__name__", None) or f"{type(plugin).__module__}.{type(plugin).__qualname__}"
        name = self.pm.get_name(plugin)
        if name.startswith(f"{PLUGINS_ENV}:"):  # one of SOFTSBI_PLUGINS: the entry, and the file it was read from
            item, file = name[len(PLUGINS_ENV) + 1:], getattr(plugin, "__file__", None)
            same = file is None or Path(item).expanduser().resolve() == Path(file).resolve()
            return f"softsbi plugin '{item}' ({PLUGINS_ENV}" + (")" if same else f", {file})")
        return f"softsbi plugin '{name}' ({module}, {self._dist(plugin)})"

    def _check_hook_names(self) -> None:
        """Hook implementations without a spec are misspelled hooks: one PluginError naming them all."""
        unknown: list[str] = []
        for name in list(vars(self.pm.hook)):
            if name.startswith("_"):
                continue
            caller = getattr(self.pm.hook, name)
            if caller.has_spec():
                continue
            for impl in caller.get_hookimpls():
                if not impl.optionalhook:
                    unknown.append(f"{self._who(impl.plugin)} has an unknown hook '{name}'."
                                   f"{closest(name, HOOKS)}")
        if unknown:
            raise PluginError(" ".join(unknown) + f" The hooks are: {', '.join(HOOKS)}.")
        try:  # whatever else pluggy finds unverified
            self.pm.check_pending()
        except pluggy.PluginValidationError as exc:
            raise PluginError(f"{self._who(exc.plugin)}: {_one_line(exc)}; {_HOOK_FIX}") from None

    def _classes(self, kind: str, hook: str, impl: Any) -> list[type]:
        """The classes one hook implementation returns, checked against the kind's ABC."""
        base = BASES[kind]
        expected = f"{base.__module__}.{base.__qualname__}"
        where = f"{self._who(impl.plugin)}: hook {hook}"
        try:
            result = impl.function()
            if result is None:
                return []
            if isinstance(result, (str, bytes, Mapping, type)) or not hasattr(result, "__iter__"):
                raise PluginError(f"{where} returned {result!r}; it must return a list of classes derived from "
                                  f"{expected}")
            result = list(result)
        except PluginError:
            raise
        except Exception as exc:  # noqa: BLE001 - any fault of a plugin's code
            raise PluginError(f"{where} raised {type(exc).__name__}: {exc}{_where(exc)}; fix the plugin's code or "
                              f"{self._drop(impl.plugin)}") from None
        out = []
        for obj in result:
            if not isinstance(obj, type):
                hint = " (an instance: return the class itself)" if isinstance(obj, base) else ""
                raise PluginError(f"{where} returned {obj!r}{hint}, which is not a class; {_a(kind)} {kind} plugin "
                                  f"is a class derived from {expected}")
            if not issubclass(obj, base):
                raise PluginError(f"{where} returned class {obj.__module__}.{obj.__qualname__}, which does not "
                                  f"derive from {expected}")
            name = getattr(obj, "name", None)
            if not isinstance(name, str) or not name:
                raise PluginError(f"{where} returned class {obj.__module__}.{obj.__qualname__} without a name; "
                                  f"give it a non-empty string class attribute `name` ({expected} requires one)")
            out.append(obj)
        return out

    # -- look-ups -------------------------------------------------------------------------------
    def get(self, kind: str, name: str) -> type:
        """Class registered under ``name`` (or under one of its ``aliases``, with a FutureWarning).

        Raises:
            PluginNotFound: no class of that kind has that name or alias; the message names the
                closest name.
            PluginError: the class is :attr:`broken` (the message names the plugin, its file and the fault).
        """
        return self._lookup(kind, name, stacklevel=3)

    def _lookup(self, kind: str, name: str, stacklevel: int) -> type:
        table = self.tables[kind]
        if name in table:
            return table[name]
        new = self.aliases.get(kind, {}).get(name)
        if (kind, new or name) in self.broken:
            raise PluginError(self.broken[(kind, new or name)])
        if new is not None:
            warnings.warn(f"plugin name '{name}' is deprecated; use '{new}'", FutureWarning, stacklevel=stacklevel)
            return table[new]
        raise PluginNotFound(kind, name, table)

    def simulator(self, name: str) -> type:
        """:meth:`get` of kind ``simulator``."""
        return self._lookup("simulator", name, stacklevel=3)

    def effect(self, name: str) -> type:
        """:meth:`get` of kind ``effect``."""
        return self._lookup("effect", name, stacklevel=3)

    def observer(self, name: str) -> type:
        """:meth:`get` of kind ``observer``."""
        return self._lookup("observer", name, stacklevel=3)

    def estimator(self, name: str) -> type:
        """:meth:`get` of kind ``estimator``."""
        return self._lookup("estimator", name, stacklevel=3)

    def executor(self, name: str) -> type:
        """:meth:`get` of kind ``executor``."""
        return self._lookup("executor", name, stacklevel=3)

    def extractor(self, name: str) -> type:
        """:meth:`get` of kind ``extractor``."""
        return self._lookup("extractor", name, stacklevel=3)

    def names(self, kind: str) -> list[str]:
        """Sorted names of one kind (aliases not included)."""
        return sorted(self.tables[kind])

    def describe(self) -> dict[str, list[dict[str, Any]]]:
        """JSON-able listing used by ``softsbi plugins --json`` (``aliases`` for classes that have them; for
        simulators the effects they support and their ``effect_kinds``; for effects ``kind``, ``generic``, the
        ``doors`` they act through (``model_edits``: the backends with a model edit), the installed ``backends``
        that can apply them (:meth:`Simulator.supports`) and their ``parameters``
        (:meth:`~softsbi.core.types.Param.summary`)). A :attr:`broken` class has ``name``, ``class``, ``package``
        and ``broken`` (the message) only, as has one whose description raises."""
        out: dict[str, list[dict[str, Any]]] = {}
        for kind, table in self.tables.items():
            old_names: dict[str, list[str]] = {}
            for alias, name in self.aliases.get(kind, {}).items():
                old_names.setdefault(name, []).append(alias)
            rows = []
            for name, cls in sorted(table.items()):
                row = {"name": name, "class": f"{cls.__module__}.{cls.__qualname__}",
                       "package": self.origin.get((kind, name), ""),
                       "doc": (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""}
                for attr in ("scenarios", "effects", "effect_kinds", "backends", "kind", "generic", "description"):
                    if hasattr(cls, attr) and not callable(getattr(cls, attr)):
                        v = getattr(cls, attr)
                        row[attr] = list(v) if isinstance(v, tuple) else v
                if name in old_names:
                    row["aliases"] = sorted(old_names[name])
                if kind == "effect":
                    try:
                        row.update(self._effect_row(cls))
                    except Exception as exc:  # noqa: BLE001 - any fault of a plugin's code
                        row = {"name": name, "class": row["class"], "package": row["package"],
                               "broken": self.fault(kind, name, f"describing it raised {type(exc).__name__}: {exc}")}
                rows.append(row)
            for (k, name), msg in sorted(self.broken.items()):
                if k == kind:
                    cls = self._provider[(k, name)][1]
                    rows.append({"name": name, "class": f"{cls.__module__}.{cls.__qualname__}",
                                 "package": self.origin.get((k, name), ""), "broken": msg})
            out[kind + "s"] = sorted(rows, key=lambda r: r["name"])
        return out

    def _effect_row(self, cls: type) -> dict[str, Any]:
        """An effect's doors, model-edit backends, the installed backends that apply it and its parameters."""
        eff = cls()
        doors: list[str] = []
        for b in [*self.tables["simulator"], *eff.model_edits]:
            doors += [d for d in eff.doors(b) if d not in doors]
        return {"doors": doors, "model_edits": list(eff.model_edits),
                "backends": [s for s, sim in sorted(self.tables["simulator"].items()) if sim.supports(eff) is None],
                "parameters": [p.summary() for p in eff.param_space()]}


def _aliases_of(cls: type, who: str, hook: str) -> list[str]:
    """The class's ``aliases`` (its own name dropped); PluginError if not a tuple of non-empty strings."""
    raw = getattr(cls, "aliases", ())
    if raw is None:
        return []
    if isinstance(raw, (str, bytes)) or not isinstance(raw, (tuple, list, frozenset, set)) or \
            not all(isinstance(a, str) and a for a in raw):
        raise PluginError(f"{who}: hook {hook} returned class {cls.__module__}.{cls.__qualname__} whose `aliases` "
                          f"is {raw!r}; it must be a tuple of non-empty strings, e.g. aliases = ('old-name',)")
    out: list[str] = []
    for a in raw:
        if a != cls.name and a not in out:
            out.append(a)
    return out


def _a(word: str) -> str:
    """The indefinite article of ``word``."""
    return "an" if word[:1] in "aeiou" else "a"


def _as_alias(cls: type, is_alias: bool) -> str:
    return f", an alias of '{cls.name}'" if is_alias else ""


@functools.lru_cache(maxsize=1)
def registry() -> Registry:
    """The process-wide registry of entry-point plugins (cached once it builds).

    Raises:
        PluginError: an installed plugin is malformed (see :class:`Registry`); nothing is cached, so
            each call reports it again.
    """
    return Registry(get_plugin_manager(autoload=True))


def option_defaults(cls: type) -> tuple[dict[str, Any], bool]:
    """``({option: default}, open)`` of a plugin class: a config-style class's ``defaults()`` or ``DEFAULTS``
    (estimators, extractors), else the keyword parameters of its ``__init__`` (simulators, executors; a
    parameter without a default maps to ``None``). ``open`` is True when ``__init__`` also takes ``**kwargs``,
    so that names outside the defaults may still be valid."""
    if callable(getattr(cls, "defaults", None)):
        return dict(cls.defaults()), False
    if isinstance(getattr(cls, "DEFAULTS", None), Mapping):
        return dict(cls.DEFAULTS), False
    out: dict[str, Any] = {}
    is_open = False
    for i, (name, par) in enumerate(inspect.signature(cls.__init__).parameters.items()):
        if i == 0 or par.kind is par.VAR_POSITIONAL:
            continue
        if par.kind is par.VAR_KEYWORD:
            is_open = True
            continue
        out[name] = None if par.default is par.empty else par.default
    return out, is_open


def check_options(cls: type, options: Mapping[str, Any], what: str) -> None:
    """Check a plugin's options before anything runs: known names, and a number or a flag where the default is one.

    Catches what a command line gets wrong (``--estimator-opt max_epochs=abc``, ``--backend-opt gridd=3``) before the
    first simulation instead of as a traceback from deep inside the plugin, after a round of simulations. Values of
    other types are left to the plugin, which may accept several (a list or a number, say).

    Args:
        cls: the plugin class (a :class:`Registry` look-up).
        options: the options the user gave.
        what: how the error names the plugin and its option flag, e.g. ``"estimator 'rkhs' (--estimator-opt)"``.

    Raises:
        ParameterError: an unknown option (with the closest name and the list), or text where a number or
            true/false is expected.
    """
    defaults, is_open = option_defaults(cls)
    check_option_values(defaults, options, what, is_open)


def check_option_values(defaults: Mapping[str, Any], options: Mapping[str, Any], what: str,
                        is_open: bool = False) -> None:
    """:func:`check_options` against a ``{option: default}`` table (``is_open``: names outside it are allowed).
    The text ``none``/``null`` passes where a number is expected: plugins read it as switched off."""
    for k, v in options.items():
        if k not in defaults:
            if is_open:
                continue
            raise ParameterError(f"unknown option '{k}' for {what}.{closest(k, defaults)} "
                                 f"Options: {', '.join(sorted(defaults)) or 'none'}")
        d = defaults[k]
        if v is None or d is None:
            continue
        if isinstance(d, bool) and type(v).__name__ not in ("bool", "bool_"):
            raise ParameterError(f"option '{k}' of {what} = {v!r} must be true or false (default {d})")
        if isinstance(d, (int, float)) and not isinstance(d, bool) and isinstance(v, str) \
                and v.lower() not in ("none", "null"):  # "none": the option switched off (point_subset=none)
            raise ParameterError(f"option '{k}' of {what} = {v!r} is not a number (default {d!r})")
