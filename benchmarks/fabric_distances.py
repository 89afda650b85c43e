"""Repeats vs fabrics for the DiffCloud tables (the real-lift and fold suites).

Recordings are named ``<fabric>`` and ``<fabric>2`` (a repeat). Posterior means are compared in
prior-normalised (unit-cube) units over the material parameters only: the placement ``yaw`` is how
the cloth was laid on the table, not what it is made of.
"""
from __future__ import annotations

import itertools
from typing import Any, Mapping

import numpy as np


def material_unit_means(reps: Mapping[str, Mapping[str, Any]], names: list[str]) -> tuple[list[str], dict]:
    """``(material names, {recording: (M,) unit-cube posterior mean})`` from each run's ``report.json``."""
    from softsbi.core.types import ParamSpace
    first = next(iter(reps.values()))
    space = ParamSpace.from_json(first["parameters"])
    for w in reversed(first.get("widened") or []):  # a `fit --widen` run: the common prior is the one before it
        space = space.with_bounds({k: tuple(v) for k, v in w["before"].items()})
    mat = [i for i, n in enumerate(names) if n != "yaw"]
    u = {r: space.to_unit(space.as_array(rep["posterior_mean"]))[mat] for r, rep in reps.items()}
    return [names[i] for i in mat], u


def repeat_fabric_distances(u: Mapping[str, np.ndarray]) -> tuple[list[float], list[float]]:
    """Euclidean distances between posterior means: ``(repeats of a fabric, different fabrics)``."""
    same, diff = [], []
    for x, y in itertools.combinations(u, 2):
        d = float(np.linalg.norm(u[x] - u[y]))
        (same if x.rstrip("2") == y.rstrip("2") else diff).append(d)
    return same, diff
