"""``pybullet-massspring`` model: the PyBullet deformable world of one rollout.

* ``p.resetSimulation(p.RESET_USE_DEFORMABLE_WORLD)``, gravity -9.81 m/s^2, a static box whose
  top is at ``scenario.table_z`` (not ``GEOM_PLANE``: a plane collision shape made with
  ``createCollisionShape`` pushes resting deformables upwards in PyBullet 3.2.7);
* cloth (lift, wipe, fling): an ``n x n`` grid written to a temporary ``.obj`` (vertex ``i * n + j``
  at local ``(-L/2 + h i, -L/2 + h j)``, x-major, *the same layout as mujoco-flex*), already placed
  in the world (grasped corner = vertex 0 at ``object["corner"]``, diagonal along
  ``object["direction"]``, ``margin`` above the table), loaded with ``p.loadSoftBody(...,
  useMassSpring=1, useBendingSprings=1, springElasticStiffness, springBendingStiffness,
  springDampingStiffness, springDampingAllDirections=1, frictionCoeff, useFaceContact=1)``
  (PyBullet quickstart guide, *loadSoftBody*; ``useNeoHookean`` is off: it does nothing on a
  surface mesh, see shared/MEASURED.md);
* rope (wind): a ribbon soft body of ``2 x rope_nodes`` nodes (width ``2 * rope radius``); the
  returned rope vertices are the midpoints of its node pairs, vertex 0 the grasped end; the spool
  is a static ``GEOM_CYLINDER``;
* grasp: ``p.createSoftBodyAnchor`` of the grasped node(s) to a collision-free, mass-0 body.

Stability: the mass-spring solver becomes unstable when ``k dt^2 / m_node`` grows (light nodes:
small, light, finely meshed cloths); :func:`substeps` gives the engine steps per control step.
"""
from __future__ import annotations

import ctypes
import math
import os
import sys
import tempfile
from typing import Any, Mapping

import numpy as np

from softsbi.core.errors import EnvironmentFault, ParameterError
from softsbi.core.types import Scenario
from softsbi.backends.scenario_build import grid_rest_vertices, obstacles

CLOTH_SCENARIOS = ("lift", "wipe", "fling")
ROPE_SCENARIOS = ("winding",)
#: stability constant of the substep rule k dt^2 / m_node <= STABILITY_C (measured: ~1.8 breaks)
STABILITY_C = 1.5


def import_pybullet() -> Any:
    """Import pybullet with its build-time banner sent to stderr, not stdout (the banner is written
    by C code at import, so stdout's file descriptor is pointed at stderr's meanwhile).

    Raises:
        EnvironmentFault: pybullet cannot be loaded (the message names the fix).
    """
    mod = sys.modules.get("pybullet")
    if mod is not None:
        return mod
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        import pybullet  # engine: imported once with its start-up banner sent to stderr
        ctypes.CDLL(None).fflush(None)  # flush C stdio while fd 1 still points at stderr
    except ImportError as exc:
        raise EnvironmentFault(f"PyBullet cannot be loaded ({exc}); reinstall it with "
                               f"`pip install --force-reinstall pybullet`") from exc
    finally:
        os.dup2(saved, 1)
        os.close(saved)
    return pybullet


def cloth_vertices(scenario: Scenario, L: float, n: int, z: float,
                   theta: Mapping[str, float] | None = None) -> np.ndarray:
    """Rest positions ``(n*n, 3)`` m of the cloth grid, mujoco-flex layout (vertex ``i*n+j``):
    :func:`softsbi.backends.scenario_build.grid_rest_vertices`."""
    return grid_rest_vertices(scenario, L, n, z, theta)


def ribbon_vertices(scenario: Scenario, length: float, n: int, width: float, z: float) -> np.ndarray:
    """Rest positions ``(2n, 3)`` m of a rope ribbon of ``length`` m and ``width`` m at height ``z`` m:
    node pairs ``2k, 2k+1`` straddle the rope axis, which starts at ``object["start"]`` and runs along
    ``object["direction"]``."""
    obj = scenario.object
    e = np.asarray(obj.get("direction", (0.0, -1.0)), float)
    e = e / np.linalg.norm(e)
    nrm = np.array([-e[1], e[0]])
    start = np.asarray(obj.get("start", scenario.gripper[0, :2]), float)
    axis = start + np.linspace(0, length, n)[:, None] * e
    pts = np.stack([axis - nrm * width / 2, axis + nrm * width / 2], axis=1).reshape(-1, 2)
    return np.column_stack([pts, np.full(len(pts), z)])


def ribbon_faces(n: int) -> np.ndarray:
    """Triangles ``(2 (n - 1), 3)`` int64 of a ribbon of ``n`` vertex pairs (vertex ``2k``/``2k+1`` = pair ``k``)."""
    f = []
    for k in range(n - 1):
        a, b, c, d = 2 * k, 2 * k + 1, 2 * k + 3, 2 * k + 2
        f += [(a, b, c), (a, c, d)]
    return np.asarray(f, dtype=np.int64)


def write_obj(path: str, verts: np.ndarray, faces: np.ndarray) -> None:
    """Write a Wavefront .obj to ``path``: vertices ``(N, 3)`` m (9 significant digits) and 0-based
    ``faces (F, 3)`` (written 1-based).

    Raises:
        OSError: ``path`` cannot be written.
    """
    with open(path, "w") as fh:
        fh.write("".join(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in verts))
        fh.write("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))



#: calibrated factor of :func:`spring_constants` (bending): cantilever droop vs mujoco-flex at D = 3e-4 N m
C_BEND = 20.0
#: factor of :func:`spring_constants` (membrane): 1 from the square-lattice argument (not calibrated)
C_STRETCH = 1.0


def spring_constants(bend: float, stretch: float, spacing: float, *, c_bend: float | None = None,
                     c_stretch: float | None = None) -> tuple[float, float]:
    """Map the shared physical cloth parameters to PyBullet's mass-spring knobs (the one mapping).

    Args:
        bend: bending rigidity ``D`` [N m] (plate theory, ``E t^3 / (12 (1 - nu^2))``; the same
            meaning as mujoco-flex's ``bend``).
        stretch: membrane stretch stiffness ``k`` [N/m] (``E t``; same as mujoco-flex's ``stretch``).
        spacing: rest edge length ``h`` [m] of the mesh (grid: ``scale / (grid - 1)``).
        c_bend, c_stretch: correction factors (default :data:`C_BEND`, :data:`C_STRETCH`).

    Returns:
        ``(springElasticStiffness, springBendingStiffness)`` in N/m per spring.

    Derivation:
        *Stretch* (square lattice, Provot 1995; Baraff & Witkin 1998 Sec. 4.2 use the same
        continuum-per-area scaling): structural springs of stiffness ``k_s`` along x, one per ``h``
        of width, carry a force per unit width ``k_s (h eps) / h = k_s eps`` at strain ``eps``, so the
        membrane stiffness is ``k_s`` itself, independent of ``h``: ``k_el = c_stretch * stretch``
        (the triangulation's diagonal springs add shear stiffness and some normal stiffness; not
        corrected, ``c_stretch = 1``).
        *Bend*: a bending spring joins vertices two edges apart. Continuum bending energy per area is
        ``D kappa^2 / 2``; the discrete-shell hinge energy (Grinspun et al. 2003, Eq. 5) of a hinge of
        edge ``h`` and dual area ``~h^2`` is ``~ D theta^2`` with hinge angle ``theta ~ h kappa``, so
        the per-hinge stiffness against the change in length across the hinge scales as ``D / h^2``
        (N/m): ``k_be = c_bend * D / h^2``. A distance spring resists bending only at second order
        (no linear stiffness when flat), so no exact constant exists: ``c_bend`` is calibrated by
        measurement (a clamped strip drooping under gravity, ``benchmarks/bench_backend_units.py``,
        against mujoco-flex; the backend-units suite of docs/benchmarks.md) at one rigidity
        and checked at the others.

    Raises:
        ParameterError: a value not > 0.
    """
    if not (bend > 0 and stretch > 0 and spacing > 0):
        raise ParameterError(f"bend, stretch and mesh spacing must be > 0 (got {bend}, {stretch}, {spacing})")
    cb = C_BEND if c_bend is None else float(c_bend)
    cs = C_STRETCH if c_stretch is None else float(c_stretch)
    return cs * float(stretch), cb * float(bend) / float(spacing) ** 2


def substeps(k_max: float, dt: float, m_node: float, max_substeps: int) -> int:
    """Engine steps per control step ``dt`` (s): ``ceil(sqrt(k_max dt^2 / (STABILITY_C m_node)))``
    clipped to ``1 .. max_substeps`` (``k_max`` N/m, ``m_node`` kg)."""
    return min(max_substeps, max(1, math.ceil(math.sqrt(k_max * dt * dt / (STABILITY_C * m_node)))))


def build_world(p: Any, cid: int, scenario: Scenario, verts0: np.ndarray, faces: np.ndarray, *, rope: bool,
                total_mass: float, friction: float, k_el: float, k_be: float, k_da: float, margin: float,
                step: float, grasps: list[list[int]] | None = None
                ) -> tuple[dict[str, int], list[int], list[np.ndarray]]:
    """Reset client ``cid`` to a deformable world holding the table, the spool (rope scenarios with
    ``object["spool"]``), the soft body and its grasp.

    Args:
        p: the pybullet module (:func:`import_pybullet`).
        verts0: rest positions ``(N, 3)`` m of the soft body's nodes (world frame), ``faces (F, 3)``.
        rope: the soft body is a rope ribbon (default grasp: node pair 0, 1).
        total_mass: kg. friction: Coulomb coefficient (table, spool, soft body).
        k_el, k_be, k_da: ``springElasticStiffness``, ``springBendingStiffness`` (N/m),
            ``springDampingStiffness``.
        margin: collision margin, m. step: engine time step, s.

        grasps: the soft-body nodes each handle holds (scenario handle order); default the first
            node (pair).

    Returns:
        ``(bodies, grip_bodies, starts)``: body ids ``{"table", "spool"?, "soft"}`` (obstacles by name),
        per handle the id of the collision-free mass-0 body its nodes are anchored to, and its start
        position ``(3,)`` m.
    """
    table_z = float(scenario.table_z)
    p.resetSimulation(p.RESET_USE_DEFORMABLE_WORLD, physicsClientId=cid)
    p.setGravity(*scenario.gravity, physicsClientId=cid)
    p.setTimeStep(step, physicsClientId=cid)
    # the table is a thick box: a GEOM_PLANE made with createCollisionShape pushes a resting
    # deformable *up* (measured: a flat cloth levitates 10 cm in 0.6 s), a box does not
    cx, cy = (float(v) for v in scenario.gripper[:, :2].mean(0))
    box = p.createCollisionShape(p.GEOM_BOX, halfExtents=[3.0, 3.0, 0.05], physicsClientId=cid)
    table = p.createMultiBody(0, box, basePosition=[cx, cy, table_z - 0.05], physicsClientId=cid)
    p.changeDynamics(table, -1, lateralFriction=friction, physicsClientId=cid)
    bodies = {"table": table}
    for i, sp in enumerate(obstacles(scenario)):
        if sp["type"] == "cylinder":
            shape = p.createCollisionShape(p.GEOM_CYLINDER, radius=float(sp["radius"]), height=float(sp["height"]),
                                           physicsClientId=cid)
            c = sp["centre"]
            pos, orn = [float(c[0]), float(c[1]), table_z + sp["height"] / 2], [0, 0, 0, 1]
        else:
            shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[float(v) for v in sp["half_size"]],
                                           physicsClientId=cid)
            pos = [float(v) for v in sp["centre"]]
            orn = p.getQuaternionFromEuler([0, 0, math.radians(float(sp.get("yaw", 0.0)))])
        body = p.createMultiBody(0, shape, basePosition=pos, baseOrientation=orn, physicsClientId=cid)
        p.changeDynamics(body, -1, lateralFriction=friction, physicsClientId=cid)
        bodies[sp.get("name") or f"obstacle_{i}"] = body
    fd, path = tempfile.mkstemp(suffix=".obj", prefix="softsbi_pb_")
    os.close(fd)
    try:
        write_obj(path, verts0, faces)
        sb = p.loadSoftBody(path, basePosition=[0, 0, 0], mass=total_mass, useNeoHookean=0, useMassSpring=1,
                            useBendingSprings=1, springElasticStiffness=k_el, springBendingStiffness=k_be,
                            springDampingStiffness=k_da, springDampingAllDirections=1, useSelfCollision=0,
                            frictionCoeff=friction, useFaceContact=1,
                            collisionMargin=margin, physicsClientId=cid)
    finally:
        os.unlink(path)
    # a deformable body falls asleep when its nodes are slow: a slowly drooping cloth then freezes
    # mid-way (measured: a clamped strip stops 2.6 cm short of its rest shape); keep it awake
    p.changeDynamics(sb, -1, activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING, physicsClientId=cid)
    grip_bodies, starts = [], []
    for grasped in grasps or [[0, 1] if rope else [0]]:
        start = verts0[grasped].mean(0)
        grip_body = p.createMultiBody(0, -1, basePosition=start.tolist(), physicsClientId=cid)
        for node in grasped:
            p.createSoftBodyAnchor(sb, node, grip_body, -1, physicsClientId=cid)
        grip_bodies.append(grip_body)
        starts.append(start)
    bodies["soft"] = sb
    return bodies, grip_bodies, starts
