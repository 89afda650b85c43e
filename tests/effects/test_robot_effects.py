"""The robot's candidate effects (softsbi/effects/robot.py): duration-scale and grasp-patch are model edits that
mujoco-flex applies, exactly the nominal model when off, and each changes the lift the way its docstring states
(mujoco-flex, 5x5 cloth, 11 frames, the prior's midpoint: one or two rollouts each)."""
from __future__ import annotations

import numpy as np
import pytest

from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.core.interfaces import MODEL_EDIT
from softsbi.effects.robot import ROBOT_EFFECTS, DurationScale, GraspPatch
from softsbi.plugins import registry
from softsbi.scenarios.builtin import lift_scenario

SIM = MujocoFlex(grid=5)
LIFT = lift_scenario(None, n_frames=11)
MID = SIM.param_space(LIFT).midpoint()
#: frames 5-8 of the 11: the gripper is rising (frame 10 is its end)
RISING = slice(5, 9)


@pytest.fixture(scope="module")
def base():
    ro = SIM.simulate(LIFT, MID)
    assert ro.ok, ro.reason
    return ro


def _run(name, **values):
    ro = SIM.simulate(LIFT, {**MID, **values}, effects=[name])
    assert ro.ok, ro.reason
    return ro


def test_registered_as_model_edits_that_mujoco_flex_applies_and_the_others_lack():
    reg = registry()
    for cls in ROBOT_EFFECTS:
        assert reg.effect(cls.name) is cls and cls.kind == "physics" and not cls.generic
        assert cls().doors("mujoco-flex") == (MODEL_EDIT,)
        assert MujocoFlex.supports(cls()) is None and cls.name in MujocoFlex.effects
        why = reg.simulator("pybullet-massspring").supports(cls())
        assert why is not None and "model edit" in why, why


def test_duration_scale_runs_the_path_slower_and_records_the_same_fractions_of_it(base):
    """s = 4: four times the steps, the same stamps and gripper points per frame, and a cloth that trails less
    while the gripper rises: its mean height over the rising frames 5-8 is 0.39 cm above the nominal's (measured;
    0.23 cm at s = 1.5, 0.29 at 2; perturbing a nominal parameter by 1% moves it by at most 0.01 cm)."""
    ro = _run("duration-scale", duration_scale=4.0)
    assert ro.info["time_scale"] == 4.0 and base.info["time_scale"] == 1.0
    assert ro.info["steps"] == 4 * base.info["steps"] == 4 * round(LIFT.times[-1] / SIM.timestep)
    np.testing.assert_array_equal(ro.times, base.times)
    np.testing.assert_array_equal(ro.gripper, base.gripper)
    rise = (ro.vertices[RISING, :, 2].mean() - base.vertices[RISING, :, 2].mean()) * 100
    assert 0.3 < rise < 0.5, rise
    slower = _run("duration-scale", duration_scale=2.0)
    assert 0.0 < (slower.vertices[RISING, :, 2].mean() - base.vertices[RISING, :, 2].mean()) * 100 < rise


def test_duration_scales_compose_and_the_off_value_leaves_the_model_as_it_is():
    spec = SIM.build_spec(LIFT, {**MID, "duration_scale": 2.0}, ["duration-scale"])
    assert spec["motion"]["time_scale"] == 2.0
    DurationScale().edit_model("mujoco-flex", spec, {"duration_scale": 1.5}, {})
    assert spec["motion"]["time_scale"] == 3.0
    assert SIM.build_spec(LIFT, {**MID, "duration_scale": 1.0}, ["duration-scale"]) == SIM.build_spec(LIFT, MID)


def test_grasp_patch_weights_hold_within_the_radius_and_fade_over_one_spacing():
    h = 0.01
    rest = np.array([[0, 0, 0], [h, 0, 0], [h, h, 0], [2 * h, 0, 0], [3 * h, 0, 0]], dtype=float)
    np.testing.assert_allclose(GraspPatch.weights(rest, 0, 0.0, h), [1, 0, 0, 0, 0])
    np.testing.assert_allclose(GraspPatch.weights(rest, 0, 0.5 * h, h), [1, 0.5, 1.5 - np.sqrt(2), 0, 0], atol=1e-12)
    np.testing.assert_allclose(GraspPatch.weights(rest, 0, 2 * h, h), [1, 1, 1, 1, 0], atol=1e-12)
    # continuous in the radius: a small step changes each weight by at most step / spacing
    a, b = GraspPatch.weights(rest, 0, 1.3 * h, h), GraspPatch.weights(rest, 0, 1.31 * h, h)
    assert np.abs(b - a).max() <= 0.01 + 1e-12


def test_grasp_patch_adds_one_softened_grasp_per_held_vertex_and_none_when_off():
    off = SIM.build_spec(LIFT, {**MID, "grasp_radius": 0.0}, ["grasp-patch"])
    assert off == SIM.build_spec(LIFT, MID) and len(off["connects"]) == 1
    h = MID["scale"] / (SIM.grid - 1)
    spec = SIM.build_spec(LIFT, {**MID, "grasp_radius": 0.5 * h}, ["grasp-patch"])
    grip, *held = spec["connects"]
    # the corner's two neighbours along the edges, half held; the diagonal one, 1.5 - sqrt(2) held
    assert sorted(c["body1"] for c in held) == ["cloth_1", "cloth_5", "cloth_6"]
    w = {c["body1"]: grip["solref"][0] / c["solref"][0] for c in held}
    assert w == pytest.approx({"cloth_1": 0.5, "cloth_5": 0.5, "cloth_6": 1.5 - np.sqrt(2)})
    for c in held:
        assert c["body2"] == "grip" and c["solimp"][:2] == pytest.approx(np.multiply(grip["solimp"][:2], w[c["body1"]]))
    # with grip-compliance, either order of the two edits gives one model
    th = {**MID, "grasp_radius": 0.5 * h, "grip_timeconst": 0.1}
    a = SIM.build_spec(LIFT, th, ["grasp-patch", "grip-compliance"])["connects"]
    b = SIM.build_spec(LIFT, th, ["grip-compliance", "grasp-patch"])["connects"]
    assert [c["body1"] for c in a] == [c["body1"] for c in b]
    np.testing.assert_allclose([c["solref"] for c in a], [c["solref"] for c in b], rtol=1e-12)
    assert a[0]["solref"][0] == 0.1 and a[1]["solref"][0] == pytest.approx(0.2)


def test_grasp_patch_holds_the_patch_at_its_rest_offsets_and_the_cloth_hangs_higher(base):
    """r = 2 cm (the 5x5 lift's spacing is 6.75 cm: the corner's two neighbours along the edges held with weight
    0.30): the last frame's mean height is 3.7 cm above the nominal's and the cloth is carried 1.9 cm along the
    diagonal (-y here) into the cloth (measured). Fully held vertices (r = 7 cm: those two neighbours) keep their
    rest offsets from the grasped corner within 2 mm."""
    ro = _run("grasp-patch", grasp_radius=0.02)
    d = ro.vertices[-1] - base.vertices[-1]
    assert 3.0 < d[:, 2].mean() * 100 < 4.5 and -2.5 < d[:, 1].mean() * 100 < -1.3, d.mean(0)
    full = _run("grasp-patch", grasp_radius=0.07)
    rest = full.vertices[0, [1, 5]] - full.vertices[0, 0]
    np.testing.assert_allclose(full.vertices[:, [1, 5]] - full.vertices[:, [0]], np.broadcast_to(rest, (11, 2, 3)),
                               atol=0.002)
