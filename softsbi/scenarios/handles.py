"""Where a scenario's handles hold a simulated object: each moving handle's path shifted onto its grasped vertex,
the vertices the pinned handles hold in place (the figures and the animation draw them)."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from softsbi.scenarios.grid import grid_corners


def handle_tracks(scenario: Any, vertices0: np.ndarray | None = None,
                  rope: bool = False) -> list[tuple[str, np.ndarray]]:
    """``[(name, (T, 3) m)]``: every handle of ``scenario`` that follows a path (its grippers), the scenario's
    gripper first; a scenario built without handles gives its ``gripper`` path, named ``gripper``. With a
    rollout's frame-0 vertices ``vertices0 (N, 3)`` m, each path is shifted to start on its grasped vertex
    (:func:`grasped_vertex`), as the backends shift it; else it is drawn as commanded."""
    tracks = []
    for h in getattr(scenario, "handles", None) or []:
        if h.path is None:
            continue
        path = np.asarray(h.path, float)
        i = None if vertices0 is None else grasped_vertex(h.grasp, vertices0, rope)
        tracks.append((h.name, path if i is None else path + (vertices0[i] - path[0])))
    return tracks or [("gripper", np.asarray(scenario.gripper, float))]


def pinned_vertices(scenario: Any, vertices0: np.ndarray, rope: bool) -> list[tuple[str, int]]:
    """``[(name, vertex index)]`` of the pinned handles of ``scenario`` in a rollout whose frame-0 vertices are
    ``vertices0 (N, 3)`` m (:func:`grasped_vertex`; a grasp it does not locate is left out)."""
    out = []
    for h in getattr(scenario, "handles", None) or []:
        i = None if h.path is not None else grasped_vertex(h.grasp, vertices0, rope)
        if i is not None:
            out.append((h.name, i))
    return out


def grasped_vertex(grasp: Mapping[str, Any], vertices0: np.ndarray, rope: bool) -> int | None:
    """The vertex a handle's ``grasp`` holds in a rollout with frame-0 vertices ``vertices0 (N, 3)`` m: a mesh
    ``vertex``, a rope ``end``, the vertex nearest a ``point``, a ``corner`` of a square grid
    (:func:`~softsbi.scenarios.grid.grid_corners`); None when the rollout does not show which."""
    N = len(vertices0)
    n = int(round(N ** 0.5))
    kind, v = next(iter(grasp.items()))
    if kind == "vertex":
        i = int(v)
    elif kind == "end" and rope:
        i = 0 if int(v) == 0 else N - 1
    elif kind == "point":
        i = int(np.argmin(np.linalg.norm(vertices0 - np.asarray(v, float), axis=1)))
    elif kind == "corner" and not rope and n * n == N:
        i = grid_corners(n)[int(v)]
    else:
        return None
    return i if 0 <= i < N else None

