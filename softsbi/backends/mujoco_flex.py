"""``mujoco-flex``: the cloth lift simulated with MuJoCo 4.0 flex (``flexcomp`` grid, 2-D shell).

Model (one XML per call, compiled in ~10 ms; see :func:`build_spec` / :func:`spec_to_xml`):

* cloth: ``<flexcomp type="grid" dim="2">`` of ``grid x grid`` vertices, side ``scale`` m, total
  mass ``mass * scale^2`` kg, with ``<elasticity elastic2d="both">`` (membrane + bending; MuJoCo
  docs, XML reference *flexcomp/elasticity*). MuJoCo 4.0 removed ``<composite>``; flex
  elasticity rejects the implicit integrators, hence ``integrator="discrete"`` by default.
* grasp: a mocap body ``grip`` and ``<equality><connect body1="cloth_<corner>" body2="grip">``
  (mocap attachments to an elastic flex are rejected by MuJoCo 4.0). The mocap follows
  ``scenario.gripper`` interpolated linearly in time between frames, offset by a constant so that
  it starts exactly at the grasped vertex (the vertex lies ``radius`` above the table).
* table: a plane at ``scenario.table_z``; the cloth lies flat on it at t = 0 with the grasped
  corner at ``object["corner"]`` and its diagonal along ``object["direction"]``.

Physical parameters -> MuJoCo (plate theory, Kirchhoff-Love; ``nu`` = ``poisson``, fixed)::

    stretch  k = E t                      [N/m]   membrane stiffness
    bend     D = E t^3 / (12 (1 - nu^2))  [N m]   bending rigidity
    =>  thickness t = sqrt(12 (1 - nu^2) D / k),   young E = k / t

``friction`` is the sliding friction coefficient of the cloth-table contact (both the table geom
and the flex contact get it; MuJoCo combines by maximum). ``mass`` is the areal density in
kg/m^2 (the ten fabrics measured by Wang et al. 2011, shipped in ``shared/data/fabric_materials``,
range 0.113-0.324 kg/m^2). ``scale`` is the cloth side in metres.

Divergence: MuJoCo resets the state silently when accelerations blow up; we check
``d.warning[mjWARN_BADQACC]``, NaN/inf, vertices outside a plausible box or far below the table,
and an over-stretched grasped edge, and return ``STATUS_DIVERGED`` / ``STATUS_IMPLAUSIBLE`` with
a reason instead of raising.

Extending (effects): :func:`build_spec` returns a plain nested dict; an effect edits it before
:func:`spec_to_xml`, e.g. ``spec["option"].update(density=1.2, viscosity=1.8e-5, wind="1 0 0")``
or ``spec["flexcomp"]["inertiabox"] = h``; see :meth:`MujocoFlex._apply_effects`.
"""
from __future__ import annotations

import math
import time
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.errors import ParameterError
from ..core.interfaces import Simulator
from ..core.types import (STATUS_DIVERGED, STATUS_IMPLAUSIBLE, STATUS_OK, Param, ParamSpace, Rollout,
                          Scenario)
from ..plugins.hookspecs import hookimpl

#: default areal density (kg/m^2) used when ``mass`` is not sampled: camel-ponte-roma, DiffCloud's start
DEFAULT_AREAL_DENSITY = 0.284


def _fmt(v: Any) -> str:
    if isinstance(v, (list, tuple, np.ndarray)):
        return " ".join(_fmt(x) for x in (v.ravel().tolist() if isinstance(v, np.ndarray) else v))
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    return str(v)


def plate_mapping(bend: float, stretch: float, poisson: float) -> tuple[float, float]:
    """Map bending rigidity ``D`` (N m) and stretch stiffness ``k`` (N/m) to MuJoCo ``(young, thickness)``.

    ``t = sqrt(12 (1 - nu^2) D / k)`` (m), ``E = k / t`` (Pa), so that ``E t = k`` and
    ``E t^3 / (12 (1 - nu^2)) = D``.
    """
    if bend <= 0 or stretch <= 0:
        raise ParameterError(f"bend and stretch must be > 0 (got {bend}, {stretch})")
    t = math.sqrt(12.0 * (1.0 - poisson ** 2) * bend / stretch)
    return stretch / t, t


def grid_faces(n: int) -> np.ndarray:
    """Triangles ``(2 (n-1)^2, 3)`` int64 of an ``n x n`` x-major vertex grid (index ``i * n + j``)."""
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            f.append((a, b, c))
            f.append((a, c, d))
    return np.asarray(f, dtype=np.int64).reshape(-1, 3)


def build_spec(scenario: Scenario, theta: Mapping[str, float], *, grid: int, timestep: float, solver: str,
               integrator: str, poisson: float, radius: float, damping: float, iterations: int,
               overrides: Mapping[str, float] | None = None) -> dict[str, Any]:
    """The model as a nested dict (``option``, ``flexcomp``, ``elasticity``, ``contact``, ``table``,
    ``grip``, ``corner_body``); units SI. ``overrides`` replaces derived MuJoCo values
    (``young``, ``thickness``, ``timestep``, ...) bypassing the parameter bounds (testing only)."""
    ov = dict(overrides or {})
    timestep = float(ov.pop("timestep", timestep))
    obj = scenario.object
    L = float(theta["scale"])
    rho = float(theta.get("mass", DEFAULT_AREAL_DENSITY))
    young, thick = plate_mapping(float(theta["bend"]), float(theta["stretch"]), poisson)
    young = float(ov.pop("young", young))
    thick = float(ov.pop("thickness", thick))
    d = np.asarray(obj.get("direction", (0.0, -1.0)), dtype=float)
    d = d / np.linalg.norm(d)
    corner = np.asarray(obj.get("corner", scenario.gripper[0, :2]), dtype=float)
    # vertex 0 of the grid sits at local (-L/2, -L/2); the local diagonal (1, 1)/sqrt2 must map to d
    phi = math.degrees(math.atan2(d[1], d[0])) - 45.0
    centre = corner + d * L / math.sqrt(2.0)
    z0 = float(scenario.table_z) + radius
    h = L / (grid - 1)
    fric = float(theta["friction"])
    spec = {
        "option": {"timestep": timestep, "solver": solver, "integrator": integrator,
                   "iterations": iterations, "gravity": [0.0, 0.0, -9.81]},
        "table": {"name": "table", "type": "plane", "size": [2.0, 2.0, 0.01],
                  "pos": [float(centre[0]), float(centre[1]), float(scenario.table_z)],
                  "friction": [fric, 0.005, 0.0001], "condim": 3},
        "grip": {"name": "grip", "mocap": "true", "pos": [float(corner[0]), float(corner[1]), z0]},
        "flexcomp": {"name": "cloth", "type": "grid", "dim": 2, "count": [grid, grid, 1],
                     "spacing": [h, h, h], "pos": [float(centre[0]), float(centre[1]), z0],
                     "euler": [0.0, 0.0, phi], "radius": radius, "mass": rho * L * L},
        "contact": {"condim": 3, "friction": [fric, 0.005, 0.0001], "selfcollide": "none",
                    "solref": [0.004, 1.0]},
        "edge": {"equality": "false"},
        "elasticity": {"young": young, "poisson": poisson, "thickness": thick,
                       "damping": float(ov.pop("damping", damping)), "elastic2d": "both"},
        "corner_body": "cloth_0",
        # stiff grasp: solref time constant at twice the step (MuJoCo's minimum for stability)
        "connect": {"body1": "cloth_0", "body2": "grip", "anchor": [0.0, 0.0, 0.0],
                    "solref": [2.0 * float(timestep), 0.4], "solimp": [0.99, 0.999, 0.001, 0.5, 2.0]},
    }
    for k, v in ov.items():  # remaining overrides go to option
        spec["option"][k] = v
    return spec


def rope_param_space() -> ParamSpace:
    """Parameters of the rope (wind) scenario in MuJoCo units: ``bend`` = ``young`` of the 1-D flex
    elasticity [Pa] (log 1e5-3e7; the rope is inextensible through ``<edge equality="true"/>``, so
    there is no ``stretch``), ``friction`` [1] 0.1-1.0, ``scale`` = rope length [m] 0.3-0.5,
    ``mass`` = linear density [kg/m] 0.01-0.05."""
    return ParamSpace([
        Param("bend", 1e5, 3e7, "Pa", log=True,
              description="MuJoCo young of the 1-D flex (rope bending; edges are inextensible)"),
        Param("friction", 0.1, 1.0, "1", description="rope-table and rope-spool friction coefficient"),
        Param("scale", 0.30, 0.50, "m", description="rope length"),
        Param("mass", 0.01, 0.05, "kg/m", description="linear density of the rope"),
    ])


def build_rope_spec(scenario: Scenario, theta: Mapping[str, float], *, nodes: int, timestep: float, solver: str,
                    integrator: str, poisson: float, damping: float, iterations: int,
                    overrides: Mapping[str, float] | None = None) -> dict[str, Any]:
    """Model dict of the rope (``wind``) scenario, same keys as :func:`build_spec` plus ``geoms``
    (the spool). The rope is a 1-D ``flexcomp`` grid of ``nodes`` vertices with
    ``<edge equality="true"/>`` (MuJoCo 4.0: a 1-D flex explodes without it, shared/MEASURED.md) and
    ``<elasticity young=bend>``; vertex 0 (body ``rope_0``) is grasped at ``object["start"]`` and the
    rope lies along ``object["direction"]``. The spool is a fixed vertical cylinder geom."""
    ov = dict(overrides or {})
    timestep = float(ov.pop("timestep", timestep))
    obj = scenario.object
    L = float(theta["scale"])
    r = float(obj.get("radius", 0.004))
    e = np.asarray(obj.get("direction", (0.0, -1.0)), dtype=float)
    e = e / np.linalg.norm(e)
    start = np.asarray(obj.get("start", scenario.gripper[0, :2]), dtype=float)
    centre = start + e * L / 2.0
    z0 = float(scenario.table_z) + r
    h = L / (nodes - 1)
    fric = float(theta["friction"])
    spec: dict[str, Any] = {
        "option": {"timestep": timestep, "solver": solver, "integrator": integrator,
                   "iterations": iterations, "gravity": [0.0, 0.0, -9.81]},
        "table": {"name": "table", "type": "plane", "size": [2.0, 2.0, 0.01],
                  "pos": [0.0, 0.0, float(scenario.table_z)], "friction": [fric, 0.005, 0.0001], "condim": 3},
        "geoms": [],
        "grip": {"name": "grip", "mocap": "true", "pos": [float(start[0]), float(start[1]), z0]},
        "flexcomp": {"name": "rope", "type": "grid", "dim": 1, "count": [nodes, 1, 1], "spacing": [h, h, h],
                     "pos": [float(centre[0]), float(centre[1]), z0],
                     "euler": [0.0, 0.0, math.degrees(math.atan2(e[1], e[0]))], "radius": r,
                     "mass": float(theta["mass"]) * L},
        "contact": {"condim": 3, "friction": [fric, 0.005, 0.0001], "selfcollide": "none", "solref": [0.004, 1.0]},
        "edge": {"equality": "true"},
        "elasticity": {"young": float(ov.pop("young", theta["bend"])), "poisson": poisson,
                       "thickness": float(ov.pop("thickness", 2.0 * r)), "damping": float(ov.pop("damping", damping))},
        "corner_body": "rope_0",
        "connect": {"body1": "rope_0", "body2": "grip", "anchor": [0.0, 0.0, 0.0],
                    "solref": [2.0 * float(timestep), 0.4], "solimp": [0.99, 0.999, 0.001, 0.5, 2.0]},
    }
    sp = obj.get("spool")
    if sp:
        spec["geoms"].append({"name": "spool", "type": "cylinder", "size": [float(sp["radius"]), float(sp["height"]) / 2],
                              "pos": [float(sp["centre"][0]), float(sp["centre"][1]),
                                      float(scenario.table_z) + float(sp["height"]) / 2],
                              "friction": [fric, 0.005, 0.0001], "condim": 3})
    for k, v in ov.items():
        spec["option"][k] = v
    return spec


def spec_to_xml(spec: Mapping[str, Any]) -> str:
    """Serialise :func:`build_spec`'s dict to an MJCF string."""
    def attrs(d: Mapping[str, Any]) -> str:
        return " ".join(f'{k}="{_fmt(v)}"' for k, v in d.items())
    fc = spec["flexcomp"]
    return f"""<mujoco model="softsbi_lift">
  <compiler autolimits="true"/>
  <option {attrs(spec["option"])}/>
  <worldbody>
    <geom {attrs(spec["table"])}/>
    {"".join(f"<geom {attrs(g)}/>" for g in spec.get("geoms", []))}
    <body {attrs(spec["grip"])}/>
    <flexcomp {attrs(fc)}>
      <contact {attrs(spec["contact"])}/>
      <edge {attrs(spec["edge"])}/>
      <elasticity {attrs(spec["elasticity"])}/>
    </flexcomp>
  </worldbody>
  <equality>
    <connect {attrs(spec["connect"])}/>
  </equality>
</mujoco>
"""


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
    scenarios = ("lift", "wipe", "wind", "fling")
    effects: tuple[str, ...] = ("air-drag", "wind", "extra-damping", "grip-compliance")

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
        """Nominal parameters of the lift (SI units, see the module docstring for the mapping).

        ``bend`` [N m] log, ``stretch`` [N/m] log, ``friction`` [1], ``scale`` [m], ``mass`` [kg/m^2].
        Bounds were swept corner by corner for stability at the default options.

        Raises:
            ValueError: scenario not supported.
        """
        self._check_scenario(scenario)
        if scenario.object.get("kind") == "rope":
            return rope_param_space()
        return ParamSpace([
            Param("bend", 1e-6, 1e-3, "N*m", log=True,
                  description="bending rigidity D = E t^3 / (12 (1 - nu^2))"),
            Param("stretch", 5.0, 1000.0, "N/m", log=True, description="membrane stretch stiffness k = E t"),
            Param("friction", 0.05, 1.5, "1", description="cloth-table sliding friction coefficient"),
            Param("scale", 0.20, 0.34, "m", description="cloth side length (square)"),
            Param("mass", 0.1, 0.35, "kg/m^2", description="areal density (fabrics: 0.11-0.32)"),
        ])

    def _check_scenario(self, scenario: Scenario) -> None:
        if scenario.name not in self.scenarios:
            raise ValueError(f"mujoco-flex cannot run scenario '{scenario.name}'; valid scenarios: "
                             f"{', '.join(self.scenarios)}")

    def _check_effects(self, effects: Sequence[str]) -> None:
        bad = [e for e in effects if e not in self.effects]
        if bad:
            raise ParameterError(f"mujoco-flex does not support effect(s) {bad}; supported effects: "
                                 f"{', '.join(self.effects) or '(none yet)'}")

    def _apply_effects(self, spec: dict[str, Any], theta: Mapping[str, float], effects: Sequence[str]) -> None:
        """Apply effects (see :mod:`softsbi.effects.builtin`) by editing ``spec`` in place."""
        if effects:
            from ..effects.builtin import apply_mujoco
            apply_mujoco(spec, theta, effects, grid=self.grid)

    def full_space(self, scenario: Scenario, effects: Sequence[str] = ()) -> ParamSpace:
        """Nominal parameters plus those of ``effects``."""
        from ..effects.builtin import BUILTIN_EFFECTS
        space = self.param_space(scenario)
        by_name = {e.name: e for e in BUILTIN_EFFECTS}
        for e in effects:
            space = space + by_name[e]().param_space()
        return space

    def build_xml(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = ()) -> str:
        """MJCF string of the lift at ``theta`` (no validation; use :meth:`simulate`)."""
        return spec_to_xml(self.build_spec(scenario, theta, effects))

    def build_spec(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = ()) -> dict[str, Any]:
        """The model dict of :func:`build_spec` with this instance's options and effects applied."""
        if scenario.object.get("kind") == "rope":
            spec = build_rope_spec(scenario, theta, nodes=self.rope_nodes, timestep=self.timestep,
                                   solver=self.solver, integrator=self.integrator, poisson=self.poisson,
                                   damping=self.damping, iterations=self.iterations, overrides=self.overrides)
        else:
            spec = build_spec(scenario, theta, grid=self.grid, timestep=self.timestep, solver=self.solver,
                              integrator=self.integrator, poisson=self.poisson, radius=self.radius,
                              damping=self.damping, iterations=self.iterations, overrides=self.overrides)
        self._apply_effects(spec, theta, effects)
        return spec

    # -- simulation -------------------------------------------------------------------------
    def simulate(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = (),
                 seed: int = 0) -> Rollout:
        """Run the lift; returns ``vertices (T, grid^2, 3)`` m at ``scenario.times``.

        ``gripper (T, 3)`` is the actual grasp target (mocap) at those times, ``faces`` the grid
        triangles ``(2 (grid-1)^2, 3)``. ``info``: ``wall_s``, ``steps``, ``young``, ``thickness``.

        Raises:
            ValueError: unknown scenario (names the valid ones).
            ParameterError: unknown/missing/out-of-bounds parameter, unsupported effect.
        """
        import mujoco

        self._check_scenario(scenario)
        self._check_effects(effects)
        space = self.full_space(scenario, effects)
        theta = space.check(theta)
        t0 = time.perf_counter()
        spec = self.build_spec(scenario, theta, effects)
        m = mujoco.MjModel.from_xml_string(spec_to_xml(spec))
        d = mujoco.MjData(m)
        mujoco.mj_forward(m, d)
        n = int(m.flex_vertnum[0])  # grid^2 (cloth) or rope_nodes (rope)
        times = scenario.times
        T = len(times)
        # constant offset from the commanded path to the grasped vertex (the corner lies on the table)
        grip0 = d.mocap_pos[0].copy()
        offset = grip0 - scenario.gripper[0]
        target = scenario.gripper + offset
        verts = np.full((T, n, 3), np.nan)
        grip = np.zeros((T, 3))
        verts[0] = d.flexvert_xpos.reshape(-1, 3)[:n]
        grip[0] = target[0]
        dt = m.opt.timestep
        status, reason = STATUS_OK, ""
        steps = 0
        # step counts are fixed in advance: after a divergence MuJoCo resets d.time to 0, so a
        # loop on d.time would never end
        frame_steps = np.maximum(np.round(times / dt).astype(int), 0)
        warn = d.warning[mujoco.mjtWarning.mjWARN_BADQACC]
        for k in range(1, T):
            while steps < frame_steps[k]:
                tn = (steps + 1) * dt
                d.mocap_pos[0] = [np.interp(tn, times, target[:, c]) for c in range(3)]
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
        wall = time.perf_counter() - t0
        if status == STATUS_OK:
            status, reason = self._plausibility(scenario, theta, verts, grip)
        if status != STATUS_OK:
            verts = np.nan_to_num(verts, nan=0.0, posinf=0.0, neginf=0.0)
        faces = np.zeros((0, 3), dtype=np.int64) if scenario.object.get("kind") == "rope" else grid_faces(self.grid)
        return Rollout(times=times.copy(), gripper=grip, vertices=verts, faces=faces,
                       status=status, reason=reason,
                       info={"wall_s": wall, "steps": steps, "backend": self.name, "grid": self.grid,
                             "timestep": dt, "young": spec["elasticity"]["young"],
                             "thickness": spec["elasticity"]["thickness"], "effects": list(effects)})

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
        g = self.grid
        first_row = verts[-1].reshape(g, g, 3)
        edge = np.linalg.norm(np.diff(first_row, axis=0), axis=-1).max()
        h = L / (g - 1)
        if edge > 3.0 * h:
            return STATUS_IMPLAUSIBLE, f"an edge is stretched to {edge / h:.1f}x its rest length"
        return STATUS_OK, ""


@hookimpl
def softsbi_simulators() -> list[type[Simulator]]:
    return [MujocoFlex]
