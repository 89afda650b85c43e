"""``mujoco-flex``: the :class:`MujocoFlex` simulator and its one stepping loop.

One XML per rollout (:mod:`.model`), compiled with MuJoCo 4.0. The grasp is a mocap body that
follows ``scenario.gripper`` interpolated linearly in time between frames, offset by a constant
so that it starts exactly at the grasped vertex (the vertex lies ``radius`` above the table).

Divergence: MuJoCo resets the state silently when accelerations blow up; we check
``d.warning[mjWARN_BADQACC]``, NaN/inf, vertices outside a plausible box or far below the table,
and an over-stretched grasped edge, and return ``STATUS_DIVERGED`` / ``STATUS_IMPLAUSIBLE`` with
a reason instead of raising.

MuJoCo's own warnings (printed on the terminal and appended to ``MUJOCO_LOG.TXT`` in the working folder by default)
are kept instead (:func:`kept_warnings`): the rollout's ``info[INFO_ENGINE_WARNINGS]`` holds their text, which the
commands count and tell once per batch (:class:`~softsbi.workflows.reporting.SimulationIssues`).

Rendering: :meth:`~softsbi.core.interfaces.Simulator.simulate_images` (the base class template)
runs :meth:`MujocoFlex._rollout` with :class:`~.render.MjFrameRenderer`. Simulation loads no
OpenGL (:mod:`.gl`).
"""
from __future__ import annotations

import contextlib
import math
import time
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from softsbi.backends.common import (EffectPlan, EffectsThroughDoor, check_effects, check_scenario, grid_corners,
                                     grid_faces, size_params)
from softsbi.backends.scenario_build import FEATURES, handle_targets, mesh_edges
from softsbi.backends.mujoco_flex.gl import import_mujoco
from softsbi.backends.mujoco_flex.model import (apply_anisotropy, build_rope_spec, build_spec, check_rope_theta,
                                                rope_param_space, spec_to_xml)
from softsbi.backends.mujoco_flex.render import MjFrameRenderer, MjState
from softsbi.core.interfaces import FORCE, MODEL_EDIT, OBSERVATION, Simulator, VertexContext
from softsbi.core.errors import ParameterError
from softsbi.core.types import (INFO_ENGINE_WARNINGS, STATUS_DIVERGED, STATUS_IMPLAUSIBLE, STATUS_OK, Param, ParamSpace,
                                Rollout, Scenario)


@contextlib.contextmanager
def kept_warnings(mujoco: Any) -> Iterator[list[str]]:
    """Inside the block, MuJoCo's warnings are appended to the yielded list instead of being printed (and written to
    ``MUJOCO_LOG.TXT``); the previous handler is restored after it."""
    said: list[str] = []
    before = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(said.append)
    try:
        yield said
    finally:
        mujoco.set_mju_user_warning(before)


class MujocoFlex(Simulator):
    """Cloth lift in MuJoCo 4.0 flex (``mujoco-flex``).

    Args:
        grid: vertices per cloth side (N = grid^2 vertices). Default 9 (~0.2 s per 1 s lift).
        timestep: MuJoCo step, s.
        solver: MuJoCo constraint solver (``"CG"``; ``"Newton"`` is ~2x slower here).
        integrator: ``"discrete"`` (flex elasticity rejects the implicit ones) or ``"Euler"``.
        poisson: Poisson ratio of the plate mapping (fixed, not inferred).
        radius: flex collision radius, m (the cloth lies this far above the table).
        damping: flex elasticity damping (Rayleigh, s).
        iterations: solver iterations.
        overrides: raw MuJoCo values (``young``, ``thickness``, ``timestep``, ``damping`` or any
            ``<option>`` attribute) replacing the derived ones, *bypassing the bounds*; for tests.

    All options are plain values, so instances pickle and can be built inside worker processes.
    """

    name = "mujoco-flex"
    #: the built-in scenarios; any scenario file needing only :attr:`features` runs too
    scenarios = ("lift", "wipe", "winding", "fling")
    #: engine features (:data:`~softsbi.backends.scenario_build.FEATURES`): grid or mesh cloth (flexcomp
    #: grid / direct), rope, any number of handles (mocap bodies + connect), box and cylinder obstacles
    features = FEATURES
    #: every registered effect this backend supports (no effect is known by name)
    effects = EffectsThroughDoor()
    effect_kinds = (FORCE, MODEL_EDIT, OBSERVATION)

    def __init__(self, grid: int = 9, timestep: float = 0.004, solver: str = "CG", integrator: str = "discrete",
                 poisson: float = 0.3, radius: float = 0.003, damping: float = 0.001, iterations: int = 50,
                 overrides: Mapping[str, float] | None = None, rope_nodes: int = 24):
        if int(grid) < 3:
            raise ValueError(f"grid must be >= 3 vertices per side, got {grid}")
        if not timestep > 0:
            raise ValueError(f"timestep must be > 0, got {timestep}")
        self.grid, self.timestep, self.solver, self.integrator = int(grid), float(timestep), solver, integrator
        self.poisson, self.radius, self.damping, self.iterations = float(poisson), float(radius), float(damping), int(iterations)
        self.overrides = dict(overrides or {})
        if int(rope_nodes) < 3:
            raise ValueError(f"rope_nodes must be >= 3, got {rope_nodes}")
        self.rope_nodes = int(rope_nodes)

    def __repr__(self) -> str:
        return (f"MujocoFlex(grid={self.grid}, timestep={self.timestep}, solver={self.solver!r}, "
                f"integrator={self.integrator!r})")

    # -- parameters -------------------------------------------------------------------------
    def param_space(self, scenario: Scenario) -> ParamSpace:
        """Nominal parameters (SI units; the mapping to MuJoCo values is in :mod:`.model`).

        Cloth (lift, wipe, fling): ``bend`` [N m] log, ``stretch`` [N/m] log, ``friction`` [1],
        ``scale`` [m], ``mass`` [kg/m^2], and ``yaw`` [deg] when the scenario's placement is unknown
        (``object["yaw_bounds"]``). Rope (wind): :func:`~.model.rope_param_space` (``young`` [Pa], ``friction``, ``scale``, ``mass``). Bounds were swept
        corner by corner for stability at the default options.

        Raises:
            ValueError: scenario not supported (names the valid ones).
        """
        check_scenario(self, scenario)
        if scenario.object.get("kind") == "rope":
            return rope_param_space(scenario)
        return ParamSpace([
            Param("bend", 1e-6, 1e-3, "N*m", log=True,
                  description="bending rigidity D = E t^3 / (12 (1 - nu^2))"),
            Param("stretch", 5.0, 1000.0, "N/m", log=True, description="membrane stretch stiffness k = E t"),
            Param("friction", 0.05, 1.5, "1", description="cloth-table sliding friction coefficient"),
            *size_params(scenario, rope=False),
        ])

    def full_space(self, scenario: Scenario, effects: Sequence[str] = ()) -> ParamSpace:
        """Nominal parameters plus those of ``effects``.

        Raises:
            ParameterError: an effect that is not installed or that this backend cannot apply.
        """
        return check_effects(self, effects).space(self.param_space(scenario))

    def build_xml(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = ()) -> str:
        """MJCF string of the lift at ``theta`` (no validation; use :meth:`simulate`). An anisotropic membrane
        (``spec["anisotropy"]``, :func:`~.model.apply_anisotropy`) is applied to the compiled model, so it is not in
        this text."""
        return spec_to_xml(self.build_spec(scenario, theta, effects))

    def build_spec(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = (),
                   plan: EffectPlan | None = None) -> dict[str, Any]:
        """The model dict of :func:`~.model.build_spec` (cloth) or :func:`~.model.build_rope_spec`
        (wind) with this instance's options and the effects' model edits applied (no validation of
        ``theta``). The edits get ``ctx = {"grid", "spacing" (m), "vertex_mass" (kg), "timestep" (s)}``."""
        if scenario.object.get("kind") == "rope":
            spec = build_rope_spec(scenario, theta, nodes=self.rope_nodes, timestep=self.timestep,
                                   solver=self.solver, integrator=self.integrator, poisson=self.poisson,
                                   damping=self.damping, iterations=self.iterations, overrides=self.overrides)
        else:
            spec = build_spec(scenario, theta, grid=self.grid, timestep=self.timestep, solver=self.solver,
                              integrator=self.integrator, poisson=self.poisson, radius=self.radius,
                              damping=self.damping, iterations=self.iterations, overrides=self.overrides)
        plan = plan if plan is not None else check_effects(self, effects)
        if plan.edits:
            fc = spec["flexcomp"]
            lay = spec.get("mesh_layout")  # a mesh cloth (flexcomp direct) has no grid spacing/count
            n = lay["n"] if lay else int(np.prod(fc["count"]))
            ctx = {"grid": self.grid, "spacing": lay["spacing"] if lay else float(fc["spacing"][0]),
                   "vertex_mass": float(fc["mass"]) / n, "timestep": float(spec["option"]["timestep"])}
            plan.edit(spec, theta, ctx)
        return spec

    # -- simulation -------------------------------------------------------------------------
    def simulate(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = (),
                 seed: int = 0) -> Rollout:
        """Roll ``scenario`` out; the physics is deterministic (``seed`` seeds only the observation
        transforms of sensor effects).

        Returns:
            :class:`Rollout` with ``vertices (T, N, 3)`` m at ``scenario.times``: cloth
            ``N = grid^2`` with ``faces`` the grid triangles ``(2 (grid-1)^2, 3)`` int64; rope
            ``N = rope_nodes`` with ``faces (0, 3)``. ``gripper (T, 3)`` m is the actual grasp target
            (mocap) at those times. ``info``: ``wall_s`` (s), ``steps``, ``timestep`` (s), ``time_scale`` (the
            motion's, set by a model edit: the paths took ``time_scale`` x the scenario's duration and frame ``k``
            was recorded at ``time_scale * times[k]`` of physical time; 1.0 nominal), ``young``
            (Pa), ``thickness`` (m), and for cloth ``corners`` (4 vertex indices,
            :func:`~softsbi.backends.common.grid_corners` order). Divergence is returned as
            ``status != 0`` with a ``reason``, its vertices zeroed where they were not finite.

        Raises:
            ValueError: unknown scenario (names the valid ones).
            ParameterError: unknown/missing parameter, a value outside its physical limits
                (``ParamSpace.check(within="limits")``: a prior widened with ``--bounds`` is simulated),
                unsupported effect, a rope's old ``bend`` (now ``young``).
        """
        return self._rollout(scenario, theta, effects, seed)

    def _frame_renderer(self, scenario: Scenario, camera: Any, style: Any) -> MjFrameRenderer:
        """The MuJoCo frame renderer of :meth:`simulate_images` (OpenGL off-screen; the GL context
        opens on the first frame, ``RenderingUnavailable`` when no back-end works)."""
        return MjFrameRenderer(scenario, camera, style)

    def _rollout(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = (),
                 seed: int = 0, frames: MjFrameRenderer | None = None) -> Rollout:
        """The one stepping loop of :meth:`simulate` and :meth:`simulate_images` (``seed`` seeds the
        effects' observation transforms). Effects act through their doors (:class:`~.common.EffectPlan`):
        model edits on the spec before compiling, force fields written to ``xfrc_applied`` of the
        vertex bodies before every step, observation transforms on the finished rollout.

        With ``frames``: ``frames.edit(spec)`` may add render-only elements to the model dict
        before compiling, and ``frames(k, MjState(m, d))`` is called after frame ``k`` is recorded
        (``k = 0`` after ``mj_forward``), with the grasp target in ``d.mocap_pos[0]``; not called
        after a failure.
        """
        mujoco = import_mujoco()

        check_scenario(self, scenario)
        plan = check_effects(self, effects)
        if scenario.object.get("kind") == "rope":
            check_rope_theta(theta)
        theta = plan.space(self.param_space(scenario)).check(theta, within="limits")
        t0 = time.perf_counter()
        spec = self.build_spec(scenario, theta, effects, plan=plan)
        if frames is not None:
            frames.edit(spec)
        with kept_warnings(mujoco) as said:
            ro = self._step(mujoco, spec, scenario, theta, list(effects), plan, frames, t0)
        ro.info[INFO_ENGINE_WARNINGS] = "; ".join(dict.fromkeys(said))
        return plan.observe(ro, theta, seed)

    def _step(self, mujoco: Any, spec: dict[str, Any], scenario: Scenario, theta: Mapping[str, float],
              effects: list[str], plan: EffectPlan, frames: MjFrameRenderer | None, t0: float) -> Rollout:
        """:meth:`_rollout`'s model compiled from ``spec`` and stepped through the scenario (before the
        observation transforms); ``t0``: when the rollout began (``perf_counter``)."""
        m = mujoco.MjModel.from_xml_string(spec_to_xml(spec))
        d = mujoco.MjData(m)
        mujoco.mj_forward(m, d)
        if spec.get("anisotropy"):  # what MJCF cannot say, on the compiled model (at the rest state)
            apply_anisotropy(m, d, spec)
            mujoco.mj_forward(m, d)
        n = int(m.flex_vertnum[0])  # grid^2 (cloth) or rope_nodes (rope)
        times = scenario.times
        T = len(times)
        # each handle's path shifted by a constant so it starts on its grasped vertex (which lies on the
        # table); pinned handles hold their vertex where it rests
        mocaps = spec["handle_mocaps"]
        targets = handle_targets(scenario, [d.mocap_pos[j].copy() for j in mocaps])
        target = targets[next(i for i, j in enumerate(mocaps) if j == 0)]
        others = [(j, tg) for j, tg in zip(mocaps, targets) if j != 0]
        verts = np.full((T, n, 3), np.nan)
        grip = np.zeros((T, 3))
        verts[0] = d.flexvert_xpos.reshape(-1, 3)[:n]
        grip[0] = target[0]
        if frames is not None:
            frames(0, MjState(m, d))
        dt = m.opt.timestep
        push = self._force_applier(m, d, plan, theta, scenario, spec)
        status, reason = STATUS_OK, ""
        steps = 0
        # the motion's time scale s (an effect's model edit; 1 nominal): the paths are executed over s times the
        # scenario's duration (physical time s * t for the scenario's time t) and frame k is recorded at s * t_k,
        # the same fraction of the motion; the rollout keeps the scenario's times (the recording's stamps)
        scale = float(spec.get("motion", {}).get("time_scale", 1.0))
        if not scale > 0:
            raise ParameterError(f"the motion's time scale must be > 0, got {scale}")
        # step counts are fixed in advance: after a divergence MuJoCo resets d.time to 0, so a
        # loop on d.time would never end
        frame_steps = np.maximum(np.round(times * scale / dt).astype(int), 0)
        warn = d.warning[mujoco.mjtWarning.mjWARN_BADQACC]
        for k in range(1, T):
            while steps < frame_steps[k]:
                tn = (steps + 1) * dt / scale
                d.mocap_pos[0] = [np.interp(tn, times, target[:, c]) for c in range(3)]
                for j, tg in others:
                    d.mocap_pos[j] = [np.interp(tn, times, tg[:, c]) for c in range(3)]
                if push is not None:
                    push(steps * dt)
                mujoco.mj_step(m, d)
                steps += 1
                if warn.number > 0:
                    break
            if warn.number > 0:
                status, reason = STATUS_DIVERGED, (f"MuJoCo reported bad accelerations (mjWARN_BADQACC) at "
                                                   f"t={steps * dt:.3f} s and reset the state")
                break
            v = d.flexvert_xpos.reshape(-1, 3)[:n]
            if not np.all(np.isfinite(v)):
                status, reason = STATUS_DIVERGED, f"non-finite vertex positions at t={times[k]:.3f} s"
                break
            verts[k] = v
            grip[k] = d.mocap_pos[0]
            if frames is not None:
                frames(k, MjState(m, d))
        wall = time.perf_counter() - t0
        if status == STATUS_OK:
            status, reason = self._plausibility(scenario, theta, verts, grip)
        if status != STATUS_OK:
            verts = np.nan_to_num(verts, nan=0.0, posinf=0.0, neginf=0.0)
        rope = scenario.object.get("kind") == "rope"
        mesh = "mesh" in scenario.object
        faces = (np.zeros((0, 3), dtype=np.int64) if rope else
                 np.asarray(scenario.object["mesh"]["faces"], dtype=np.int64) if mesh else grid_faces(self.grid))
        info = {"wall_s": wall, "steps": steps, "backend": self.name, "grid": self.grid,
                "timestep": dt, "time_scale": scale, "young": spec["elasticity"]["young"],
                "thickness": spec["elasticity"]["thickness"], "effects": list(effects),
                "handle_vertices": list(spec["handle_vertices"])}
        if not rope and not mesh:
            info["corners"] = grid_corners(self.grid)
        return Rollout(times=times.copy(), gripper=grip, vertices=verts, faces=faces,
                       status=status, reason=reason, info=info)

    @staticmethod
    def _force_applier(m: Any, d: Any, plan: EffectPlan, theta: Mapping[str, float], scenario: Scenario,
                       spec: Mapping[str, Any]):
        """``push(t)``: writes the effects' summed force field at the current state into
        ``d.xfrc_applied`` of the flex vertex bodies (world frame, at the vertex), or None without
        force fields.

        The state is read from ``qpos``/``qvel`` (not ``flexvert_xpos``/``cvel``, which ``mj_step``
        leaves one integration behind): each vertex body moves on 3 slide joints, so
        ``x = x(q0) + A (q - q0)`` and ``v = A qdot`` with ``A`` the joint axes in the world frame.
        """
        n = int(m.flex_vertnum[0])
        ids = np.asarray(m.flex_vertbodyid[:n], dtype=int)
        vctx = MujocoFlex._vertex_context(m, d, ids, scenario, spec)
        total = plan.force_fn(theta, vctx)
        if total is None:
            return None
        if not np.all(m.body_jntnum[ids] == 3) or not np.all(m.jnt_type[m.body_jntadr[ids]] == 2):
            raise RuntimeError("mujoco-flex force fields expect flex vertex bodies with 3 slide joints each")
        jnt = m.body_jntadr[ids][:, None] + np.arange(3)[None, :]          # (n, 3) joint ids
        axes = np.asarray(d.xaxis)[jnt]                                     # (n, 3 joints, 3 xyz)
        qadr = m.jnt_qposadr[jnt]
        vadr = m.jnt_dofadr[jnt]
        q0 = d.qpos[qadr].copy()
        x0 = d.xpos[ids].copy()
        mocaps = list(spec["handle_mocaps"])
        if np.allclose(axes, np.eye(3)[None]):  # flexcomp's vertex joints are world-aligned: skip the rotation
            def push(t: float) -> None:
                vctx.handles[:] = d.mocap_pos[mocaps]
                d.xfrc_applied[ids, :3] = total(x0 + (d.qpos[qadr] - q0), d.qvel[vadr], t)
        else:
            def push(t: float) -> None:
                vctx.handles[:] = d.mocap_pos[mocaps]
                x = x0 + np.einsum("njc,nj->nc", axes, d.qpos[qadr] - q0)
                v = np.einsum("njc,nj->nc", axes, d.qvel[vadr])
                d.xfrc_applied[ids, :3] = total(x, v, t)
        return push

    @staticmethod
    def _vertex_context(m: Any, d: Any, ids: np.ndarray, scenario: Scenario, spec: Mapping[str, Any]) -> VertexContext:
        """The :class:`~softsbi.core.interfaces.VertexContext` of the compiled model (masses from MuJoCo)."""
        fc = spec["flexcomp"]
        lay = spec.get("mesh_layout")  # a mesh cloth: mean edge length, per-vertex patch areas, layout (N,)
        h = lay["spacing"] if lay else float(fc["spacing"][0])
        rope = int(fc["dim"]) == 1
        n = len(ids)
        area = (np.asarray(lay["area"], float) if lay else
                np.full(n, h * 2.0 * float(fc["radius"]) if rope else h * h))
        shape = (n,) if rope or lay else (int(fc["count"][0]), int(fc["count"][1]))
        mocaps = list(spec["handle_mocaps"])
        names = tuple(h.name for h in scenario.handles) if len(scenario.handles) == len(mocaps) else ()
        return VertexContext(mass=np.asarray(m.body_mass[ids], dtype=float).copy(), area=area,
                             x0=np.asarray(d.xpos[ids], dtype=float).copy(), table_z=float(scenario.table_z),
                             spacing=h, shape=shape, grasped=tuple(int(v) for v in spec.get("handle_vertices", (0,))),
                             gravity=np.asarray(m.opt.gravity, float).copy(),
                             handles=np.asarray(d.mocap_pos[mocaps], dtype=float).copy(), handle_names=names,
                             corners=() if len(shape) != 2 else tuple(grid_corners(shape[0])))

    def _plausibility(self, scenario: Scenario, theta: Mapping[str, float], verts: np.ndarray,
                      grip: np.ndarray) -> tuple[int, str]:
        L = float(theta["scale"])
        tz = float(scenario.table_z)
        zmin = float(verts[..., 2].min())
        if zmin < tz - 0.02:
            return STATUS_IMPLAUSIBLE, f"a vertex fell {100 * (tz - zmin):.1f} cm below the table"
        reach = np.linalg.norm(verts - grip[:, None, :], axis=-1).max()
        if reach > 2.0 * L * math.sqrt(2.0):
            return STATUS_IMPLAUSIBLE, (f"a vertex is {reach:.2f} m from the grasp point, more than twice the "
                                        f"cloth diagonal ({L * math.sqrt(2):.2f} m): torn or exploded")
        if scenario.object.get("kind") == "rope":
            h = L / (verts.shape[1] - 1)
            edge = np.linalg.norm(np.diff(verts[-1], axis=0), axis=-1).max()
            if edge > 3.0 * h:
                return STATUS_IMPLAUSIBLE, f"a rope segment is stretched to {edge / h:.1f}x its rest length"
            return STATUS_OK, ""
        if "mesh" in scenario.object:
            e = mesh_edges(np.asarray(scenario.object["mesh"]["faces"], dtype=np.int64))
            rest = np.linalg.norm(verts[0, e[:, 0]] - verts[0, e[:, 1]], axis=-1)
            ratio = (np.linalg.norm(verts[-1, e[:, 0]] - verts[-1, e[:, 1]], axis=-1) / rest).max()
            if ratio > 3.0:
                return STATUS_IMPLAUSIBLE, f"an edge is stretched to {ratio:.1f}x its rest length"
            return STATUS_OK, ""
        g = self.grid
        first_row = verts[-1].reshape(g, g, 3)
        edge = np.linalg.norm(np.diff(first_row, axis=0), axis=-1).max()
        h = L / (g - 1)
        if edge > 3.0 * h:
            return STATUS_IMPLAUSIBLE, f"an edge is stretched to {edge / h:.1f}x its rest length"
        return STATUS_OK, ""

