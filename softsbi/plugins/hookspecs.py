"""Typed pluggy hook specifications of the ``softsbi`` project.

A plugin is a module (or object) with functions decorated by :data:`hookimpl`, exposed
through the ``softsbi`` entry-point group of its package, e.g. in ``pyproject.toml``::

    [project.entry-points.softsbi]
    mytoy = "mytoy.plugin"

Each hook returns a list of *classes*; softsbi instantiates them on demand. Built-in
plugins are registered through the same entry points as third-party ones.

The registry (:mod:`softsbi.plugins.manager`) checks every plugin when it is built and raises
:class:`~softsbi.core.errors.PluginError` for: a hook returning anything but classes derived
from the hook's ABC with a non-empty string ``name``; two classes of one kind with the same
name or alias; a ``@hookimpl`` function whose name is not one of the hooks below (a typo). A
class renamed may keep its old name working for a while (with a ``FutureWarning``)::

    class MassSpring(Simulator):
        name = "pybullet-massspring"
        aliases = ("pybullet-fem",)
"""
from __future__ import annotations

import pluggy

from softsbi.core.interfaces import Effect, Executor, KeypointExtractor, Observer, PosteriorEstimator, Simulator

PROJECT = "softsbi"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def softsbi_simulators() -> list[type[Simulator]]:
    """Simulator backends this plugin provides."""


@hookspec
def softsbi_effects() -> list[type[Effect]]:
    """Physical effects this plugin provides."""


@hookspec
def softsbi_observers() -> list[type[Observer]]:
    """Observers / keypoint extractors this plugin provides."""


@hookspec
def softsbi_estimators() -> list[type[PosteriorEstimator]]:
    """Posterior estimators this plugin provides."""


@hookspec
def softsbi_executors() -> list[type[Executor]]:
    """Executors (where simulations run) this plugin provides."""


@hookspec
def softsbi_extractors() -> list[type[KeypointExtractor]]:
    """Keypoint extractors (image -> K keypoints) this plugin provides."""


@hookspec
def softsbi_scenarios() -> dict:
    """Code-defined scenarios: ``{name: Scenario | zero-argument callable returning one | scenario file
    path}`` (:mod:`softsbi.scenarios.catalog`; ``softsbi scenarios`` lists them)."""
