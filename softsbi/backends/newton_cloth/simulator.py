"""``newton-cloth``: the :class:`NewtonCloth` simulator and its one stepping loop (single and batched).

Solver: Newton's **VBD** (vertex block descent, ``newton.solvers.SolverVBD``). Why VBD and not the
other cloth solvers Newton ships:

* it is implicit (one backward-Euler step solved by block Gauss-Seidel), so the stiff end of the
  shared parameter box (``stretch`` 1000 N/m on 3 mm-heavy vertices) stays stable at the 4 ms step
  mujoco-flex uses, where ``SolverSemiImplicit`` would need sub-millisecond steps;
* its energies have physical units that map one-to-one onto the shared parameters: a stable
  Neo-Hookean membrane with 2-D Lamé parameters (``stretch``, :func:`~.model.membrane_lame`) and a
  dihedral hinge energy (``bend``, :func:`~.model.bend_edge_stiffness`); XPBD's compliances and
  springs have no such one-to-one reading;
* it is Newton's own cloth solver (Isaac Lab's cloth tasks use it) and runs many worlds in one model.

Handles are kinematic particles (mass 0): before every step a small Warp kernel writes each handle's
target (its path shifted to start on its grasped vertex, interpolated linearly in time) into the
particle positions. Force-field effects are summed on the host at the current state and written to
``State.particle_f`` before every step. Table contact: one ground plane per world with its own
friction (:func:`~.model.build_cloth_world`).

Batching (:meth:`NewtonCloth.simulate_batch`): B parameter sets become B worlds of one model, stepped
together; world ``b`` is independent of the others (its own table, particles ``b N .. (b+1) N - 1``).

Silent failures: VBD does not raise on divergence; every recorded frame is checked for non-finite
positions (``STATUS_DIVERGED``), and the finished rollout for a vertex below the table, a vertex far
from the grasp and an over-stretched edge (``STATUS_IMPLAUSIBLE``), as on the other backends.
"""
from __future__ import annotations

import math
import time
from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.backends.common import (EffectPlan, EffectsThroughDoor, check_effects, check_scenario,
                                     cloth_material_params, grid_corners, grid_faces, size_params)
from softsbi.backends.newton_cloth.model import ClothWorld, build_cloth_world, finish_model, import_newton
from softsbi.backends.scenario_build import handle_targets
from softsbi.core.errors import ParameterError
from softsbi.core.interfaces import FORCE, OBSERVATION, Simulator, VertexContext, batch_seeds
from softsbi.core.types import STATUS_DIVERGED, STATUS_IMPLAUSIBLE, STATUS_OK, ParamSpace, Rollout, Scenario

_KERNELS: dict[str, Any] = {}

#: rollouts per ``simulate_batch`` call in a fit's worker (:attr:`Simulator.batch_size`). From the newton-throughput
#: suite on 2 CPU cores (docs/benchmarks.md): one by one 0.19-0.23 rollouts/s, batches of 8 0.5-1.0/s, of 64 1.3/s;
#: 32 per worker keeps two workers' batches near the large-batch rate within a 64-simulation phase.
BATCH_SIZE = 32


def _set_kinematic_kernel(wp: Any) -> Any:
    """The Warp kernel writing the handles' targets of one step into the particle positions (built once)."""
    if "kin" not in _KERNELS:
        @wp.kernel
        def set_kinematic(q: wp.array(dtype=wp.vec3), qd: wp.array(dtype=wp.vec3), idx: wp.array(dtype=wp.int32),
                          path: wp.array2d(dtype=wp.vec3), step: int, inv_dt: float):
            k = wp.tid()
            p = path[step, k]
            qd[idx[k]] = (p - q[idx[k]]) * inv_dt
            q[idx[k]] = p
        _KERNELS["kin"] = set_kinematic
    return _KERNELS["kin"]


class NewtonCloth(Simulator):
    """Cloth (lift, wipe, fling and cloth-grid scenario files) in Newton's VBD solver (``newton-cloth``).

    Args:
        grid: vertices per cloth side (N = grid^2). Default 9, as the other backends.
        timestep: step, s (default 4 ms, as mujoco-flex).
        iterations: VBD iterations per step. The parameter mapping is exact where the solve converges: the
            clamped strip droops like mujoco-flex's (2.05x against 2.0x the Euler-Bernoulli value at 9x9) at 80
            iterations per 4 ms step, but 4.85x at 20: an unfinished VBD solve leaves the cloth softer than its
            ``bend``. The default (5) is the speed setting (lift: about 3 s at 5, 12 s at 20 on one CPU core; its
            vertices lie 1.0 cm on average, 3.4 cm in the last frame, from a 40-iteration rollout's, 0.3 / 0.8 cm
            at 20); raise it (or shorten ``timestep``) where the bending must mean the same as on mujoco-flex.
        poisson: Poisson ratio of the membrane mapping (fixed, not inferred).
        radius: particle contact radius, m (the cloth lies this far above the table).
        damping: Rayleigh damping time, s (membrane and hinge damping = ``damping`` x stiffness).
        contact_ke: particle-table contact stiffness, N/m.
        device: Warp device, ``"cpu"`` or ``"cuda"`` (``"cuda:0"``...).
        batch_size: rollouts per :meth:`simulate_batch` call in a fit's worker (:data:`BATCH_SIZE`).

    All options are plain values, so instances pickle; Newton is imported on the first rollout
    (:func:`~.model.import_newton`), so softsbi imports and lists this plugin without it.
    """

    name = "newton-cloth"
    #: the built-in cloth scenarios; any scenario file needing only :attr:`features` runs too
    scenarios = ("lift", "wipe", "fling")
    #: square cloth grids held by any number of moving or pinned handles; no mesh cloth, rope or
    #: obstacles yet (refused in one line by :func:`~softsbi.backends.common.check_scenario`)
    features = ("cloth", "several handles", "pinned handles")
    #: every registered effect this backend supports (no effect is known by name)
    effects = EffectsThroughDoor()
    #: force fields through ``State.particle_f`` and observation transforms; no model edit is
    #: registered for newton-cloth yet
    effect_kinds = (FORCE, OBSERVATION)

    def __init__(self, grid: int = 9, timestep: float = 0.004, iterations: int = 5, poisson: float = 0.3,
                 radius: float = 0.003, damping: float = 0.001, contact_ke: float = 1000.0, device: str = "cpu",
                 batch_size: int = BATCH_SIZE):
        if int(grid) < 3:
            raise ValueError(f"grid must be >= 3 vertices per side, got {grid}")
        if not timestep > 0:
            raise ValueError(f"timestep must be > 0, got {timestep}")
        if int(iterations) < 1:
            raise ValueError(f"iterations must be >= 1, got {iterations}")
        if not 0.0 < radius < 0.05:
            raise ValueError(f"radius must lie in (0, 0.05) m, got {radius}")
        self.grid, self.timestep, self.iterations = int(grid), float(timestep), int(iterations)
        self.poisson, self.radius, self.damping = float(poisson), float(radius), float(damping)
        self.contact_ke, self.device = float(contact_ke), str(device)
        if int(batch_size) < 1:
            raise ValueError(f"batch_size must be >= 1 rollouts per call, got {batch_size}")
        self.batch_size = int(batch_size)

    def __repr__(self) -> str:
        return (f"NewtonCloth(grid={self.grid}, timestep={self.timestep}, iterations={self.iterations}, "
                f"device={self.device!r})")

    # -- parameters -------------------------------------------------------------------------
    def check_installed(self) -> None:
        """Import Newton and Warp now (:func:`~.model.import_newton`).

        Raises:
            DependencyMissing: Newton or Warp is not installed.
        """
        import_newton()

    def param_space(self, scenario: Scenario) -> ParamSpace:
        """The shared physical cloth parameters (:func:`~softsbi.backends.common.cloth_material_params`,
        the same names, units and bounds as mujoco-flex): ``bend`` [N m], ``stretch`` [N/m],
        ``friction`` [1], then ``scale`` [m], ``mass`` [kg/m^2] and ``yaw`` [deg] where the scenario's
        placement is unknown.

        Raises:
            ValueError: scenario not supported (names the missing feature).
        """
        check_scenario(self, scenario)
        return ParamSpace([*cloth_material_params(), *size_params(scenario, rope=False)])

    def full_space(self, scenario: Scenario, effects: Sequence[str] = ()) -> ParamSpace:
        """Nominal parameters plus those of ``effects``.

        Raises:
            ParameterError: an effect that is not installed or that this backend cannot apply.
        """
        return check_effects(self, effects).space(self.param_space(scenario))

    # -- simulation -------------------------------------------------------------------------
    def simulate(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = (),
                 seed: int = 0) -> Rollout:
        """Roll ``scenario`` out at ``theta`` (a batch of one, :meth:`simulate_batch`).

        Returns:
            :class:`Rollout` with ``vertices (T, grid^2, 3)`` m at ``scenario.times``, ``faces`` the grid
            triangles, ``gripper (T, 3)`` m the first moving handle's target; ``info``: ``wall_s``,
            ``steps``, ``timestep`` (s), ``corners``, ``handle_vertices``, ``batch`` (1). Divergence is
            ``status != 0`` with a ``reason``.

        Raises:
            ValueError: unsupported scenario. ParameterError: bad ``theta`` or effect.
            DependencyMissing: Newton is not installed (names ``pip install "softsbi[newton]"``).
        """
        return self.simulate_batch(scenario, [theta], effects, seed)[0]

    def simulate_batch(self, scenario: Scenario, thetas: Any, effects: Sequence[str] = (),
                       seed: int | Sequence[int] = 0) -> list[Rollout]:
        """Roll ``scenario`` out at B parameter sets in one Newton model (one world each), stepped together.

        Args:
            thetas: a sequence of B mappings, or an array ``(B, D)`` whose columns follow
                ``full_space(scenario, effects).names``.
            seed: seeds the observation transforms: B ints, one per rollout, or one int (rollout ``b`` uses
                ``seed + b``).

        Returns:
            B :class:`Rollout` as :meth:`simulate` would return each (``info["wall_s"]`` is the batch's
            wall time divided by B, ``info["batch"]`` = B).

        Raises:
            ParameterError: a theta outside the physical limits, a wrong number of columns, an empty
                batch, an unsupported effect, B seeds that do not match B thetas. ValueError: unsupported
                scenario. DependencyMissing: no Newton.
        """
        check_scenario(self, scenario)
        plan = check_effects(self, effects)
        space = plan.space(self.param_space(scenario))
        if isinstance(thetas, np.ndarray):
            arr = np.atleast_2d(np.asarray(thetas, dtype=float))
            if arr.shape[1] != len(space.names):
                raise ParameterError(f"thetas has {arr.shape[1]} columns; {self.name} on '{scenario.name}' expects "
                                     f"{len(space.names)}: {', '.join(space.names)}")
            thetas = [dict(zip(space.names, row)) for row in arr]
        thetas = [space.check(th, within="limits") for th in thetas]
        if not thetas:
            raise ParameterError("simulate_batch needs at least one theta")
        return self._rollouts(scenario, thetas, plan, batch_seeds(seed, len(thetas)))

    def _vertex_context(self, scenario: Scenario, w: ClothWorld, gravity: np.ndarray) -> VertexContext:
        n = len(w.rest)
        return VertexContext(mass=w.mass.copy(), area=np.full(n, w.spacing ** 2), x0=w.rest.copy(),
                             table_z=float(scenario.table_z), spacing=w.spacing, shape=(self.grid, self.grid),
                             grasped=tuple(w.handles), gravity=gravity)

    def _rollouts(self, scenario: Scenario, thetas: list[dict[str, float]], plan: EffectPlan,
                  seeds: list[int]) -> list[Rollout]:
        """The one stepping loop: B worlds, kinematic handles, force fields, checks, observation."""
        newton, wp = import_newton()
        t0 = time.perf_counter()
        B, N, dt = len(thetas), self.grid ** 2, self.timestep
        built = [build_cloth_world(newton, wp, scenario, th, grid=self.grid, radius=self.radius,
                                   poisson=self.poisson, damping=self.damping, contact_ke=self.contact_ke)
                 for th in thetas]
        worlds = [w for _, w in built]
        gravity = np.asarray(scenario.gravity, dtype=float)
        model = finish_model(newton, [b for b, _ in built], gravity, self.device, self.contact_ke)
        solver = newton.solvers.SolverVBD(model, iterations=self.iterations)
        s0, s1, ctl = model.state(), model.state(), model.control()
        pipe = newton.CollisionPipeline(model)
        contacts = pipe.contacts()

        times = scenario.times
        T = len(times)
        frame_steps = np.maximum(np.round(times / dt).astype(int), 0)
        S = int(frame_steps[-1])
        # handle targets: each handle's path shifted to start on its grasped vertex (pinned: held)
        targets = [handle_targets(scenario, [w.rest[v] for v in w.handles]) for w in worlds]  # B x H x (T, 3)
        first = next(i for i, h in enumerate(scenario.handles) if not h.pinned)
        kin = np.concatenate([b * N + np.asarray(w.handles) for b, w in enumerate(worlds)]).astype(np.int32)
        tg = np.stack([t for tb in targets for t in tb], axis=1)  # (T, K, 3)
        tn = (np.arange(S) + 1) * dt
        path = np.empty((max(S, 1), len(kin), 3), dtype=np.float32)
        for k in range(len(kin)):
            for c in range(3):
                path[:S, k, c] = np.interp(tn, times, tg[:, k, c])
        kernel = _set_kinematic_kernel(wp)
        kin_d = wp.array(kin, dtype=wp.int32, device=self.device)
        path_d = wp.array(path, dtype=wp.vec3, device=self.device)

        forces = None
        if plan.forces:
            fns = [plan.force_fn(th, self._vertex_context(scenario, w, gravity)) for th, w in zip(thetas, worlds)]

            def forces(t: float) -> None:
                x = s0.particle_q.numpy().reshape(B, N, 3).astype(float)
                v = s0.particle_qd.numpy().reshape(B, N, 3).astype(float)
                f = np.stack([fn(x[b], v[b], t) for b, fn in enumerate(fns)])
                s0.particle_f.assign(f.reshape(-1, 3).astype(np.float32))

        verts = np.full((B, T, N, 3), np.nan)
        verts[:, 0] = s0.particle_q.numpy().reshape(B, N, 3)
        failed: dict[int, str] = {}
        steps = 0
        for k in range(1, T):
            while steps < frame_steps[k]:
                wp.launch(kernel, dim=len(kin), device=self.device,
                          inputs=[s0.particle_q, s0.particle_qd, kin_d, path_d, steps, 1.0 / dt])
                if forces is not None:
                    s0.clear_forces()
                    forces(steps * dt)
                pipe.collide(s0, contacts)
                solver.step(s0, s1, ctl, contacts, dt)
                s0, s1 = s1, s0
                steps += 1
            q = s0.particle_q.numpy().reshape(B, N, 3)
            verts[:, k] = q
            for b in np.flatnonzero(~np.isfinite(q).all(axis=(1, 2))):
                failed.setdefault(int(b), f"non-finite vertex positions at t={times[k]:.3f} s")
            if len(failed) == B:
                break
        wall = time.perf_counter() - t0
        out = []
        for b, (th, w) in enumerate(zip(thetas, worlds)):
            grip = targets[b][first]
            v = verts[b]
            status, reason = (STATUS_DIVERGED, failed[b]) if b in failed else self._plausibility(scenario, th, v, grip)
            if status != STATUS_OK:
                v = np.nan_to_num(v, nan=0.0, posinf=0.0, neginf=0.0)
            info = {"wall_s": wall / B, "steps": steps, "backend": self.name, "grid": self.grid, "timestep": dt,
                    "iterations": self.iterations, "device": self.device, "batch": B,
                    "effects": [e.name for e in plan.effects],
                    "handle_vertices": list(w.handles), "corners": grid_corners(self.grid)}
            ro = Rollout(times=times.copy(), gripper=grip.copy(), vertices=v, faces=grid_faces(self.grid),
                         status=status, reason=reason, info=info)
            out.append(plan.observe(ro, th, seeds[b]))
        return out

    def _plausibility(self, scenario: Scenario, theta: Mapping[str, float], verts: np.ndarray,
                      grip: np.ndarray) -> tuple[int, str]:
        """``(status, reason)`` of a finished rollout ``verts (T, N, 3)`` m: a vertex more than 2 cm below the
        table, farther from the grasp than twice the cloth diagonal, or a grid edge stretched past 3x its rest
        length is ``STATUS_IMPLAUSIBLE``."""
        L = float(theta["scale"])
        tz = float(scenario.table_z)
        zmin = float(verts[..., 2].min())
        if zmin < tz - 0.02:
            return STATUS_IMPLAUSIBLE, f"a vertex fell {100 * (tz - zmin):.1f} cm below the table"
        reach = float(np.linalg.norm(verts - grip[:, None, :], axis=-1).max())
        if reach > 2.0 * L * math.sqrt(2.0):
            return STATUS_IMPLAUSIBLE, (f"a vertex is {reach:.2f} m from the grasp point, more than twice the "
                                        f"cloth diagonal ({L * math.sqrt(2):.2f} m): torn or exploded")
        g = self.grid
        last = verts[-1].reshape(g, g, 3)
        edge = max(np.linalg.norm(np.diff(last, axis=0), axis=-1).max(),
                   np.linalg.norm(np.diff(last, axis=1), axis=-1).max())
        if edge > 3.0 * L / (g - 1):
            return STATUS_IMPLAUSIBLE, f"an edge is stretched to {edge * (g - 1) / L:.1f}x its rest length"
        return STATUS_OK, ""

