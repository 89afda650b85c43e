"""The effect door: backends apply effects through force fields, model edits and observation transforms,
never by name, and refuse an effect with one line naming the missing door."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from softsbi.backends.common import EffectPlan, check_effects
from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.backends.pybullet_massspring import PybulletMassSpring
from softsbi.core.errors import ParameterError, ShapeError, SoftsbiError
from softsbi.core.interfaces import Effect, VertexContext
from softsbi.core.types import Param, ParamSpace
from softsbi.effects.builtin import ExtraDamping, GripCompliance
from softsbi.effects.physics import HeavyHem
from softsbi.effects.sensor import CalibrationOffset
from softsbi.plugins import registry
from softsbi.scenarios.builtin import lift_scenario
from softsbi.workflows.criticism.screening import candidate_effects

pytestmark = pytest.mark.integration

LIFT = lift_scenario(None, n_frames=11)


def test_force_field_on_mujoco_matches_the_fluid_model_edit():
    """The same damping through the force door (explicit, xfrc_applied) and through MuJoCo's fluid model
    (implicit): they differ only by the integration, first order in the step (measured 1.8 mm at 4 ms)."""
    sim = MujocoFlex(grid=5)
    base = sim.param_space(LIFT).midpoint()
    edit = sim.simulate(LIFT, {**base, "damping_rate": 24.0}, effects=["extra-damping"]).vertices
    force = sim.simulate(LIFT, {**base, "lin_kh": 24.0, "lin_kv": 24.0}, effects=["generic-linear-drag"]).vertices
    nominal = sim.simulate(LIFT, base).vertices
    gap, effect = np.abs(edit - force).max(), np.abs(edit - nominal).max()
    assert gap < 0.003 and effect > 5 * gap, (gap, effect)


def test_supports_names_the_missing_door():
    assert MujocoFlex.supports(HeavyHem) is None and MujocoFlex.supports(CalibrationOffset) is None
    assert PybulletMassSpring.supports(CalibrationOffset) is None
    assert PybulletMassSpring.supports(HeavyHem) == "a force field (pybullet-massspring applies: observation)"
    assert PybulletMassSpring.supports(GripCompliance).startswith(
        "a model edit registered for 'pybullet-massspring' (the effect has edits for: mujoco-flex)")
    # extra-damping has a mujoco edit and a force field: pybullet lacks the force door
    assert "force field" in PybulletMassSpring.supports(ExtraDamping)


def test_backends_list_what_they_support():
    mj, pb = set(MujocoFlex.effects), set(PybulletMassSpring.effects)
    assert {"air-drag", "wind", "extra-damping", "grip-compliance", "heavy-hem", "generic-constant",
            "calibration-offset"} <= mj
    assert "toy-wind" not in mj  # applied by name by toy-gauss only
    assert pb == {n for n, c in registry().tables["effect"].items() if c.kind == "sensor"}


def test_refusal_is_one_line_naming_the_door():
    sim = PybulletMassSpring(grid=5)
    with pytest.raises(ParameterError) as err:
        sim.simulate(LIFT, sim.param_space(LIFT).midpoint(), effects=["heavy-hem"])
    msg = str(err.value)
    assert "\n" not in msg and "'heavy-hem' needs a force field" in msg and "supported effects: arm-mask, calibration-offset" in msg
    with pytest.raises(ParameterError, match="'no-such' is not an installed effect"):
        check_effects(MujocoFlex(), ["no-such"])


def test_pybullet_applies_observation_transforms():
    sim = PybulletMassSpring(grid=5)
    th = sim.param_space(LIFT).midpoint()
    a = sim.simulate(LIFT, th).vertices
    b = sim.simulate(LIFT, {**th, "offset_x": 0.02, "offset_y": 0.0, "offset_z": 0.0},
                     effects=["calibration-offset"]).vertices
    np.testing.assert_allclose(b - a, np.broadcast_to([0.02, 0.0, 0.0], a.shape), atol=1e-12)


class _BadShape(Effect):
    """Returns one force for all vertices (wrong shape). Off at 0."""

    name = "bad-shape"

    def param_space(self):
        return ParamSpace([Param("k", 0.0, 1.0, "N")])

    def force(self, x, v, t, theta, ctx):
        return np.zeros(3)


def test_a_force_of_the_wrong_shape_is_named():
    plan = EffectPlan("mujoco-flex", effects=[_BadShape()], forces=[_BadShape()])
    ctx = VertexContext(mass=np.ones(4), area=np.ones(4), x0=np.zeros((4, 3)), table_z=0.0, spacing=0.1, shape=(2, 2))
    with pytest.raises(ShapeError, match=r"effect 'bad-shape': force\(\) must return \(4, 3\)"):
        plan.force_fn({"k": 0.5}, ctx)(np.zeros((4, 3)), np.zeros((4, 3)), 0.0)


def test_vertex_context_edges():
    ctx = VertexContext(mass=np.ones(9), area=np.ones(9), x0=np.zeros((9, 3)), table_z=0.0, spacing=0.1, shape=(3, 3))
    assert ctx.edges.tolist() == [True] * 4 + [False] + [True] * 4


def test_diagnose_candidates_come_through_the_door():
    run = SimpleNamespace(config=SimpleNamespace(backend="mujoco-flex"), effects=["wind"])
    names = {c.name for c in candidate_effects(run, None)}
    assert {"air-drag", "extra-damping", "heavy-hem", "sticky-patch", "table-slope", "point-noise"} <= names
    assert "wind" not in names
    # generic force terms are screened too (for the third verdict); the diagnosis never refits or names them
    generic = {c.name for c in candidate_effects(run, None) if c.generic}
    assert generic and all(n.startswith("generic-") for n in generic)
    assert [c.name for c in candidate_effects(run, ["generic-constant"])] == ["generic-constant"]  # asked by name
    pb = SimpleNamespace(config=SimpleNamespace(backend="pybullet-massspring"), effects=[])
    with pytest.raises(SoftsbiError, match="heavy-hem \\(it needs a force field"):
        candidate_effects(pb, ["heavy-hem"])


def test_a_rope_s_default_candidates_leave_out_what_cannot_act_on_a_rope_and_say_so():
    """The default family of a rope held aniso-stretch, a cloth-only model edit: its refusal stopped the screening
    of all 21 candidates. Now it is left out, in one line; named, it is refused before any work."""
    rope = SimpleNamespace(config=SimpleNamespace(backend="mujoco-flex"), effects=[],
                           scenario=SimpleNamespace(object={"kind": "rope", "length": 0.3}))
    said: list[str] = []
    names = {c.name for c in candidate_effects(rope, None, said.append)}
    assert "aniso-stretch" not in names and {"heavy-hem", "wind", "sticky-patch"} <= names
    assert said == [f"left out of the candidates: aniso-stretch (cannot act on a rope); the other {len(names)} are "
                    f"screened"]
    with pytest.raises(SoftsbiError, match="aniso-stretch cannot act on a rope .it acts on cloth.; leave it out"):
        candidate_effects(rope, ["wind", "aniso-stretch"])
    cloth = SimpleNamespace(config=rope.config, effects=[], scenario=SimpleNamespace(object={"kind": "cloth"}))
    assert "aniso-stretch" in {c.name for c in candidate_effects(cloth, None, said.append)} and len(said) == 1


def test_an_empty_candidate_family_is_no_family():
    """An empty family means check's omnibus test alone, not every installed effect: the check of a refit that adds
    all of a diagnosis' candidates (`diagnose --effect heavy-hem`, or the pair of `--effect a --effect b`) screens
    the family less the refit's effects, so the family never grows between the steps of one diagnosis."""
    run = SimpleNamespace(config=SimpleNamespace(backend="mujoco-flex"), effects=["heavy-hem"])
    assert candidate_effects(run, []) == []


class _Recorder(Effect):
    """Records the state the force door passes (zero force). Off always."""

    name = "recorder"
    calls: list = []

    def param_space(self):
        return ParamSpace([Param("unused", 0.0, 1.0, "1")])

    def force(self, x, v, t, theta, ctx):
        type(self).calls.append((t, x.copy(), v.copy(), ctx))
        return np.zeros_like(x)


def test_force_door_sees_the_current_state(monkeypatch):
    """x, v, t passed to a force field are the state at the start of each step, read from qpos/qvel: the
    rollout's frame k (``flexvert_xpos`` after the frame's last step, which MuJoCo computes before
    integrating that step) is the state one step earlier, and (x_{n+1} - x_n) / dt equals v_{n+1}
    (MuJoCo's semi-implicit Euler)."""
    monkeypatch.setitem(registry().tables["effect"], "recorder", _Recorder)
    _Recorder.calls = []
    sim = MujocoFlex(grid=5)
    ro = sim.simulate(LIFT, {**sim.param_space(LIFT).midpoint(), "unused": 0.0}, effects=["recorder"])
    dt = ro.info["timestep"]
    t = np.array([c[0] for c in _Recorder.calls])
    x = np.stack([c[1] for c in _Recorder.calls])
    v = np.stack([c[2] for c in _Recorder.calls])
    np.testing.assert_allclose(t, np.arange(len(t)) * dt)
    for k in range(1, len(ro.times) - 1):
        n = int(round(ro.times[k] / dt))
        np.testing.assert_allclose(x[n - 1], ro.vertices[k], atol=1e-12)
    np.testing.assert_allclose((x[1:] - x[:-1]) / dt, v[1:], atol=1e-9)
    ctx = _Recorder.calls[0][3]
    assert ctx.shape == (5, 5) and np.isclose(ctx.mass.sum(), sim.param_space(LIFT).midpoint()["mass"] * 0.27 ** 2)
    # the cloth rests one collision radius (3 mm) above the table, as the effect how-to says and computes it
    assert ctx.x0[:, 2].min() - ctx.table_z == pytest.approx(sim.radius) and sim.radius == 0.003


def test_the_effect_howto_lists_every_attribute_of_the_context_with_its_rest_height():
    """A plugin author reads the how-to, not the source: every attribute of VertexContext is in its table, and the
    height the cloth rests at above ``table_z`` is given with the way to read it."""
    import dataclasses
    from pathlib import Path
    doc = (Path(__file__).parents[2] / "docs" / "howto" / "effect-plugin.md").read_text()
    names = [f.name for f in dataclasses.fields(VertexContext)] + [
        n for n, v in vars(VertexContext).items() if isinstance(v, property)]
    assert "edges" in names and all(f"| `ctx.{n}` |" in doc for n in names), names
    assert "3 mm" in doc and "rest = ctx.x0[:, 2].min() - ctx.table_z" in doc


def test_fluid_force_is_mujocos_inertia_box_force():
    """fluid_force reproduces qfrc_fluid of the air-drag + wind model edit at random velocities."""
    import mujoco

    from softsbi.backends.mujoco_flex import spec_to_xml
    from softsbi.effects.builtin import fluid_force
    sim = MujocoFlex(grid=5)
    th = {**sim.param_space(LIFT).midpoint(), "air_density": 3.0, "wind_x": 1.5, "wind_y": -1.0}
    spec = sim.build_spec(LIFT, th, ["air-drag", "wind"])
    m = mujoco.MjModel.from_xml_string(spec_to_xml(spec))
    d = mujoco.MjData(m)
    d.qvel[:] = np.random.default_rng(0).normal(size=m.nv)
    mujoco.mj_forward(m, d)
    opt = spec["option"]
    f = fluid_force(d.qvel.reshape(-1, 3), spec["flexcomp"]["spacing"][0], opt["density"], opt["viscosity"],
                    np.array(opt["wind"]))
    np.testing.assert_allclose(d.qfrc_fluid.reshape(-1, 3), f, atol=1e-12)
    assert np.abs(f).max() > 0.1


@pytest.mark.parametrize("name,values", [("air-drag", {"air_density": 6.0}), ("wind", {"wind_x": 2.0, "wind_y": -1.0}),
                                         ("extra-damping", {"damping_rate": 24.0})])
def test_builtin_force_fields_match_their_model_edits(monkeypatch, name, values):
    """The built-ins' engine-neutral force fields, run on mujoco-flex through the force door (a copy
    without the model edit), agree with the MuJoCo edit up to the explicit-vs-implicit integration."""
    cls = registry().effect(name)
    as_force = type(cls.__name__ + "Force", (cls,), {"name": name + "-force", "model_edits": ()})
    monkeypatch.setitem(registry().tables["effect"], as_force.name, as_force)
    sim = MujocoFlex(grid=5)
    base = sim.param_space(LIFT).midpoint()
    edit = sim.simulate(LIFT, {**base, **values}, effects=[name]).vertices
    force = sim.simulate(LIFT, {**base, **values}, effects=[as_force.name]).vertices
    nominal = sim.simulate(LIFT, base).vertices
    # mean vertex distance: a strong wind makes the cloth flutter, and the largest single-vertex gap
    # (2-3 cm) does not shrink with the step, while the mean does (grid 5, 11 frames)
    gap = np.linalg.norm(edit - force, axis=-1).mean()
    effect = np.linalg.norm(edit - nominal, axis=-1).mean()
    assert gap < 0.01 and effect > 10 * gap, (gap, effect)  # measured: wind 5.5 mm of 130 mm


class _Spy(Effect):
    """A force field of zero that records what its context says of the handles and corners. Off at 0."""

    name = "spy"

    def __init__(self):
        self.seen = []

    def param_space(self):
        return ParamSpace([Param("k", 0.0, 1.0, "N")])

    def force(self, x, v, t, theta, ctx):
        self.seen.append((t, ctx.handles.copy(), ctx.handle_names, ctx.corners))
        return np.zeros_like(x)


def test_a_force_field_sees_the_handles_current_positions_and_the_cloth_corners(monkeypatch):
    """The context tells an effect where each handle is at every step (the gripper's path, not its rest) and which
    vertices are the cloth's corners 0-3."""
    import softsbi.backends.mujoco_flex.simulator as mj
    from softsbi.backends.common import grid_corners
    spy = _Spy()
    monkeypatch.setattr(mj, "check_effects", lambda sim, effects: EffectPlan("mujoco-flex", [spy], forces=[spy]))
    sim = MujocoFlex(grid=5)
    ro = sim.simulate(LIFT, {**sim.param_space(LIFT).midpoint(), "k": 0.5}, effects=["spy"])
    assert len(spy.seen) > 10
    names = tuple(h.name for h in LIFT.handles)
    for _t, handles, seen_names, corners in spy.seen:
        assert handles.shape == (len(LIFT.handles), 3) and seen_names == names
        assert corners == tuple(grid_corners(5))
    dt = ro.info["timestep"]
    for k in (3, len(LIFT.times) - 1):  # the step that ends at frame k: the grasp target of frame k
        t, handles, _, _ = min(spy.seen, key=lambda s: abs(s[0] + dt - LIFT.times[k]))
        np.testing.assert_allclose(handles[0], ro.gripper[k], atol=1e-9)
    assert np.ptp([s[1][0, 2] for s in spy.seen]) > 0.05  # the handle moves: not its rest position


class _NaNForce(Effect):
    """Returns NaN forces once switched on (k > 0)."""

    name = "nan-force"

    def param_space(self):
        return ParamSpace([Param("k", 0.0, 1.0, "N")])

    def force(self, x, v, t, theta, ctx):
        return np.full_like(x, np.nan if theta["k"] > 0 else 0.0)


def test_a_non_finite_force_fails_the_rollout_naming_the_effect_not_the_engine(monkeypatch):
    """A plugin force() returning NaN was reported as a MuJoCo instability (bad accelerations) with a "narrow the
    prior bounds" hint; now the rollout fails with the effect named, through the same door on the real engine."""
    from softsbi.core.errors import EffectFault
    plan = EffectPlan("mujoco-flex", effects=[_NaNForce()], forces=[_NaNForce()])
    ctx = VertexContext(mass=np.ones(4), area=np.ones(4), x0=np.zeros((4, 3)), table_z=0.0, spacing=0.1, shape=(2, 2))
    with pytest.raises(EffectFault, match=r"effect 'nan-force': force\(\) returned a non-finite force .* k=0\.5"):
        plan.force_fn({"k": 0.5}, ctx)(np.zeros((4, 3)), np.zeros((4, 3)), 0.0)
    monkeypatch.setitem(registry().tables["effect"], "nan-force", _NaNForce)
    sim = MujocoFlex(grid=5)
    with pytest.raises(EffectFault, match="effect 'nan-force'"):
        sim.simulate(LIFT, {**sim.param_space(LIFT).midpoint(), "k": 0.5}, effects=["nan-force"])
