"""Typed pluggy hook specifications of the ``softsbi`` project.

A plugin is a module (or object) with functions decorated by :data:`hookimpl`, exposed
through the ``softsbi`` entry-point group of its package, e.g. in ``pyproject.toml``::

    [project.entry-points.softsbi]
    mytoy = "mytoy.plugin"

Each hook returns a list of *classes*; softsbi instantiates them on demand. Built-in
plugins are registered through the same entry points as third-party ones.
"""
from __future__ import annotations

import pluggy

from ..core.interfaces import Effect, Executor, KeypointExtractor, Observer, PosteriorEstimator, Simulator

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
