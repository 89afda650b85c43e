"""Code shared by the simulator backends (``mujoco-flex``, ``pybullet-massspring``).

* the cloth grid layout both engines use (:func:`~softsbi.scenarios.grid.grid_faces`,
  :func:`~softsbi.scenarios.grid.grid_corners`, importable from here too), so that ``rollout.info["corners"]``
  and vertex indices agree across engines;
* the visual-only robot drawn by both renderers (:func:`robot_base`, :func:`visual_robot`) and
  the colour helpers (:data:`PROP_COLOUR`, :func:`rgba`);
* the size/density/placement parameters every engine shares (:func:`size_params`);
* the scenario/effect checks with the backend's name in the message (:func:`check_scenario`,
  :func:`check_effects`), and the effect door's bookkeeping (:class:`EffectPlan`: model edits,
  force fields, observation transforms; :class:`EffectsThroughDoor`);
* :class:`FrameRenderer`, the base of each engine's per-frame renderer used by the template
  :meth:`softsbi.core.interfaces.Simulator.simulate_images`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.core.errors import EffectFault, ParameterError, PluginNotFound, ShapeError
from softsbi.core.interfaces import FORCE, MODEL_EDIT, OBSERVATION, Effect, VertexContext
from softsbi.core.types import Param, ParamSpace, Rollout, Scenario
from softsbi.scenarios.grid import grid_corners, grid_faces  # noqa: F401 - the backends import them from here
from softsbi.backends.scenario_build import check_features
from softsbi.plugins import registry
from softsbi.scenarios.builtin import placement_params
from softsbi.scenarios.spec import load_scenario_data


#: shared physical cloth parameters: name -> (low, high, unit, log, description); one meaning on every backend
CLOTH_MATERIAL = {
    "bend": (1e-6, 1e-3, "N*m", True, "bending rigidity D = E t^3 / (12 (1 - nu^2))"),
    "stretch": (5.0, 1000.0, "N/m", True, "membrane stretch stiffness k = E t"),
    "friction": (0.05, 1.5, "1", False, "cloth-table sliding friction coefficient (Coulomb)"),
}


def cloth_material_params(**narrow: tuple[float, float]) -> list[Param]:
    """The shared physical cloth material parameters (:data:`CLOTH_MATERIAL`), one name, unit and meaning
    on every backend: ``bend`` bending rigidity [N m] log 1e-6-1e-3, ``stretch`` membrane stiffness
    [N/m] log 5-1000, ``friction`` Coulomb coefficient 0.05-1.5. Each backend maps them to its own
    knobs (mujoco-flex: :func:`softsbi.backends.mujoco_flex.model.plate_mapping`; pybullet-massspring:
    :func:`softsbi.backends.pybullet_massspring.model.spring_constants`). With the size parameters
    (:func:`size_params`) they are the shared physical space.

    Args:
        narrow: ``name=(low, high)``: a backend that cannot honour the whole shared range of ``name``
            gives the sub-range it can (must lie inside the shared one).

    Raises:
        ValueError: an unknown name, or a range not inside the shared one.
    """
    out = []
    for name, (lo, hi, unit, log, desc) in CLOTH_MATERIAL.items():
        if name in narrow:
            a, b = narrow[name]
            if not lo <= a < b <= hi:
                raise ValueError(f"narrowed range of '{name}' {a}-{b} must lie inside the shared {lo}-{hi} {unit}")
            lo, hi = a, b
        out.append(Param(name, lo, hi, unit, log=log, description=desc))
    bad = set(narrow) - set(CLOTH_MATERIAL)
    if bad:
        raise ValueError(f"unknown shared parameter(s) {sorted(bad)}; shared: {', '.join(CLOTH_MATERIAL)}")
    return out


def cantilever_scenario(L: float = 0.2, grid: int = 9, clamp_rows: int = 5, g: float = 9.81,
                        duration: float = 16.0, frames: int = 11) -> Scenario:
    """A static check of the bending mapping: a clamped cloth strip drooping under its own weight.

    A square grid cloth of side ``L`` m (placed with its grid axes along world x, y, vertex 0 at the
    origin) has its first ``clamp_rows`` rows (x <= (clamp_rows - 1) h, h = L / (grid - 1)) pinned: a
    clamped edge and a free overhang ``a = L - (clamp_rows - 1) h``. Gravity points *up* (``+g``
    m/s^2) so the table below never touches the strip. Use the backend at ``grid`` vertices per side.
    One handle follows a standing-still path (a scenario needs one moving handle).

    Raises:
        DataError: invalid values (the scenario-file validation).
    """
    h = L / (grid - 1)
    handles: list[dict[str, Any]] = []
    for i in range(clamp_rows):
        for j in range(grid):
            p = [h * i, h * j, 0.0]
            if i == 0 and j == 0:
                handles.append({"name": "h0_0", "grasp": {"point": p},
                                "path": {"keyframes": [{"t": 0.0, "p": p}, {"t": duration, "p": p}]}})
            else:
                handles.append({"name": f"h{i}_{j}", "grasp": {"point": p}, "pinned": True})
    data = {"format": "softsbi-scenario/1", "name": "cantilever", "object": {"kind": "cloth", "size": L},
            "placement": {"corner": [0.0, 0.0], "direction": [1.0, 1.0]}, "handles": handles,
            "frames": {"count": frames, "duration": duration}, "world": {"table_z": 0.0, "gravity": [0.0, 0.0, g]}}
    return load_scenario_data(data, "<cantilever>", None)


def cantilever_tip_deflection(vertices: np.ndarray, grid: int) -> float:
    """Tip deflection (m) of :func:`cantilever_scenario`: mean rise of the free edge (grid row ``grid - 1``)
    between the first and last frame of ``vertices (T, grid^2, 3)``."""
    v = np.asarray(vertices, dtype=float).reshape(len(vertices), grid, grid, 3)
    return float((v[-1, -1, :, 2] - v[0, -1, :, 2]).mean())


def cantilever_analytic(bend: float, mass: float, L: float = 0.2, grid: int = 9, clamp_rows: int = 5,
                        g: float = 9.81) -> float:
    """Small-deflection tip deflection (m) of a clamped plate strip under its weight (Euler-Bernoulli):
    ``w a^4 / (8 D)``, ``w = mass g`` N/m^2 (``mass`` kg/m^2), ``a`` the overhang (m), ``D = bend`` N m
    (Timoshenko & Gere, *Mechanics of Materials*, cantilever under uniform load). Valid while it is
    small against ``a`` (say < 0.1 a)."""
    a = L - (clamp_rows - 1) * L / (grid - 1)
    return mass * g * a ** 4 / (8.0 * bend)


def rope_cantilever_scenario(L: float = 0.3, nodes: int = 31, clamp_nodes: int = 6, g: float = 9.81,
                             radius: float = 0.004, duration: float = 12.0, frames: int = 13) -> Scenario:
    """A static check of a rope's bending: a clamped rope drooping under its own weight.

    A rope of length ``L`` m and ``radius`` m lies along -y from the origin; its first ``clamp_nodes``
    vertices (of ``nodes``, the backend's rope resolution: pass the same number to the backend) are
    pinned, leaving a free overhang ``a = L - (clamp_nodes - 1) L / (nodes - 1)``. Gravity points *up*
    (``+g`` m/s^2) so the table never touches the rope. Tip deflection:
    :func:`rope_cantilever_tip_deflection`; Euler-Bernoulli value: :func:`cantilever_analytic` with
    ``bend = EI`` [N m^2] and ``mass`` in kg/m (the same formula per unit width or per rope).

    Raises:
        DataError: invalid values (the scenario-file validation).
    """
    h = L / (nodes - 1)
    handles: list[dict[str, Any]] = []
    for i in range(clamp_nodes):
        p = [0.0, -h * i, 0.0]
        if i == 0:
            handles.append({"name": "clamp_0", "grasp": {"point": p},
                            "path": {"keyframes": [{"t": 0.0, "p": p}, {"t": duration, "p": p}]}})
        else:
            handles.append({"name": f"clamp_{i}", "grasp": {"point": p}, "pinned": True})
    data = {"format": "softsbi-scenario/1", "name": "rope-cantilever", "object": {"kind": "rope", "length": L,
                                                                                "radius": radius},
            "placement": {"corner": [0.0, 0.0], "direction": [0.0, -1.0]}, "handles": handles,
            "frames": {"count": frames, "duration": duration}, "world": {"table_z": 0.0, "gravity": [0.0, 0.0, g]}}
    return load_scenario_data(data, "<rope-cantilever>", None)


def rope_cantilever_tip_deflection(vertices: np.ndarray, last: int = 3) -> float:
    """Tip deflection (m) of :func:`rope_cantilever_scenario`: the rise of the free end (last vertex of
    ``vertices (T, N, 3)``) from the first frame, averaged over the ``last`` frames (a lightly damped
    rope still swings a little about its rest shape)."""
    v = np.asarray(vertices, dtype=float)
    return float((v[-last:, -1, 2] - v[0, -1, 2]).mean())


def size_params(scenario: Scenario | None, rope: bool) -> list[Param]:
    """The size, density and placement parameters, the same in every engine (units, bounds).

    Rope: ``scale`` (length) [m] 0.30-0.50, ``mass`` (linear density) [kg/m] 0.01-0.05. Cloth:
    ``scale`` (side) [m] 0.20-0.34, ``mass`` (areal density) [kg/m^2] 0.1-0.35, and ``yaw`` [deg]
    when ``scenario.object`` has ``"yaw_bounds"`` (:func:`~softsbi.scenarios.builtin.placement_params`).

    Raises:
        DataError: malformed ``yaw_bounds``.
    """
    if rope:
        return [Param("scale", 0.30, 0.50, "m", description="rope length"),
                Param("mass", 0.01, 0.05, "kg/m", description="linear density of the rope")]
    return [Param("scale", 0.20, 0.34, "m", description="cloth side length (square)"),
            Param("mass", 0.1, 0.35, "kg/m^2", description="areal density (fabrics: 0.11-0.32)"),
            *placement_params(scenario)]


# -- checks ------------------------------------------------------------------------------------
def check_scenario(sim: Any, scenario: Scenario) -> None:
    """Refuse a scenario needing an engine feature ``sim`` lacks (any valid scenario file otherwise runs;
    :func:`softsbi.backends.scenario_build.check_features`).

    Raises:
        ValueError: names the backend, the scenario and the missing feature.
    """
    check_features(sim, scenario)


class EffectsThroughDoor:
    """Class attribute ``effects`` of a backend that applies effects through the effect door: the sorted
    names of every registered effect the backend :meth:`~softsbi.core.interfaces.Simulator.supports`
    (built-in and third-party alike), read from the plugin registry when asked. No effect is known
    by name."""

    def __get__(self, obj: Any, cls: type) -> tuple[str, ...]:
        table = registry().tables["effect"]
        return tuple(n for n in sorted(table) if cls.supports(table[n]) is None)


@dataclass
class EffectPlan:
    """The effects of one rollout, resolved to objects and sorted by door (:func:`check_effects`).

    Attributes:
        backend: the simulator's name.
        effects: the :class:`~softsbi.core.interfaces.Effect` instances, in the order given.
        edits / forces / observers: those acting through a model edit for ``backend``, a force
            field, an observation transform.
    """

    backend: str
    effects: list[Effect] = field(default_factory=list)
    edits: list[Effect] = field(default_factory=list)
    forces: list[Effect] = field(default_factory=list)
    observers: list[Effect] = field(default_factory=list)

    def space(self, base: ParamSpace) -> ParamSpace:
        """``base`` plus every effect's parameters."""
        for e in self.effects:
            base = base + e.param_space()
        return base

    def edit(self, model: Any, theta: Mapping[str, float], ctx: Mapping[str, Any]) -> None:
        """Apply the model edits, in order, to ``model`` in place."""
        for e in self.edits:
            e.edit_model(self.backend, model, e.own(theta), ctx)

    def force_fn(self, theta: Mapping[str, float], ctx: VertexContext):
        """``f(x (N,3), v (N,3), t) -> (N, 3)`` N: the sum of the force fields, or None when there are none.

        Raises (when called):
            ShapeError: a force field returned an array whose shape is not ``(N, 3)``.
            EffectFault: a force field returned a non-finite value (the rollout fails naming the effect, where the
                engine would otherwise diverge and be blamed).
        """
        if not self.forces:
            return None
        parts = [(e, e.own(theta)) for e in self.forces]

        def total(x: np.ndarray, v: np.ndarray, t: float) -> np.ndarray:
            f = np.zeros_like(x)
            for e, th in parts:
                fe = np.asarray(e.force(x, v, t, th, ctx), dtype=float)
                if fe.shape != x.shape:
                    raise ShapeError(f"effect '{e.name}': force() must return ({len(x)}, 3) newtons, got "
                                     f"shape {fe.shape}")
                if not np.all(np.isfinite(fe)):
                    raise EffectFault(f"effect '{e.name}': force() returned a non-finite force (NaN or inf) at "
                                      f"t={t:.3f} s, {_at(th)}; a fault of the effect's code, not of the engine: fix "
                                      f"its force()")
                f += fe
            return f
        return total

    def observe(self, rollout: Rollout, theta: Mapping[str, float], seed: int) -> Rollout:
        """Apply the observation transforms, in order, to a successful rollout (``rng`` seeded by ``seed``).

        Raises:
            EffectFault: a transform returned vertices of another shape than the ``(T, N, 3)`` it was given, or made
                finite vertices non-finite (NaN or inf): the rollout fails naming the effect, where the observer or
                a figure would otherwise fail on them without naming it.
        """
        if not self.observers or not rollout.ok:
            return rollout
        rng = np.random.default_rng(int(seed))
        for e in self.observers:
            th = e.own(theta)
            seen = rollout
            rollout = e.observe(seen, th, rng)
            if not isinstance(rollout, Rollout) or np.shape(rollout.vertices) != np.shape(seen.vertices):
                got = (f"vertices of shape {np.shape(rollout.vertices)}" if isinstance(rollout, Rollout) else
                       f"a {type(rollout).__name__}, not a Rollout")
                raise EffectFault(f"effect '{e.name}': observe() returned {got}, expected a Rollout whose vertices "
                                  f"have the shape it was given, {np.shape(seen.vertices)} (T frames, N vertices, "
                                  f"xyz), at {_at(th)}; a fault of the effect's code, not of the engine: fix its "
                                  f"observe()")
            if not np.all(np.isfinite(np.asarray(rollout.vertices, dtype=float))) and \
                    np.all(np.isfinite(np.asarray(seen.vertices, dtype=float))):
                raise EffectFault(f"effect '{e.name}': observe() returned non-finite vertices (NaN or inf) at "
                                  f"{_at(th)}; a fault of the effect's code, not of the engine: fix its observe()")
        return rollout


def _at(theta: Mapping[str, float]) -> str:
    """``"name=value, ..."`` of an effect's own parameters (or ``"no parameters"``), for its fault's message."""
    return ", ".join(f"{name}={val:.4g}" for name, val in theta.items()) or "no parameters"


def check_effects(sim: Any, effects: Sequence[str]) -> EffectPlan:
    """Resolve effect names through the plugin registry and refuse any the backend cannot apply.

    Returns:
        the :class:`EffectPlan` of the rollout.

    Raises:
        ParameterError: one line naming the backend, the effect and the missing door (or that no such
            effect is installed), and the effects it supports.
    """

    plan = EffectPlan(sim.name)
    problems = []
    for name in effects:
        try:
            eff = registry().effect(name)()
        except PluginNotFound:
            problems.append(f"'{name}' is not an installed effect")
            continue
        why = type(sim).supports(eff)
        if why is not None:
            problems.append(f"'{name}' needs {why}")
            continue
        plan.effects.append(eff)
        doors = eff.doors(sim.name)
        if MODEL_EDIT in doors:
            plan.edits.append(eff)
        if FORCE in doors:
            plan.forces.append(eff)
        if OBSERVATION in doors:
            plan.observers.append(eff)
    if problems:
        raise ParameterError(f"{sim.name} does not support effect(s): {'; '.join(problems)}; supported effects: "
                             f"{', '.join(sim.effects) or '(none yet)'}")
    return plan


# -- the visual-only robot (shared by both backends' renderers) -------------------------------
#: half sizes (m) of the black gripper block: 5 cm towards the robot base, 7 cm across, 4 cm high
GRIPPER_HALF = (0.025, 0.035, 0.02)
#: radius (m) and length (m, between the cap centres) of the white arm capsule
ARM_RADIUS = 0.03
ARM_LENGTH = 0.55
#: height (m) of the arm's shoulder point above the table for the synthetic scenarios
SHOULDER_HEIGHT = 0.5
#: colour of scene geoms other than the table, cloth and robot (the winding scenario's spool), RGB 0-255
PROP_COLOUR = (120, 128, 150)


def rgba(c: Sequence[int]) -> list[float]:
    """RGB 0-255 -> ``[r, g, b, 1.0]`` floats in 0-1."""
    return [c[0] / 255.0, c[1] / 255.0, c[2] / 255.0, 1.0]


def robot_base(scenario: Scenario) -> np.ndarray:
    """World point ``(3,)`` m the visual arm reaches towards (the robot's shoulder).

    ``scenario.options["robot_base"]``, which a scenario file declares with ``robot: {base, frame}``
    (the built-in lift: the real robot's shoulder mapped from the robot frame; wipe: beyond the stroke's
    far end); otherwise behind the workspace along +y, :data:`SHOULDER_HEIGHT` above the table.
    """
    if "robot_base" in scenario.options:
        return np.asarray(scenario.options["robot_base"], dtype=float).reshape(3)
    g = scenario.gripper
    return np.array([g[:, 0].mean(), g[:, 1].max() + 0.55, float(scenario.table_z) + SHOULDER_HEIGHT])


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


# -- the per-frame renderer of Simulator.simulate_images --------------------------------------
class FrameRenderer:
    """Base of an engine's frame renderer (the protocol of
    :meth:`softsbi.core.interfaces.Simulator.simulate_images`).

    Holds the outputs, filled frame by frame by the engine's ``__call__``:
    ``rgb (T, H, W, 3)`` uint8, ``depth (T, H, W)`` float32 m along the optical axis,
    ``segmentation (T, H, W)`` uint8 (``SEG_*``), ``seconds`` (s spent rendering) and
    ``setup_seconds`` (s of it spent once, on the first frame); ``T = scenario.n_frames``,
    ``H, W = camera.height, camera.width``. Also ``base``: the visual robot's shoulder
    (:func:`robot_base`).
    """

    def __init__(self, scenario: Scenario, camera: Any, style: Any):
        self.scenario, self.camera, self.style = scenario, camera, style
        self.base = robot_base(scenario)
        T, H, W = scenario.n_frames, camera.height, camera.width
        self.rgb = np.zeros((T, H, W, 3), np.uint8)
        self.depth = np.zeros((T, H, W), np.float32)
        self.segmentation = np.zeros((T, H, W), np.uint8)
        self.seconds = 0.0
        self.setup_seconds = 0.0

    def edit(self, model: Any) -> None:
        """Add render-only elements to the engine's model description before it is built
        (default: nothing)."""

    def __call__(self, k: int, state: Any) -> None:
        """Render recorded frame ``k`` from the engine's ``state`` into the output arrays."""
        raise NotImplementedError

    def close(self) -> None:
        """Release what rendering holds (GL contexts); safe to call twice (default: nothing)."""
