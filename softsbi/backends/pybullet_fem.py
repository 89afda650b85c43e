"""``pybullet-fem``: cloth and rope scenarios simulated with PyBullet's deformable world (mass-spring).

Model (one fresh deformable world per rollout, on this instance's own DIRECT physics client):

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
* grasp: ``p.createSoftBodyAnchor`` of the grasped node(s) to a collision-free, mass-0 body moved
  with ``resetBasePositionAndOrientation`` along ``scenario.gripper`` (linear interpolation in
  time, offset by a constant so it starts on the grasped node);
* nodes read with ``p.getMeshData(..., flags=p.MESH_DATA_SIMULATION_MESH)`` (simulation nodes in
  ``.obj`` order).

Parameters (PyBullet's own units; the names are shared with mujoco-flex where the physics is):

* ``stretch``: ``springElasticStiffness``, N/m per structural spring (the membrane stiffness of
  the square lattice, roughly mesh independent);
* ``bend``: ``springBendingStiffness``, N/m per bending spring (springs across two edges). Weakly
  identifiable here: low vs high bound moves a light cloth by < 1 cm (benchmarks/identifiability.py);
* ``friction``: ``frictionCoeff`` (Coulomb, cloth-table and cloth-spool);
* ``scale``: cloth side / rope length, m;  ``mass``: areal (cloth, kg/m^2) or linear (rope, kg/m)
  density.

Stability (shared/MEASURED.md and the sweeps behind these bounds): the mass-spring solver
becomes unstable when ``k dt^2 / m_node`` grows (light nodes: small, light, finely meshed
cloths). Each rollout therefore takes ``substeps = ceil(sqrt(k_max dt^2 / (1.5 m_node)))`` engine
steps per ``timestep`` (``k_max = max(stretch, bend)``). Failures are *not* NaNs: the cloth
crumples, tunnels through the table or explodes to ~1000 m; they are detected from the minimum
height, the extent and the edge lengths and returned as ``STATUS_DIVERGED`` /
``STATUS_IMPLAUSIBLE`` with a reason.

Rendering (:meth:`PybulletFEM.simulate_images`): PyBullet's CPU TinyRenderer in the same DIRECT
client, one ``getCameraImage`` per recorded frame giving colour, depth and the segmentation mask
at once. The view matrix is the camera's ``[R | t]`` with OpenCV axes flipped to OpenGL's (y up,
looking along -z); the projection matrix is built from the exact intrinsics (``fx, fy, cx, cy``,
near/far :data:`NEAR`/:data:`FAR`), with TinyRenderer's half-pixel offsets compensated (measured:
without it, rendered spheres sit +0.5 px right and 0.5 px up of ``Camera.project``). Depth is the
linearised z-buffer ``near far / (far - (far - near) z)``. The visual-only robot
(:func:`~softsbi.backends.mujoco_flex.visual_robot`) is two collision-free, mass-0 multibodies
created after the cloth and moved to each frame's grasp point before rendering (the arm is a
square bar of the capsule's size: TinyRenderer shades capsule sides wrongly): they do not
change the physics (vertices bit-identical to :meth:`PybulletFEM.simulate`). Segmentation mask
ids map to labels: soft body -> 1, robot bodies -> 2, table/spool/nothing -> 0.
"""
from __future__ import annotations

import ctypes
import math
import os
import sys
import tempfile
import time
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.errors import EnvironmentFault, ParameterError
from ..core.interfaces import Simulator
from ..core.types import (SEG_BACKGROUND, SEG_OBJECT, SEG_ROBOT, STATUS_DIVERGED, STATUS_IMPLAUSIBLE,
                          STATUS_OK, Param, ParamSpace, Rollout, Scenario)
from ..plugins.hookspecs import hookimpl
from .scenarios import placed_direction, placement_params
from .mujoco_flex import PROP_COLOUR, _check_render_args, grid_corners, grid_faces, robot_base, visual_robot

CLOTH_SCENARIOS = ("lift", "wipe", "fling")
ROPE_SCENARIOS = ("wind",)
#: stability constant of the substep rule k dt^2 / m_node <= STABILITY_C (measured: ~1.8 breaks)
STABILITY_C = 1.5
#: clipping planes of the rendering projection, m
NEAR, FAR = 0.01, 20.0


def gl_matrices(camera: Any, near: float = NEAR, far: float = FAR) -> tuple[list[float], list[float]]:
    """PyBullet ``(viewMatrix, projectionMatrix)`` (16 floats each, column-major) of an OpenCV
    :class:`~softsbi.core.camera.Camera`, for ``getCameraImage`` with the TinyRenderer.

    The projection maps ``u = fx x/z + cx``, ``v = fy y/z + cy`` exactly, including TinyRenderer's
    half-pixel conventions (its pixel (i, j) is sampled at (i - 0.5, j + 0.5) of OpenCV's grid).
    """
    W, H = camera.width, camera.height
    V = np.eye(4)
    V[:3, :4] = np.diag([1.0, -1.0, -1.0]) @ np.asarray(camera.world_to_cam, dtype=float)
    P = np.zeros((4, 4))
    P[0, 0] = 2.0 * camera.fx / W
    P[0, 2] = 1.0 - 2.0 * camera.cx / W
    P[1, 1] = 2.0 * camera.fy / H
    P[1, 2] = 2.0 * (camera.cy + 1.0) / H - 1.0
    P[2, 2] = -(far + near) / (far - near)
    P[2, 3] = -2.0 * far * near / (far - near)
    P[3, 2] = -1.0
    return V.T.ravel().tolist(), P.T.ravel().tolist()


def _pb():
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
        import pybullet
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
    """Rest positions ``(n*n, 3)`` m of the cloth grid, mujoco-flex layout (vertex ``i*n+j``).

    Vertex 0 is the grasped corner at ``object["corner"]`` and the local diagonal (1, 1) points
    along ``object["direction"]`` rotated by ``theta["yaw"]`` deg if given
    (:func:`softsbi.backends.scenarios.placed_direction`).
    """
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


def ribbon_vertices(scenario: Scenario, length: float, n: int, width: float, z: float) -> np.ndarray:
    """Rest positions ``(2n, 3)`` of a rope ribbon: node pairs ``2k, 2k+1`` straddle the rope axis."""
    obj = scenario.object
    e = np.asarray(obj.get("direction", (0.0, -1.0)), float)
    e = e / np.linalg.norm(e)
    nrm = np.array([-e[1], e[0]])
    start = np.asarray(obj.get("start", scenario.gripper[0, :2]), float)
    axis = start + np.linspace(0, length, n)[:, None] * e
    pts = np.stack([axis - nrm * width / 2, axis + nrm * width / 2], axis=1).reshape(-1, 2)
    return np.column_stack([pts, np.full(len(pts), z)])


def ribbon_faces(n: int) -> np.ndarray:
    """Triangles ``(2 (n - 1), 3)`` of a ribbon of ``n`` vertex pairs (vertex ``2k``/``2k+1`` = pair ``k``)."""
    f = []
    for k in range(n - 1):
        a, b, c, d = 2 * k, 2 * k + 1, 2 * k + 3, 2 * k + 2
        f += [(a, b, c), (a, c, d)]
    return np.asarray(f, dtype=np.int64)


def write_obj(path: str, verts: np.ndarray, faces: np.ndarray) -> None:
    """Wavefront .obj with vertices ``(N, 3)`` and 0-based ``faces (F, 3)``."""
    with open(path, "w") as fh:
        fh.write("".join(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in verts))
        fh.write("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))


class PybulletFEM(Simulator):
    """Cloth (lift, wipe, fling) and rope (wind) in PyBullet's deformable world (``pybullet-fem``).

    Args:
        grid: cloth vertices per side (N = grid^2). Default 9.
        rope_nodes: rope vertices (ribbon node pairs). Default 24.
        timestep: control step, s (PyBullet's usual 1/240); engine substeps are added automatically.
        damping: ``springDampingStiffness`` (fixed; stable 0.02-5 per shared/MEASURED.md).
        margin: collision margin, m; the cloth starts this far above the table.
        max_substeps: cap of the automatic substeps.
        overrides: raw values bypassing the bounds, for tests: ``springElasticStiffness``,
            ``springBendingStiffness``, ``springDampingStiffness``, ``substeps``, ``timestep``.

    Each instance owns one PyBullet DIRECT client, created on first use (also inside worker
    processes: the client is not pickled) and reset for every rollout.
    """

    name = "pybullet-fem"
    scenarios = CLOTH_SCENARIOS + ROPE_SCENARIOS
    effects: tuple[str, ...] = ()

    def __init__(self, grid: int = 9, rope_nodes: int = 24, timestep: float = 1.0 / 240.0, damping: float = 0.1,
                 margin: float = 0.004, max_substeps: int = 10, overrides: Mapping[str, float] | None = None):
        if int(grid) < 3:
            raise ValueError(f"grid must be >= 3 vertices per side, got {grid}")
        if int(rope_nodes) < 3:
            raise ValueError(f"rope_nodes must be >= 3, got {rope_nodes}")
        if not timestep > 0:
            raise ValueError(f"timestep must be > 0, got {timestep}")
        if not damping > 0:
            raise ValueError(f"damping must be > 0 (0 explodes), got {damping}")
        self.grid, self.rope_nodes, self.timestep = int(grid), int(rope_nodes), float(timestep)
        self.damping, self.margin, self.max_substeps = float(damping), float(margin), int(max_substeps)
        self.overrides = dict(overrides or {})
        self._cid: int | None = None

    def __repr__(self) -> str:
        return f"PybulletFEM(grid={self.grid}, rope_nodes={self.rope_nodes}, timestep={self.timestep:.5g})"

    # -- pickling / client lifetime ------------------------------------------------------------
    def __getstate__(self) -> dict[str, Any]:
        st = dict(self.__dict__)
        st["_cid"] = None
        return st

    def _client(self) -> int:
        p = _pb()
        if self._cid is None or not p.isConnected(physicsClientId=self._cid):
            self._cid = p.connect(p.DIRECT)
        return self._cid

    def close(self) -> None:
        """Disconnect this instance's physics client (a later rollout reconnects)."""
        if getattr(self, "_cid", None) is not None:
            try:
                p = _pb()
                if p.isConnected(physicsClientId=self._cid):
                    p.disconnect(physicsClientId=self._cid)
            except Exception:  # noqa: BLE001 - interpreter shutdown
                pass
            self._cid = None

    def __del__(self) -> None:
        self.close()

    # -- parameters ----------------------------------------------------------------------------
    def param_space(self, scenario: Scenario) -> ParamSpace:
        """Parameters in PyBullet units (module docstring). Cloth scenarios: ``bend`` [N/m] log
        0.05-20, ``stretch`` [N/m] log 20-200, ``friction`` 0.05-1.5, ``scale`` [m] 0.20-0.34,
        ``mass`` [kg/m^2] 0.1-0.35, and ``yaw`` [deg] when ``object["yaw_bounds"]`` is set (placement
        unknown). Rope (wind): ``bend`` [N/m] log 0.05-20, ``stretch`` [N/m] log 80-600,
        ``friction`` 0.1-1.0, ``scale`` (rope length) [m] 0.3-0.5, ``mass`` [kg/m] 0.01-0.05.

        Raises:
            ValueError: scenario not supported (names the valid ones).
        """
        self._check_scenario(scenario)
        if scenario.name in ROPE_SCENARIOS:
            return ParamSpace([
                Param("bend", 0.05, 20.0, "N/m", log=True,
                      description="PyBullet springBendingStiffness of the rope ribbon (per bending spring)"),
                Param("stretch", 80.0, 600.0, "N/m", log=True,
                      description="PyBullet springElasticStiffness of the rope ribbon (per spring)"),
                Param("friction", 0.1, 1.0, "1", description="PyBullet frictionCoeff, rope-table and rope-spool"),
                Param("scale", 0.30, 0.50, "m", description="rope length"),
                Param("mass", 0.01, 0.05, "kg/m", description="linear density of the rope"),
            ])
        return ParamSpace([
            Param("bend", 0.05, 20.0, "N/m", log=True,
                  description="PyBullet springBendingStiffness (per bending spring; ~D / h^2 for rigidity D)"),
            Param("stretch", 20.0, 200.0, "N/m", log=True,
                  description="PyBullet springElasticStiffness (per structural spring; ~membrane stiffness)"),
            Param("friction", 0.05, 1.5, "1", description="PyBullet frictionCoeff, cloth-table"),
            Param("scale", 0.20, 0.34, "m", description="cloth side length (square)"),
            Param("mass", 0.1, 0.35, "kg/m^2", description="areal density (fabrics: 0.11-0.32)"),
            *placement_params(scenario),
        ])

    def _check_scenario(self, scenario: Scenario) -> None:
        if scenario.name not in self.scenarios:
            raise ValueError(f"pybullet-fem cannot run scenario '{scenario.name}'; valid scenarios: "
                             f"{', '.join(self.scenarios)}")

    def _check_effects(self, effects: Sequence[str]) -> None:
        bad = [e for e in effects if e not in self.effects]
        if bad:
            raise ParameterError(f"pybullet-fem does not support effect(s) {bad}; supported effects: "
                                 f"{', '.join(self.effects) or '(none yet)'}")

    # -- simulation ----------------------------------------------------------------------------
    def simulate(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = (),
                 seed: int = 0) -> Rollout:
        """Roll ``scenario`` out; deterministic (``seed`` is unused: the engine has no randomness).

        Returns:
            :class:`Rollout` with ``vertices (T, N, 3)`` m at ``scenario.times``: cloth
            ``N = grid^2`` with ``faces`` the grid triangles ``(2 (grid-1)^2, 3)``; rope
            ``N = rope_nodes`` (ribbon midpoints, vertex 0 grasped) with ``faces (0, 3)``.
            ``gripper (T, 3)``: the anchor body's position. ``info``: ``wall_s``, ``steps``,
            ``substeps``, ``sim_s`` (time inside ``stepSimulation``), for cloth ``corners`` (4 vertex
            indices, :func:`~softsbi.backends.mujoco_flex.grid_corners` order).

        Raises:
            ValueError: unknown scenario. ParameterError: bad/missing parameter, unsupported effect.
        """
        return self._rollout(scenario, theta, effects)

    def simulate_images(self, scenario: Scenario, theta: Mapping[str, float], camera: Any,
                        effects: Sequence[str] = (), seed: int = 0, style: Any = None) -> Rollout:
        """:meth:`simulate` plus every recorded frame rendered through ``camera`` (TinyRenderer, CPU).

        Args:
            camera: a :class:`~softsbi.core.camera.Camera` (exact pinhole intrinsics, OpenCV axes).
            style: :class:`~softsbi.core.camera.RenderStyle` colours and ``show_robot`` (default
                style if None).

        Returns:
            The rollout of :meth:`simulate` (identical vertices) with ``rgb (T, H, W, 3)`` uint8,
            ``depth (T, H, W)`` float32 m along the optical axis and ``segmentation (T, H, W)``
            uint8 (0 table/background, 1 cloth/rope, 2 robot); ``info["render_s"]`` is the time
            spent rendering (``info["render_setup_s"]`` of it once per rollout). A failed rollout
            (``status != 0``) has them None.

        Raises:
            ValueError: unknown scenario. ParameterError: bad parameter or effect.
            DataError: ``camera``/``style`` of the wrong type, or a mirrored camera (det R = -1).
        """
        style = _check_render_args(camera, style)
        frames = _PbFrames(scenario, camera, style)
        ro = self._rollout(scenario, theta, effects, frame_hook=frames)
        if ro.ok:
            ro.rgb, ro.depth, ro.segmentation = frames.rgb, frames.depth, frames.seg
        ro.info["render_s"] = frames.seconds
        ro.info["render_setup_s"] = frames.setup_seconds
        return ro

    def _rollout(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = (),
                 frame_hook: Any = None) -> Rollout:
        """The one stepping loop of :meth:`simulate` and :meth:`simulate_images`.

        ``frame_hook(k, cid, bodies, grip_pos)`` is called after frame ``k`` is recorded (``k = 0``
        before the first step) with the client id, ``{"table", "soft", "spool"?}`` body ids and the
        grasp target ``(3,)``; it is not called after a failure.
        """
        self._check_scenario(scenario)
        self._check_effects(effects)
        theta = self.param_space(scenario).check(theta)
        p = _pb()
        t0 = time.perf_counter()
        cid = self._client()
        rope = scenario.name in ROPE_SCENARIOS
        ov = self.overrides
        dt = float(ov.get("timestep", self.timestep))
        k_el = float(ov.get("springElasticStiffness", theta["stretch"]))
        k_be = float(ov.get("springBendingStiffness", theta["bend"]))
        k_da = float(ov.get("springDampingStiffness", self.damping))
        L = float(theta["scale"])
        table_z = float(scenario.table_z)
        if rope:
            radius = float(scenario.object.get("radius", 0.004))
            n = self.rope_nodes
            verts0 = ribbon_vertices(scenario, L, n, 2 * radius, table_z + max(self.margin, radius))
            faces_sim = ribbon_faces(n)
            total_mass = float(theta["mass"]) * L
        else:
            n = self.grid
            verts0 = cloth_vertices(scenario, L, n, table_z + self.margin, theta)
            faces_sim = grid_faces(n)
            total_mass = float(theta["mass"]) * L * L
        m_node = total_mass / len(verts0)
        sub = int(ov.get("substeps", 0)) or min(self.max_substeps, max(1, math.ceil(
            math.sqrt(max(k_el, k_be) * dt * dt / (STABILITY_C * m_node)))))
        h = dt / sub

        p.resetSimulation(p.RESET_USE_DEFORMABLE_WORLD, physicsClientId=cid)
        p.setGravity(0, 0, -9.81, physicsClientId=cid)
        p.setTimeStep(h, physicsClientId=cid)
        # the table is a thick box: a GEOM_PLANE made with createCollisionShape pushes a resting
        # deformable *up* (measured: a flat cloth levitates 10 cm in 0.6 s), a box does not
        cx, cy = (float(v) for v in scenario.gripper[:, :2].mean(0))
        box = p.createCollisionShape(p.GEOM_BOX, halfExtents=[3.0, 3.0, 0.05], physicsClientId=cid)
        table = p.createMultiBody(0, box, basePosition=[cx, cy, table_z - 0.05], physicsClientId=cid)
        p.changeDynamics(table, -1, lateralFriction=float(theta["friction"]), physicsClientId=cid)
        bodies = {"table": table}
        if rope and "spool" in scenario.object:
            sp = scenario.object["spool"]
            cyl = p.createCollisionShape(p.GEOM_CYLINDER, radius=float(sp["radius"]), height=float(sp["height"]),
                                         physicsClientId=cid)
            c = sp["centre"]
            spool = p.createMultiBody(0, cyl, basePosition=[float(c[0]), float(c[1]), table_z + sp["height"] / 2],
                                      physicsClientId=cid)
            p.changeDynamics(spool, -1, lateralFriction=float(theta["friction"]), physicsClientId=cid)
            bodies["spool"] = spool
        fd, path = tempfile.mkstemp(suffix=".obj", prefix="softsbi_pb_")
        os.close(fd)
        try:
            write_obj(path, verts0, faces_sim)
            sb = p.loadSoftBody(path, basePosition=[0, 0, 0], mass=total_mass, useNeoHookean=0, useMassSpring=1,
                                useBendingSprings=1, springElasticStiffness=k_el, springBendingStiffness=k_be,
                                springDampingStiffness=k_da, springDampingAllDirections=1, useSelfCollision=0,
                                frictionCoeff=float(theta["friction"]), useFaceContact=1,
                                collisionMargin=self.margin, physicsClientId=cid)
        finally:
            os.unlink(path)
        grasped = [0, 1] if rope else [0]
        start = verts0[grasped].mean(0)
        grip_body = p.createMultiBody(0, -1, basePosition=start.tolist(), physicsClientId=cid)
        for node in grasped:
            p.createSoftBodyAnchor(sb, node, grip_body, -1, physicsClientId=cid)
        bodies["soft"] = sb

        def nodes() -> np.ndarray:
            _, v = p.getMeshData(sb, -1, flags=p.MESH_DATA_SIMULATION_MESH, physicsClientId=cid)
            v = np.asarray(v, dtype=float)
            return 0.5 * (v[0::2] + v[1::2]) if rope else v

        times = scenario.times
        T = len(times)
        target = scenario.gripper + (start - scenario.gripper[0])
        first = nodes()
        N = len(first)
        verts = np.zeros((T, N, 3))
        grip = np.zeros((T, 3))
        verts[0], grip[0] = first, target[0]
        if frame_hook is not None:
            frame_hook(0, cid, bodies, grip[0])
        frame_steps = np.maximum(np.round(times / dt).astype(int), 0)
        steps = 0
        sim_s = 0.0
        status, reason = STATUS_OK, ""
        ext_limit = 3.0 * L * (1.0 if rope else math.sqrt(2.0)) + float(np.ptp(target, axis=0).max())
        for k in range(1, T):
            while steps < frame_steps[k]:
                tn = (steps + 1) * dt
                pos = [float(np.interp(tn, times, target[:, c])) for c in range(3)]
                p.resetBasePositionAndOrientation(grip_body, pos, [0, 0, 0, 1], physicsClientId=cid)
                ts = time.perf_counter()
                for _ in range(sub):
                    p.stepSimulation(physicsClientId=cid)
                sim_s += time.perf_counter() - ts
                steps += 1
            v = nodes()
            grip[k] = target[k]
            if not np.all(np.isfinite(v)):
                status, reason = STATUS_DIVERGED, f"non-finite node positions at t={times[k]:.3f} s"
                break
            verts[k] = v
            ext = float(np.ptp(v, axis=0).max())
            if ext > ext_limit or np.abs(v - target[k]).max() > ext_limit:
                status, reason = STATUS_DIVERGED, (f"exploded: extent {ext:.2f} m at t={times[k]:.3f} s "
                                                   f"(limit {ext_limit:.2f} m)")
                break
            if frame_hook is not None:
                frame_hook(k, cid, bodies, grip[k])
        wall = time.perf_counter() - t0
        if status == STATUS_OK:
            status, reason = self._plausibility(verts, table_z, L, rope, n)
        if status != STATUS_OK:
            verts = np.nan_to_num(verts, nan=0.0, posinf=0.0, neginf=0.0)
        faces = np.zeros((0, 3), dtype=np.int64) if rope else grid_faces(n)
        info = {"wall_s": wall, "sim_s": sim_s, "steps": steps, "substeps": sub, "backend": self.name,
                "grid": n, "timestep": dt, "springElasticStiffness": k_el,
                "springBendingStiffness": k_be, "springDampingStiffness": k_da, "effects": list(effects)}
        if not rope:
            info["corners"] = grid_corners(n)
        return Rollout(times=times.copy(), gripper=grip, vertices=verts, faces=faces, status=status, reason=reason,
                       info=info)

    @staticmethod
    def _plausibility(verts: np.ndarray, table_z: float, L: float, rope: bool, n: int) -> tuple[int, str]:
        zmin = float(verts[..., 2].min())
        if zmin < table_z - 0.02:
            return STATUS_IMPLAUSIBLE, f"tunnelled through the table: a node is {100 * (table_z - zmin):.1f} cm below it"
        h = L / (n - 1)
        if rope:
            edge = np.linalg.norm(np.diff(verts, axis=1), axis=-1)
        else:
            g = verts.reshape(len(verts), n, n, 3)
            edge = np.concatenate([np.linalg.norm(np.diff(g, axis=1), axis=-1).reshape(len(verts), -1),
                                   np.linalg.norm(np.diff(g, axis=2), axis=-1).reshape(len(verts), -1)], axis=1)
        if edge.max() > 3.0 * h:
            return STATUS_IMPLAUSIBLE, f"torn: an edge is stretched to {edge.max() / h:.1f}x its rest length"
        # crumpled: the mesh collapsed (mean edge far below rest length)
        if edge[-1].mean() < 0.3 * h:
            return STATUS_IMPLAUSIBLE, f"crumpled: mean edge {edge[-1].mean() / h:.2f}x its rest length"
        return STATUS_OK, ""


def _rgba(c: Sequence[int]) -> list[float]:
    return [c[0] / 255.0, c[1] / 255.0, c[2] / 255.0, 1.0]


class _PbFrames:
    """Renders each recorded frame of a PyBullet rollout (the ``frame_hook`` of ``_rollout``)."""

    def __init__(self, scenario: Scenario, camera: Any, style: Any):
        self.camera, self.style = camera, style
        self.base = robot_base(scenario)
        T, H, W = scenario.n_frames, camera.height, camera.width
        self.rgb = np.zeros((T, H, W, 3), np.uint8)
        self.depth = np.zeros((T, H, W), np.float32)
        self.seg = np.zeros((T, H, W), np.uint8)
        self.view, self.proj = gl_matrices(camera)
        self.robot: list[tuple[int, str]] = []
        self.lut: dict[int, int] = {}
        self.seconds = 0.0
        self.setup_seconds = 0.0

    def _setup(self, cid: int, bodies: Mapping[str, int], grip: np.ndarray) -> None:
        p = _pb()
        st = self.style
        p.changeVisualShape(bodies["table"], -1, rgbaColor=_rgba(st.table), physicsClientId=cid)
        if "spool" in bodies:
            p.changeVisualShape(bodies["spool"], -1, rgbaColor=_rgba(PROP_COLOUR), physicsClientId=cid)
        p.changeVisualShape(bodies["soft"], -1, rgbaColor=_rgba(st.cloth), flags=p.VISUAL_SHAPE_DOUBLE_SIDED,
                            physicsClientId=cid)
        self.lut = {bodies["soft"]: SEG_OBJECT}
        if st.show_robot:
            for part in visual_robot(grip, self.base):
                colour = _rgba(st.gripper if part["part"] == "gripper" else st.robot)
                if part["shape"] == "box":
                    vs = p.createVisualShape(p.GEOM_BOX, halfExtents=[float(v) for v in part["size"]],
                                             rgbaColor=colour, physicsClientId=cid)
                else:
                    # the arm as a square bar of the capsule's width and length (no caps): TinyRenderer
                    # lights the sides of capsules/cylinders as if their normals pointed inwards
                    # (a tilted white capsule renders at ambient grey), flat faces are lit correctly
                    r, hl = float(part["size"][0]), float(part["size"][1])
                    vs = p.createVisualShape(p.GEOM_BOX, halfExtents=[r, r, hl], rgbaColor=colour,
                                             physicsClientId=cid)
                # no collision shape, mass 0: invisible to the physics
                body = p.createMultiBody(0, -1, vs, physicsClientId=cid)
                self.robot.append((body, part["part"]))
                self.lut[body] = SEG_ROBOT

    def __call__(self, k: int, cid: int, bodies: Mapping[str, int], grip: np.ndarray) -> None:
        from scipy.spatial.transform import Rotation
        p = _pb()
        t0 = time.perf_counter()
        if k == 0:
            self._setup(cid, bodies, grip)
            self.setup_seconds = time.perf_counter() - t0
        if self.robot:
            parts = {q["part"]: q for q in visual_robot(grip, self.base)}
            for body, name in self.robot:
                q = parts[name]
                p.resetBasePositionAndOrientation(body, [float(v) for v in q["pos"]],
                                                  Rotation.from_matrix(q["rot"]).as_quat().tolist(),
                                                  physicsClientId=cid)
        W, H = self.camera.width, self.camera.height
        _, _, rgba, zbuf, ids = p.getCameraImage(W, H, self.view, self.proj, renderer=p.ER_TINY_RENDERER,
                                                 shadow=0, lightDirection=[0.3, -0.2, 1.0],
                                                 lightAmbientCoeff=0.45, lightDiffuseCoeff=0.55,
                                                 lightSpecularCoeff=0.0, physicsClientId=cid)
        self.rgb[k] = np.asarray(rgba, dtype=np.uint8).reshape(H, W, 4)[..., :3]
        z = np.asarray(zbuf, dtype=np.float64).reshape(H, W)
        self.depth[k] = (NEAR * FAR / (FAR - (FAR - NEAR) * z)).astype(np.float32)
        ids = np.asarray(ids, dtype=np.int64).reshape(H, W)
        lab = np.full((H, W), SEG_BACKGROUND, np.uint8)
        for body, label in self.lut.items():
            lab[ids == body] = label
        self.seg[k] = lab
        self.seconds += time.perf_counter() - t0


@hookimpl
def softsbi_simulators() -> list[type[Simulator]]:
    return [PybulletFEM]
