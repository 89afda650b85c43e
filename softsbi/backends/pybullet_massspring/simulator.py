"""``pybullet-massspring``: the :class:`PybulletMassSpring` simulator and its one stepping loop.

Each rollout builds a fresh deformable world (:func:`~.model.build_world`) on this instance's own
DIRECT physics client and moves the grasp body with ``resetBasePositionAndOrientation`` along
``scenario.gripper`` (linear interpolation in time, offset by a constant so it starts on the
grasped node); nodes are read with ``p.getMeshData(..., flags=p.MESH_DATA_SIMULATION_MESH)``
(simulation nodes in ``.obj`` order).

Parameters: cloth has the *shared physical* parameters, the same names, units, meaning and (where
honoured) bounds as mujoco-flex (:func:`~softsbi.backends.common.cloth_material_params`): ``bend``
bending rigidity [N m], ``stretch`` membrane stiffness [N/m], ``friction`` (Coulomb, cloth-table),
``scale`` side [m], ``mass`` areal density [kg/m^2]. :func:`~.model.spring_constants` is the one
mapping to PyBullet's ``springElasticStiffness`` / ``springBendingStiffness`` (derivation and
calibration in its docstring). Rope (wind) has PyBullet-only spring knobs ``pb_rope_bend`` and
``pb_rope_stretch`` (N/m per ribbon spring; formerly ``bend``/``stretch``: those names now raise a
one-line rename error, :meth:`PybulletMassSpring.check_legacy_theta`).

Stability (shared/MEASURED.md and the sweeps behind these bounds): each rollout takes
``substeps = ceil(sqrt(k_max dt^2 / (1.5 m_node)))`` engine steps per ``timestep``
(``k_max = max(stretch, bend)``, :func:`~.model.substeps`). Failures are *not* NaNs: the cloth
crumples, tunnels through the table or explodes to ~1000 m; they are detected from the minimum
height, the extent and the edge lengths and returned as ``STATUS_DIVERGED`` /
``STATUS_IMPLAUSIBLE`` with a reason.

Rendering: :meth:`~softsbi.core.interfaces.Simulator.simulate_images` (the base class template)
runs :meth:`PybulletMassSpring._rollout` with :class:`~.render.PbFrameRenderer`.
"""
from __future__ import annotations

import math
import time
from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.backends.common import (EffectsThroughDoor, check_effects, check_scenario, cloth_material_params,
                                     grid_corners, grid_faces, size_params)
from softsbi.backends.scenario_build import FEATURES, friction_words, handle_targets, handle_vertices, mesh_edges, mesh_rest
from softsbi.backends.pybullet_massspring.model import (CLOTH_SCENARIOS, ROPE_SCENARIOS, build_world, cloth_vertices,
                                                        import_pybullet, ribbon_faces, ribbon_vertices, spring_constants,
                                                        substeps)
from softsbi.backends.pybullet_massspring.render import PbFrameRenderer, PbState
from softsbi.core.interfaces import OBSERVATION, Simulator
from softsbi.core.errors import ParameterError
from softsbi.core.types import STATUS_DIVERGED, STATUS_IMPLAUSIBLE, STATUS_OK, Param, ParamSpace, Rollout, Scenario


#: the ``stretch`` bounds [N/m] this backend honours (a sub-box of the shared 5-1000: stiffer springs crumple)
PB_STRETCH_BOUNDS = (20.0, 200.0)


class PybulletMassSpring(Simulator):
    """Cloth (lift, wipe, fling) and rope (wind) in PyBullet's deformable world, mass-spring model
    (``pybullet-massspring``; the old name ``pybullet-fem`` still resolves, with a FutureWarning).

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

    name = "pybullet-massspring"
    #: former plugin names (resolved by the registry with a FutureWarning)
    aliases = ("pybullet-fem",)
    #: the built-in scenarios; any scenario file needing only :attr:`features` runs too
    scenarios = CLOTH_SCENARIOS + ROPE_SCENARIOS
    #: grid or mesh cloth (a soft body from the mesh), rope (ribbon), any number of handles (soft-body
    #: anchors to mass-0 bodies), box and cylinder obstacles
    features = FEATURES
    #: every registered effect this backend supports (no effect is known by name)
    effects = EffectsThroughDoor()
    #: observation transforms only: PyBullet 3.2's applyExternalForce does nothing to a deformable
    #: body's nodes (measured: all-node and whole-body forces of 2 m g leave a lift unchanged to
    #: the last digit), and its deformable world has no model edits registered yet
    effect_kinds = (OBSERVATION,)

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
        return f"PybulletMassSpring(grid={self.grid}, rope_nodes={self.rope_nodes}, timestep={self.timestep:.5g})"

    # -- pickling / client lifetime ------------------------------------------------------------
    def __getstate__(self) -> dict[str, Any]:
        st = dict(self.__dict__)
        st["_cid"] = None
        return st

    def _client(self) -> int:
        p = import_pybullet()
        if self._cid is None or not p.isConnected(physicsClientId=self._cid):
            self._cid = p.connect(p.DIRECT)
        return self._cid

    def close(self) -> None:
        """Disconnect this instance's physics client (a later rollout reconnects)."""
        if getattr(self, "_cid", None) is not None:
            try:
                p = import_pybullet()
                if p.isConnected(physicsClientId=self._cid):
                    p.disconnect(physicsClientId=self._cid)
            except Exception:  # noqa: BLE001 - interpreter shutdown
                pass
            self._cid = None

    def __del__(self) -> None:
        self.close()

    # -- parameters ----------------------------------------------------------------------------
    def param_space(self, scenario: Scenario) -> ParamSpace:
        """Cloth (any grid or mesh cloth): the shared physical parameters with mujoco-flex's names,
        units and meaning (:func:`~softsbi.backends.common.cloth_material_params`: ``bend`` [N m],
        ``stretch`` [N/m], ``friction``, then ``scale`` [m], ``mass`` [kg/m^2], ``yaw`` [deg]); they
        become spring constants in :func:`~.model.spring_constants`. ``stretch`` is narrowed to
        :data:`PB_STRETCH_BOUNDS` (stiffer springs crumple at the default step and substep cap).
        Rope (wind): PyBullet-only knobs ``pb_rope_bend`` [N/m] log 0.05-20 and ``pb_rope_stretch``
        [N/m] log 80-600 (per ribbon spring), ``friction`` 0.1-1.0, ``scale`` (rope length) [m]
        0.3-0.5, ``mass`` [kg/m] 0.01-0.05.

        Raises:
            ValueError: scenario not supported (names the valid ones).
        """
        check_scenario(self, scenario)
        if scenario.object.get("kind") == "rope":
            return ParamSpace([
                Param("pb_rope_bend", 0.05, 20.0, "N/m", log=True,
                      description="PyBullet springBendingStiffness of the rope ribbon (per bending spring)"),
                Param("pb_rope_stretch", 80.0, 600.0, "N/m", log=True,
                      description="PyBullet springElasticStiffness of the rope ribbon (per spring)"),
                Param("friction", 0.1, 1.0, "1", description=friction_words(scenario, "rope")),
                *size_params(scenario, True),
            ])
        return ParamSpace([*cloth_material_params(stretch=PB_STRETCH_BOUNDS), *size_params(scenario, False)])

    @staticmethod
    def check_legacy_theta(scenario: Scenario, theta: Mapping[str, float]) -> None:
        """Refuse parameters written for the pre-issue-15 PyBullet units with one line naming the rename.

        Raises:
            ParameterError: rope ``bend``/``stretch`` (now ``pb_rope_bend``/``pb_rope_stretch``), or a
                cloth ``bend`` >= 0.05 (a per-spring N/m value, the old unit; the
                shared N m range ends at 1e-3).
        """
        rope = scenario.object.get("kind") == "rope"
        if rope and ("bend" in theta or "stretch" in theta):
            raise ParameterError("pybullet-massspring rope parameters were renamed: bend -> pb_rope_bend, stretch -> "
                                 "pb_rope_stretch (same values, N/m per ribbon spring); rename them in your theta")
        if not rope and "bend" in theta and float(theta["bend"]) >= 0.05:
            raise ParameterError(f"pybullet-massspring 'bend' is now the bending rigidity in N*m (1e-06..0.001, as on "
                                 f"mujoco-flex), got {theta['bend']}: that is an old per-spring N/m value; convert "
                                 f"it with bend = value * h^2 / C_BEND (spring_constants), or pass it raw as "
                                 f"overrides={{'springBendingStiffness': value}}")

    # -- simulation ----------------------------------------------------------------------------
    def simulate(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = (),
                 seed: int = 0) -> Rollout:
        """Roll ``scenario`` out; the engine is deterministic (``seed`` seeds only the observation
        transforms of sensor effects, the one effect door this backend implements).

        Returns:
            :class:`Rollout` with ``vertices (T, N, 3)`` m at ``scenario.times``: cloth
            ``N = grid^2`` with ``faces`` the grid triangles ``(2 (grid-1)^2, 3)``; rope
            ``N = rope_nodes`` (ribbon midpoints, vertex 0 grasped) with ``faces (0, 3)``.
            ``gripper (T, 3)``: the anchor body's position. ``info``: ``wall_s``, ``steps``,
            ``substeps``, ``sim_s`` (time inside ``stepSimulation``), for cloth ``corners`` (4 vertex
            indices, :func:`~softsbi.backends.common.grid_corners` order).

        Raises:
            ValueError: unknown scenario. ParameterError: bad/missing parameter, unsupported effect.
        """
        return self._rollout(scenario, theta, effects, seed)

    def _frame_renderer(self, scenario: Scenario, camera: Any, style: Any) -> PbFrameRenderer:
        """The TinyRenderer frame renderer of :meth:`simulate_images` (CPU, no OpenGL)."""
        return PbFrameRenderer(scenario, camera, style)

    def _rollout(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = (),
                 seed: int = 0, frames: PbFrameRenderer | None = None) -> Rollout:
        """The one stepping loop of :meth:`simulate` and :meth:`simulate_images` (``seed`` seeds the
        effects' observation transforms, applied to the finished rollout).

        With ``frames``: ``frames(k, PbState(cid, bodies, grip_pos))`` is called after frame ``k``
        is recorded (``k = 0`` before the first step) with the client id, the ``{"table", "soft",
        "spool"?}`` body ids and the grasp target ``(3,)`` m; it is not called after a failure.
        """
        check_scenario(self, scenario)
        plan = check_effects(self, effects)
        self.check_legacy_theta(scenario, theta)
        theta = plan.space(self.param_space(scenario)).check(theta, within="limits")
        p = import_pybullet()
        t0 = time.perf_counter()
        cid = self._client()
        rope = scenario.object.get("kind") == "rope"
        mesh = "mesh" in scenario.object
        ov = self.overrides
        dt = float(ov.get("timestep", self.timestep))
        k_da = float(ov.get("springDampingStiffness", self.damping))
        L = float(theta["scale"])
        table_z = float(scenario.table_z)
        if rope:
            radius = float(scenario.object.get("radius", 0.004))
            n = self.rope_nodes
            verts0 = ribbon_vertices(scenario, L, n, 2 * radius, table_z + max(self.margin, radius))
            faces_sim = ribbon_faces(n)
            total_mass = float(theta["mass"]) * L
            vidx = handle_vertices(scenario, 0.5 * (verts0[0::2] + verts0[1::2]))
            grasps = [[2 * v, 2 * v + 1] for v in vidx]
        elif mesh:
            verts0, faces_sim = mesh_rest(scenario, theta, table_z + self.margin)
            n = len(verts0)
            area = float(0.5 * np.linalg.norm(np.cross(verts0[faces_sim[:, 1]] - verts0[faces_sim[:, 0]],
                                                       verts0[faces_sim[:, 2]] - verts0[faces_sim[:, 0]]), axis=1).sum())
            total_mass = float(theta["mass"]) * area
            vidx = handle_vertices(scenario, verts0)
            grasps = [[v] for v in vidx]
        else:
            n = self.grid
            verts0 = cloth_vertices(scenario, L, n, table_z + self.margin, theta)
            faces_sim = grid_faces(n)
            total_mass = float(theta["mass"]) * L * L
            vidx = handle_vertices(scenario, verts0, n)
            grasps = [[v] for v in vidx]
        if rope:
            k_el, k_be = float(theta["pb_rope_stretch"]), float(theta["pb_rope_bend"])
        else:
            spacing = (float(np.linalg.norm(verts0[mesh_edges(faces_sim)[:, 0]] - verts0[mesh_edges(faces_sim)[:, 1]],
                                            axis=1).mean()) if mesh else L / (n - 1))
            k_el, k_be = spring_constants(float(theta["bend"]), float(theta["stretch"]), spacing)
        k_el = float(ov.get("springElasticStiffness", k_el))
        k_be = float(ov.get("springBendingStiffness", k_be))
        m_node = total_mass / len(verts0)
        sub = int(ov.get("substeps", 0)) or substeps(max(k_el, k_be), dt, m_node, self.max_substeps)
        h = dt / sub
        bodies, grip_bodies, starts = build_world(p, cid, scenario, verts0, faces_sim, rope=rope,
                                                  total_mass=total_mass, friction=float(theta["friction"]), k_el=k_el,
                                                  k_be=k_be, k_da=k_da, margin=self.margin, step=h, grasps=grasps)
        # each handle's path starts on its grasped node(s); pinned handles stay where their nodes rest
        targets = handle_targets(scenario, starts)
        first = next(i for i, hd in enumerate(scenario.handles) if not hd.pinned)
        grip_body = grip_bodies[first]
        others = [(b, tg) for i, (b, tg, hd) in enumerate(zip(grip_bodies, targets, scenario.handles))
                  if i != first and not hd.pinned]
        sb = bodies["soft"]

        def nodes() -> np.ndarray:
            _, v = p.getMeshData(sb, -1, flags=p.MESH_DATA_SIMULATION_MESH, physicsClientId=cid)
            v = np.asarray(v, dtype=float)
            return 0.5 * (v[0::2] + v[1::2]) if rope else v

        times = scenario.times
        T = len(times)
        target = targets[first]
        first = nodes()
        N = len(first)
        verts = np.zeros((T, N, 3))
        grip = np.zeros((T, 3))
        verts[0], grip[0] = first, target[0]
        if frames is not None:
            frames(0, PbState(cid, bodies, grip[0]))
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
                for b, tg in others:
                    p.resetBasePositionAndOrientation(b, [float(np.interp(tn, times, tg[:, c])) for c in range(3)],
                                                      [0, 0, 0, 1], physicsClientId=cid)
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
            if frames is not None:
                frames(k, PbState(cid, bodies, grip[k]))
        wall = time.perf_counter() - t0
        if status == STATUS_OK:
            status, reason = self._plausibility(verts, table_z, L, rope, n,
                                                mesh_edges(faces_sim) if mesh else None)
        if status != STATUS_OK:
            verts = np.nan_to_num(verts, nan=0.0, posinf=0.0, neginf=0.0)
        faces = np.zeros((0, 3), dtype=np.int64) if rope else (faces_sim if mesh else grid_faces(n))
        info = {"handle_vertices": list(vidx), "wall_s": wall, "sim_s": sim_s, "steps": steps, "substeps": sub, "backend": self.name,
                "grid": n, "timestep": dt, "springElasticStiffness": k_el,
                "springBendingStiffness": k_be, "springDampingStiffness": k_da, "effects": list(effects)}
        if not rope and not mesh:
            info["corners"] = grid_corners(n)
        ro = Rollout(times=times.copy(), gripper=grip, vertices=verts, faces=faces, status=status, reason=reason,
                     info=info)
        return plan.observe(ro, theta, seed)

    @staticmethod
    def _plausibility(verts: np.ndarray, table_z: float, L: float, rope: bool, n: int,
                      edges: np.ndarray | None = None) -> tuple[int, str]:
        zmin = float(verts[..., 2].min())
        if zmin < table_z - 0.02:
            return STATUS_IMPLAUSIBLE, f"tunnelled through the table: a node is {100 * (table_z - zmin):.1f} cm below it"
        h = L / (n - 1)
        if edges is not None:  # a mesh cloth: edge lengths relative to their rest lengths
            rest = np.linalg.norm(verts[0, edges[:, 0]] - verts[0, edges[:, 1]], axis=-1)
            edge = np.linalg.norm(verts[:, edges[:, 0]] - verts[:, edges[:, 1]], axis=-1) / rest
            h = 1.0
        elif rope:
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
