"""Engine-independent pieces of building any valid scenario (both backends use them).

* :func:`required_features` / :func:`check_features`: what a scenario needs from an engine
  (``cloth``, ``cloth-mesh``, ``rope``, ``several handles``, ``pinned handles``, ``box obstacles``,
  ``cylinder obstacles``), refused in one line naming the missing feature;
* rest geometry: :func:`grid_rest_vertices` (the square grid both engines use, vertex ``i * n + j``)
  and :func:`mesh_rest` (a mesh cloth at its placement, scaled and rotated by ``theta``);
* :func:`handle_vertices`: the vertex each handle holds.

Mesh placement: the mesh lies flat on the table (``z = table_z + lift``: every vertex keeps its
x, y), or with ``placement.rest: mesh`` keeps the file's heights above its lowest vertex; ``theta["scale"]`` (the side of a square of the same area, m) scales it and ``theta["yaw"]``
(deg, counter-clockwise from above) rotates it, both about the first moving handle's vertex
(``object["mesh"]["pivot"]``).
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.core.errors import ParameterError
from softsbi.core.types import Scenario
from softsbi.scenarios.grid import grid_corners
from softsbi.scenarios.builtin import placed_direction
from softsbi.scenarios.spec import obstacles

#: every feature name :func:`required_features` can return
FEATURES = ("cloth", "cloth-mesh", "rope", "several handles", "pinned handles", "box obstacles",
            "cylinder obstacles")


def required_features(scenario: Scenario) -> list[str]:
    """The engine features ``scenario`` needs (names from :data:`FEATURES`)."""
    obj = scenario.object
    kind = obj.get("kind", "cloth")
    if kind not in ("cloth", "rope"):
        return [f"objects of kind '{kind}'"]
    out = ["rope" if kind == "rope" else ("cloth-mesh" if "mesh" in obj else "cloth")]
    if len(scenario.handles) > 1:
        out.append("several handles")
    if any(h.pinned for h in scenario.handles):
        out.append("pinned handles")
    for o in obstacles(scenario):
        f = f"{o['type']} obstacles"
        if f not in out:
            out.append(f)
    return out


def unsupported(sim: Any, scenario: Scenario) -> str | None:
    """Why ``sim`` (a simulator class or instance) cannot run ``scenario``, or None. A backend with a
    ``features`` attribute runs every scenario needing only those; one without it (an older plugin)
    runs the scenario names in its ``scenarios``."""
    if not hasattr(sim, "features"):
        if scenario.name in getattr(sim, "scenarios", ()):
            return None
        return (f"{sim.name} cannot run scenario '{scenario.name}'; it runs "
                f"{', '.join(getattr(sim, 'scenarios', ())) or 'no scenario'}")
    have = set(sim.features)
    missing = [f for f in required_features(scenario) if f not in have]
    if not missing:
        return None
    return (f"{sim.name} cannot run scenario '{scenario.name}': it lacks {', '.join(missing)} "
            f"(it supports {', '.join(f for f in FEATURES if f in have)}); use another backend or "
            f"change the scenario")


def check_features(sim: Any, scenario: Scenario) -> None:
    """Refuse a scenario needing a feature missing from ``sim.features``.

    Raises:
        ValueError: one line naming the backend, the scenario and the missing feature.
    """
    why = unsupported(sim, scenario)
    if why:
        raise ValueError(why)


def friction_words(scenario: Scenario, obj: str) -> str:
    """What a friction coefficient acts between, from the scenario's own obstacles (:func:`obstacles`, by name, else
    by type): ``"rope-table friction coefficient"``, ``"rope-table and rope-spool friction coefficient"``."""
    pairs = [f"{obj}-{o}" for o in dict.fromkeys(["table"] + [o.get("name") or o["type"] for o in obstacles(scenario)])]
    return (" and ".join(pairs) if len(pairs) < 3 else ", ".join(pairs[:-1]) + " and " + pairs[-1]) + \
        " friction coefficient"


def grid_rest_vertices(scenario: Scenario, L: float, n: int, z: float,
                       theta: Mapping[str, float] | None = None) -> np.ndarray:
    """Rest positions ``(n*n, 3)`` m of the square cloth grid (vertex ``i*n+j`` at local
    ``(-L/2 + h i, -L/2 + h j)``): vertex 0 at ``object["corner"]``, the local diagonal (1, 1) along
    ``object["direction"]`` rotated by ``theta["yaw"]`` deg
    (:func:`softsbi.scenarios.builtin.placed_direction`)."""
    obj = scenario.object
    d = placed_direction(scenario, theta)
    corner = np.asarray(obj.get("corner", scenario.gripper[0, :2]), dtype=float)
    phi = math.atan2(d[1], d[0]) - math.pi / 4
    c, s = math.cos(phi), math.sin(phi)
    g = np.linspace(-L / 2, L / 2, n)
    loc = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    rot = loc @ np.array([[c, s], [-s, c]])
    centre = corner + d * L / math.sqrt(2.0)
    return np.column_stack([rot + centre, np.full(len(rot), z)])


def mesh_rest(scenario: Scenario, theta: Mapping[str, float], z: float) -> tuple[np.ndarray, np.ndarray]:
    """Rest vertices ``(N, 3)`` m and triangles ``(F, 3)`` of a mesh cloth (module docstring), flat at
    height ``z`` m."""
    mesh = scenario.object["mesh"]
    v = np.asarray(mesh["vertices"], dtype=float).copy()
    f = np.asarray(mesh["faces"], dtype=np.int64)
    piv = v[int(mesh["pivot"]), :2].copy()
    k = float(theta.get("scale", scenario.object["size"])) / float(scenario.object["size"])
    a = math.radians(float(theta.get("yaw", 0.0)))
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    v[:, :2] = piv + ((v[:, :2] - piv) * k) @ rot.T
    v[:, 2] = z + ((v[:, 2] - v[:, 2].min()) * k if mesh.get("rest") == "mesh" else 0.0)
    return v, f


def handle_vertices(scenario: Scenario, rest: np.ndarray, n: int | None = None) -> list[int]:
    """Vertex index of each handle of ``scenario`` in a body whose rest positions are ``rest (N, 3)``.

    ``corner`` k: :func:`~softsbi.scenarios.grid.grid_corners` of the ``n x n`` grid; ``end`` 0/1: first
    or last rope vertex; ``vertex`` i: as given (mesh order); ``point``: the nearest rest vertex.

    Raises:
        ParameterError: a vertex index out of range.
    """
    out = []
    N = len(rest)
    for h in scenario.handles:
        (kind, val), = h.grasp.items()
        if kind == "corner":
            out.append(grid_corners(int(n))[int(val)])
        elif kind == "end":
            out.append(0 if int(val) == 0 else N - 1)
        elif kind == "vertex":
            if not 0 <= int(val) < N:
                raise ParameterError(f"handle '{h.name}' holds vertex {val}, but the object has {N} vertices; "
                                     f"choose 0..{N - 1}")
            out.append(int(val))
        else:
            out.append(int(np.argmin(np.linalg.norm(rest - np.asarray(val, dtype=float), axis=1))))
    return out


def handle_targets(scenario: Scenario, starts: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Each handle's target path ``(T, 3)`` m: its commanded path shifted by a constant so it starts
    at ``starts[h]`` (the grasped vertex at rest), or ``starts[h]`` held for a pinned handle."""
    T = scenario.n_frames
    out = []
    for h, s in zip(scenario.handles, starts):
        s = np.asarray(s, dtype=float)
        out.append(np.repeat(s[None], T, axis=0) if h.path is None else h.path + (s - h.path[0]))
    return out


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """Unique undirected edges ``(E, 2)`` of triangles ``(F, 3)``."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0)
