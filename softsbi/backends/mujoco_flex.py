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

Rendering (:meth:`MujocoFlex.simulate_images`): the same model plus a fixed camera with the exact
pinhole intrinsics (``focalpixel``/``principalpixel``/``sensorsize``; OpenCV axes converted to
MuJoCo's camera frame, which looks along -z with y up), one directional light from above and the
headlight off; shadows and reflections are switched off after every ``update_scene`` (5 ms per
320 px frame instead of ~50 ms). Cameras, lights and colours do not enter the physics: the
vertices are bit-identical to :meth:`MujocoFlex.simulate`. The robot is *visual only*: geoms added
to the rendered scene (:func:`visual_robot`), never to the model. Segmentation comes from MuJoCo's
segmentation rendering (flex -> ``SEG_OBJECT``, the added robot geoms -> ``SEG_ROBOT``, everything
else -> ``SEG_BACKGROUND``), depth from the linearised depth buffer (metres along the optical axis).
Off-screen OpenGL is chosen only when rendering is first asked for (:mod:`.mujoco_gl`):
``MUJOCO_GL`` if set, else OSMesa if its library loads, else EGL. Simulation loads no OpenGL.
"""
from __future__ import annotations

import math
import time
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..core.errors import DataError, ParameterError, RenderingUnavailable
from ..core.interfaces import Simulator
from ..core.types import (SEG_BACKGROUND, SEG_OBJECT, SEG_ROBOT, STATUS_DIVERGED, STATUS_IMPLAUSIBLE,
                          STATUS_OK, Param, ParamSpace, Rollout, Scenario)
from ..plugins.hookspecs import hookimpl
from .mujoco_gl import RENDER_FIX, choose_backend, gl_context_class, import_mujoco
from .scenarios import placed_direction, placement_params

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


def grid_corners(n: int) -> list[int]:
    """Vertex indices of the 4 corners of an ``n x n`` x-major grid, in the order grid ``(0, 0)``,
    ``(0, n-1)``, ``(n-1, n-1)``, ``(n-1, 0)`` (index ``i * n + j``); index 0 is the grasped corner.
    Both backends use this layout, so ``rollout.info["corners"]`` agrees across them."""
    return [0, n - 1, n * n - 1, (n - 1) * n]


# -- the visual-only robot (shared by both backends' renderers) -------------------------------
#: half sizes (m) of the black gripper block: 5 cm towards the robot base, 7 cm across, 4 cm high
GRIPPER_HALF = (0.025, 0.035, 0.02)
#: radius (m) and length (m, between the cap centres) of the white arm capsule
ARM_RADIUS = 0.03
ARM_LENGTH = 0.55
#: height (m) of the arm's shoulder point above the table for the synthetic scenarios
SHOULDER_HEIGHT = 0.5


def robot_base(scenario: Scenario) -> np.ndarray:
    """World point ``(3,)`` m the visual arm reaches towards (the robot's shoulder).

    ``scenario.options["robot_base"]`` when given; ``lift``: the real robot base (robot-frame
    origin, shoulder 0.33 m up) mapped with the recording's real->lift transform; ``wipe``: 0.45 m
    beyond the stroke's far end along the drag direction +x (the cloth trails away from the robot,
    as in the real wiping images); ``fling``/``wind``/others: behind the workspace along +y.
    """
    if "robot_base" in scenario.options:
        return np.asarray(scenario.options["robot_base"], dtype=float).reshape(3)
    g = scenario.gripper
    tz = float(scenario.table_z)
    if scenario.name == "lift":
        from .scenarios import DEFAULT_TRANSFORM, real_to_lift_frame
        cfg = scenario.options.get("transform", DEFAULT_TRANSFORM)
        return real_to_lift_frame(np.array([0.0, 0.0, 0.33]), cfg)
    if scenario.name == "wipe":
        return np.array([g[:, 0].max() + 0.45, g[:, 1].mean(), tz + SHOULDER_HEIGHT])
    return np.array([g[:, 0].mean(), g[:, 1].max() + 0.55, tz + SHOULDER_HEIGHT])


def _frame_from_x(x: np.ndarray) -> np.ndarray:
    """Rotation ``(3, 3)`` (columns = local axes in world) whose x axis is horizontal ``x``, z up."""
    x = np.array([x[0], x[1], 0.0])
    nx = np.linalg.norm(x)
    x = x / nx if nx > 1e-9 else np.array([1.0, 0.0, 0.0])
    z = np.array([0.0, 0.0, 1.0])
    return np.column_stack([x, np.cross(z, x), z])


def _frame_from_z(z: np.ndarray) -> np.ndarray:
    """Rotation ``(3, 3)`` (columns = local axes in world) whose z axis is the unit vector ``z``."""
    z = np.asarray(z, dtype=float) / np.linalg.norm(z)
    a = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def visual_robot(grip: np.ndarray, base: np.ndarray) -> list[dict[str, Any]]:
    """The visual-only robot at grasp point ``grip (3,)`` m, arm reaching towards ``base (3,)`` m.

    Returns two parts, each ``{"part": "gripper"|"arm", "shape": "box"|"capsule", "pos": (3,) m
    (centre), "rot": (3, 3) local->world, "size": box half sizes (3,) | capsule (radius,
    half-length)}``: a :data:`GRIPPER_HALF` block standing on the grasp point (its bottom at the
    grasp height) and an :data:`ARM_RADIUS` capsule of length :data:`ARM_LENGTH` rising from the
    block's top edge on the base side towards ``base`` (from above it occludes what lies under it,
    like the arm in the real wiping images).
    """
    grip = np.asarray(grip, dtype=float)
    base = np.asarray(base, dtype=float)
    hx, hy, hz = GRIPPER_HALF
    rg = _frame_from_x(base - grip)
    parts = [{"part": "gripper", "shape": "box", "pos": grip + np.array([0.0, 0.0, hz]), "rot": rg,
              "size": np.array([hx, hy, hz])}]
    p0 = grip + rg[:, 0] * (hx + 0.5 * ARM_RADIUS) + np.array([0.0, 0.0, 2 * hz + ARM_RADIUS])
    axis = base - p0
    if np.linalg.norm(axis) < 1e-6:
        axis = np.array([0.0, 0.0, 1.0])
    axis = axis / np.linalg.norm(axis)
    parts.append({"part": "arm", "shape": "capsule", "pos": p0 + axis * ARM_LENGTH / 2,
                  "rot": _frame_from_z(axis), "size": np.array([ARM_RADIUS, ARM_LENGTH / 2])})
    return parts


def _check_render_args(camera: Any, style: Any) -> Any:
    """Validate ``camera``/``style`` of ``simulate_images``; returns the style (default if None)."""
    from ..core.camera import Camera, RenderStyle
    if not isinstance(camera, Camera):
        raise DataError(f"camera must be a softsbi.core.camera.Camera (e.g. default_camera('wipe', 128)), "
                        f"got {type(camera).__name__}")
    if np.linalg.det(camera.R) < 0:
        raise DataError("camera.world_to_cam's 3x3 block is a reflection (det = -1), not a rotation: the "
                        "OpenCV axes x right, y down, z forward must form a right-handed frame (z = x cross y)")
    if style is None:
        return RenderStyle()
    if not isinstance(style, RenderStyle):
        raise DataError(f"style must be a softsbi.core.camera.RenderStyle or None, got {type(style).__name__}")
    return style


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
    d = placed_direction(scenario, theta)
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
    # rendering only (simulate_images): <visual> settings, a camera and a light; no physics effect
    rnd = spec.get("render") or {}
    visual = "".join(f"<{k} {attrs(v)}/>" for k, v in rnd.get("visual", {}).items())
    visual = f"\n  <visual>{visual}</visual>" if visual else ""
    extras = "".join(f"<{k} {attrs(v)}/>" for k, v in rnd.get("bodies", []))
    return f"""<mujoco model="softsbi_lift">
  <compiler autolimits="true"/>
  <option {attrs(spec["option"])}/>{visual}
  <worldbody>{extras}
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

        ``bend`` [N m] log, ``stretch`` [N/m] log, ``friction`` [1], ``scale`` [m], ``mass`` [kg/m^2],
        and ``yaw`` [deg] when the scenario's placement is unknown (``object["yaw_bounds"]``). Bounds
        were swept corner by corner for stability at the default options.

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
            *placement_params(scenario),
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
        triangles ``(2 (grid-1)^2, 3)``. ``info``: ``wall_s``, ``steps``, ``young``, ``thickness``,
        and for cloth ``corners`` (4 vertex indices, :func:`grid_corners` order).

        Raises:
            ValueError: unknown scenario (names the valid ones).
            ParameterError: unknown/missing/out-of-bounds parameter, unsupported effect.
        """
        return self._rollout(scenario, theta, effects)

    def simulate_images(self, scenario: Scenario, theta: Mapping[str, float], camera: Any,
                        effects: Sequence[str] = (), seed: int = 0, style: Any = None) -> Rollout:
        """:meth:`simulate` plus every recorded frame rendered through ``camera`` (OpenGL off-screen).

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
            RenderingUnavailable: no off-screen OpenGL back-end works (the message names the fix:
                ``apt-get install -y libosmesa6``, or ``MUJOCO_GL=egl``).
        """
        style = _check_render_args(camera, style)
        frames = _MjFrames(scenario, camera, style)
        try:
            ro = self._rollout(scenario, theta, effects, spec_hook=frames.edit_spec, frame_hook=frames)
        finally:
            frames.close()
        if ro.ok:
            ro.rgb, ro.depth, ro.segmentation = frames.rgb, frames.depth, frames.seg
        ro.info["render_s"] = frames.seconds
        ro.info["render_setup_s"] = frames.setup_seconds
        return ro

    def _rollout(self, scenario: Scenario, theta: Mapping[str, float], effects: Sequence[str] = (),
                 spec_hook: Callable[[dict[str, Any]], None] | None = None,
                 frame_hook: Callable[[int, Any, Any], None] | None = None) -> Rollout:
        """The one stepping loop of :meth:`simulate` and :meth:`simulate_images`.

        ``spec_hook(spec)`` may add render-only elements to the model dict before compiling;
        ``frame_hook(k, m, d)`` is called after frame ``k`` is recorded (``k = 0`` after
        ``mj_forward``), with the grasp target in ``d.mocap_pos[0]``; not called after a failure.
        """
        mujoco = import_mujoco()

        self._check_scenario(scenario)
        self._check_effects(effects)
        space = self.full_space(scenario, effects)
        theta = space.check(theta)
        t0 = time.perf_counter()
        spec = self.build_spec(scenario, theta, effects)
        if spec_hook is not None:
            spec_hook(spec)
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
        if frame_hook is not None:
            frame_hook(0, m, d)
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
            if frame_hook is not None:
                frame_hook(k, m, d)
        wall = time.perf_counter() - t0
        if status == STATUS_OK:
            status, reason = self._plausibility(scenario, theta, verts, grip)
        if status != STATUS_OK:
            verts = np.nan_to_num(verts, nan=0.0, posinf=0.0, neginf=0.0)
        rope = scenario.object.get("kind") == "rope"
        faces = np.zeros((0, 3), dtype=np.int64) if rope else grid_faces(self.grid)
        info = {"wall_s": wall, "steps": steps, "backend": self.name, "grid": self.grid,
                "timestep": dt, "young": spec["elasticity"]["young"],
                "thickness": spec["elasticity"]["thickness"], "effects": list(effects)}
        if not rope:
            info["corners"] = grid_corners(self.grid)
        return Rollout(times=times.copy(), gripper=grip, vertices=verts, faces=faces,
                       status=status, reason=reason, info=info)

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


def _rgba(c: Sequence[int]) -> np.ndarray:
    return np.array([c[0] / 255.0, c[1] / 255.0, c[2] / 255.0, 1.0], dtype=np.float32)


#: colour of scene geoms other than the table (the wind scenario's spool), RGB 0-255
PROP_COLOUR = (120, 128, 150)
#: objid given to the added robot geoms in the rendered scene (segmentation decoding)
_ROBOT_OBJID = -1000


class _MjFrames:
    """Renders each recorded frame of a MuJoCo rollout (the ``frame_hook`` of ``_rollout``).

    Low-level pipeline (``mjv_updateScene`` -> ``mjr_render`` -> ``mjr_readPixels``) rather than
    ``mujoco.Renderer``, so that one pass reads colour *and* depth (the Renderer needs a pass for
    each) and a second pass the segmentation: 2 passes per frame instead of 3.
    """

    CAMERA = "softsbi_cam"

    def __init__(self, scenario: Scenario, camera: Any, style: Any):
        self.scenario, self.camera, self.style = scenario, camera, style
        self.base = robot_base(scenario)
        T, H, W = scenario.n_frames, camera.height, camera.width
        self.rgb = np.zeros((T, H, W, 3), np.uint8)
        self.depth = np.zeros((T, H, W), np.float32)
        self.seg = np.zeros((T, H, W), np.uint8)
        self._buf_rgb = np.zeros((H, W, 3), np.uint8)
        self._buf_depth = np.zeros((H, W), np.float32)
        self.gl = self.ctx = None
        self.seconds = 0.0
        self.setup_seconds = 0.0

    def edit_spec(self, spec: dict[str, Any]) -> None:
        """Add the camera (exact intrinsics), a light from above and off-screen buffer settings."""
        cam = self.camera
        W, H = cam.width, cam.height
        R = cam.R
        # OpenCV camera axes (x right, y down, z forward) -> MuJoCo's (x right, y up, looking along -z)
        xa, ya = R[0], -R[1]
        pitch = 1e-4  # m per pixel of a virtual sensor: only the focal/sensor ratio matters
        # MuJoCo's principal offset moves the image content the other way than OpenCV's (cx, cy)
        # (checked by projecting spheres: agreement within 0.3 px, tests/test_render.py)
        camera = {"name": self.CAMERA, "pos": cam.position.tolist(), "xyaxes": list(xa) + list(ya),
                  "resolution": [W, H], "sensorsize": [W * pitch, H * pitch],
                  "focalpixel": [cam.fx, cam.fy], "principalpixel": [(W - 1) / 2 - cam.cx, (H - 1) / 2 - cam.cy]}
        light = {"name": "softsbi_sun", "pos": [0.0, 0.0, 3.0], "dir": [0.0, 0.0, -1.0], "directional": "true",
                 "castshadow": "false", "ambient": [0.45] * 3, "diffuse": [0.55] * 3, "specular": [0.0] * 3}
        spec["render"] = {
            # no shadow map, no multisampling (software MSAA is slow and would blend segmentation ids)
            "visual": {"global": {"offwidth": max(640, W), "offheight": max(480, H)},
                       "headlight": {"active": 0, "ambient": [0.0] * 3, "diffuse": [0.0] * 3, "specular": [0.0] * 3},
                       "quality": {"shadowsize": 0, "offsamples": 0}},
            "bodies": [("camera", camera), ("light", light)],
        }

    def _setup(self, m: Any) -> None:
        mujoco = import_mujoco()
        table = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table")
        for g in range(m.ngeom):
            m.geom_rgba[g] = _rgba(self.style.table if g == table else PROP_COLOUR)
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
                # size[2] of a plane is only its rendering grid spacing (1 cm: 160 000 quads, ~6 ms a
                # frame in software GL); one quad suffices under a directional light. No physics effect.
                m.geom_size[g, 2] = max(float(m.geom_size[g, 0]), float(m.geom_size[g, 1]), 1.0)
        m.flex_rgba[:] = _rgba(self.style.cloth)
        cls = gl_context_class()  # RenderingUnavailable names the fix
        try:
            self.gl = cls(max(640, self.camera.width), max(480, self.camera.height))
            self.gl.make_current()
            self.ctx = mujoco.MjrContext(m, mujoco.mjtFontScale.mjFONTSCALE_100)
        except Exception as exc:  # noqa: BLE001 - GL back-ends fail with many exception types
            self.close()
            raise RenderingUnavailable(f"MuJoCo could not open an off-screen OpenGL context with back-end "
                                       f"{choose_backend()!r} ({type(exc).__name__}: {exc}); {RENDER_FIX}") from exc
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.ctx)
        self.ctx.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR  # reversed z (as mujoco.Renderer)
        self.scene = mujoco.MjvScene(m, maxgeom=m.ngeom + m.nflex + 16)
        self.opt = mujoco.MjvOption()
        self.cam = mujoco.MjvCamera()
        self.cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self.cam.fixedcamid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, self.CAMERA)
        self.rect = mujoco.MjrRect(0, 0, self.camera.width, self.camera.height)
        # reversed-z depth buffer -> metres along the optical axis (mujoco.Renderer's formula)
        near = np.float32(m.vis.map.znear * m.stat.extent)
        far = np.float32(m.vis.map.zfar * m.stat.extent)
        self._c = float(np.float32(-0.5) * (-(far + near) / (far - near)) - np.float32(0.5))
        self._d = float(np.float32(-0.5) * (-(np.float32(2) * far * near) / (far - near)))

    def _add_robot(self, scene: Any, grip: np.ndarray) -> None:
        mujoco = import_mujoco()
        for part in visual_robot(grip, self.base):
            if scene.ngeom >= scene.maxgeom:
                break
            g = scene.geoms[scene.ngeom]
            colour = self.style.gripper if part["part"] == "gripper" else self.style.robot
            if part["shape"] == "box":
                gtype, size = mujoco.mjtGeom.mjGEOM_BOX, np.asarray(part["size"], float)
            else:
                gtype = mujoco.mjtGeom.mjGEOM_CAPSULE
                size = np.array([part["size"][0], part["size"][1], 0.0])
            mujoco.mjv_initGeom(g, int(gtype), size, np.asarray(part["pos"], float),
                                np.asarray(part["rot"], float).ravel(), _rgba(colour))
            g.objtype, g.objid, g.segid = int(mujoco.mjtObj.mjOBJ_UNKNOWN), _ROBOT_OBJID, scene.ngeom
            scene.ngeom += 1

    def __call__(self, k: int, m: Any, d: Any) -> None:
        mujoco = import_mujoco()
        t0 = time.perf_counter()
        if self.ctx is None:
            self._setup(m)
            self.setup_seconds = time.perf_counter() - t0
        self.gl.make_current()
        scn, flags = self.scene, mujoco.mjtRndFlag
        mujoco.mjv_updateScene(m, d, self.opt, None, self.cam, int(mujoco.mjtCatBit.mjCAT_ALL), scn)
        if self.style.show_robot:
            self._add_robot(scn, np.array(d.mocap_pos[0]))
        scn.flags[flags.mjRND_SHADOW] = 0
        scn.flags[flags.mjRND_REFLECTION] = 0
        # pass 1: colour and depth
        mujoco.mjr_render(self.rect, scn, self.ctx)
        mujoco.mjr_readPixels(self._buf_rgb, self._buf_depth, self.rect, self.ctx)
        self.rgb[k] = self._buf_rgb[::-1]
        self.depth[k] = (self._d / (self._buf_depth[::-1].astype(np.float64) + self._c)).astype(np.float32)
        # pass 2: segmentation (each geom drawn in a colour encoding segid + 1; 0 = nothing)
        scn.flags[flags.mjRND_SEGMENT] = 1
        scn.flags[flags.mjRND_IDCOLOR] = 1
        mujoco.mjr_render(self.rect, scn, self.ctx)
        scn.flags[flags.mjRND_SEGMENT] = 0
        scn.flags[flags.mjRND_IDCOLOR] = 0
        mujoco.mjr_readPixels(self._buf_rgb, None, self.rect, self.ctx)
        ids = self._buf_rgb[::-1].astype(np.int64)
        ids = ids[..., 0] + (ids[..., 1] << 8) + (ids[..., 2] << 16)
        lut = np.zeros(scn.ngeom + 2, np.uint8)
        flex = int(mujoco.mjtObj.mjOBJ_FLEX)
        for i in range(scn.ngeom):
            g = scn.geoms[i]
            if 0 <= g.segid <= scn.ngeom:
                lab = (SEG_OBJECT if g.objtype == flex else
                       SEG_ROBOT if g.objid == _ROBOT_OBJID else SEG_BACKGROUND)
                lut[g.segid + 1] = lab
        self.seg[k] = lut[np.clip(ids, 0, len(lut) - 1)]
        self.seconds += time.perf_counter() - t0

    def close(self) -> None:
        if self.ctx is not None:
            if self.gl is not None:
                self.gl.make_current()
            self.ctx.free()
            self.ctx = None
        if self.gl is not None:
            self.gl.free()
            self.gl = None


@hookimpl
def softsbi_simulators() -> list[type[Simulator]]:
    return [MujocoFlex]
