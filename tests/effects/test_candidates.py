"""The built-in candidate effects: off at their nominal values, and each changes the rollout in the
direction its docstring states (mujoco-flex, 5x5 cloth, 11 frames)."""
from __future__ import annotations

import numpy as np
import pytest

from softsbi.backends.mujoco_flex import MujocoFlex
from softsbi.effects.generic import GENERIC_EFFECTS
from softsbi.effects.material import MATERIAL_EFFECTS
from softsbi.effects.physics import PHYSICS_EFFECTS, TableSlope
from softsbi.effects.rig import RIG_EFFECTS
from softsbi.effects.robot import ROBOT_EFFECTS
from softsbi.effects.sensor import SENSOR_EFFECTS
from softsbi.plugins import registry
from softsbi.scenarios.builtin import lift_scenario, wipe_scenario

SIM = MujocoFlex(grid=5)
LIFT = lift_scenario(None, n_frames=11)
WIPE = wipe_scenario(n_frames=11)  # dragged from (0, 0) to (0.3, 0.15): drag along +x


def _run(sc, effects=(), seed=0, **values):
    theta = {**SIM.param_space(sc).midpoint(), **values}
    for e in effects:
        theta = {**registry().effect(e)().nominal(), **theta}
    ro = SIM.simulate(sc, theta, effects=list(effects), seed=seed)
    assert ro.ok, ro.reason
    return ro


@pytest.fixture(scope="module")
def base():
    return {
        "lift": _run(LIFT).vertices,
        "wipe": _run(WIPE).vertices,
        "wipe_slippery": _run(WIPE, friction=0.1).vertices,
    }


def test_all_registered_with_kinds():
    reg = registry()
    for cls in PHYSICS_EFFECTS + ROBOT_EFFECTS + SENSOR_EFFECTS + GENERIC_EFFECTS + MATERIAL_EFFECTS + RIG_EFFECTS:
        assert reg.effect(cls.name) is cls
        # documented, and switched off (Effect.nominal) at a value of each of its parameters that its prior holds
        off, params = cls().nominal(), cls().param_space().params
        assert cls.__doc__ and set(off) == {p.name for p in params}, cls.name
        assert all(p.low <= off[p.name] <= p.high for p in params), cls.name
    assert {c.kind for c in SENSOR_EFFECTS + RIG_EFFECTS} == {"sensor"}
    assert {c.kind for c in PHYSICS_EFFECTS + ROBOT_EFFECTS + GENERIC_EFFECTS + MATERIAL_EFFECTS} == {"physics"}
    assert all(c.generic for c in GENERIC_EFFECTS)
    assert not any(c.generic for c in PHYSICS_EFFECTS + ROBOT_EFFECTS + SENSOR_EFFECTS + MATERIAL_EFFECTS + RIG_EFFECTS)


def test_a_fit_passes_the_estimator_the_options_its_effects_ask_for_and_the_users_win():
    from softsbi.inference.estimators import MDNNEstimator, RKHSEstimator
    from softsbi.workflows.fit.run import FitConfig, estimator_options
    assert registry().effect("point-noise").estimator_options == {"frame_thickness": True}
    assert estimator_options(FitConfig(effects=["wind", "point-noise"]), RKHSEstimator) == {"frame_thickness": True}
    assert estimator_options(FitConfig(effects=["wind"]), RKHSEstimator) == {}
    # an estimator without the option gets nothing it would refuse; the user's setting wins
    assert estimator_options(FitConfig(effects=["point-noise"]), MDNNEstimator) == {}
    mine = FitConfig(effects=["point-noise"], estimator_options={"frame_thickness": False, "ensemble": 1})
    assert estimator_options(mine, RKHSEstimator) == {"frame_thickness": False, "ensemble": 1}


@pytest.mark.parametrize("cls", PHYSICS_EFFECTS + ROBOT_EFFECTS + SENSOR_EFFECTS + GENERIC_EFFECTS + MATERIAL_EFFECTS
                         + RIG_EFFECTS, ids=lambda c: c.name)
def test_nominal_is_the_nominal_model(cls, base):
    ro = _run(LIFT, [cls.name], seed=3, **cls().nominal())
    assert np.array_equal(ro.vertices, base["lift"])


def test_heavy_hem_lowers_the_hanging_cloth(base):
    v = _run(LIFT, ["heavy-hem"], hem_density=0.05).vertices
    assert (v[-1, :, 2] - base["lift"][-1, :, 2]).mean() < -0.005


@pytest.mark.parametrize("slope_y,sign", [(10.0, 1.0), (-10.0, -1.0)])
def test_table_slope_pulls_the_dragged_cloth_downhill(base, slope_y, sign):
    v = _run(WIPE, ["table-slope"], slope_x=0.0, slope_y=slope_y).vertices
    assert sign * (v[-1, :, 1] - base["wipe"][-1, :, 1]).mean() > 0.01


def test_table_slope_is_one_force_in_its_two_components():
    """A tilt along x and y together is the tilt of their combined gradient: downhill along it, with
    magnitude m g sin(alpha), tan(alpha) = |gradient| (5 deg along x and y: alpha = 7.06 deg)."""
    from types import SimpleNamespace
    ctx = SimpleNamespace(x0=np.zeros((2, 3)), table_z=0.0, gravity=np.array([0.0, 0.0, -9.81]), mass=np.ones(2))
    f = TableSlope().force(np.zeros((2, 3)), np.zeros((2, 3)), 0.0, {"slope_x": 5.0, "slope_y": 5.0}, ctx)
    a = np.arctan(np.hypot(np.tan(np.radians(5.0)), np.tan(np.radians(5.0))))
    np.testing.assert_allclose(f[0, :2], 9.81 * np.sin(a) / np.sqrt(2) * np.ones(2), rtol=1e-12)
    np.testing.assert_allclose(f[0, 2], 9.81 * (1 - np.cos(a)), rtol=1e-12)
    assert np.degrees(a) == pytest.approx(7.06, abs=0.01)


def test_sticky_patch_holds_the_dragged_cloth_back(base):
    v = _run(WIPE, ["sticky-patch"], friction=0.1, patch_friction=1.5, patch_radius=0.2).vertices
    assert (v[-1, :, 0] - base["wipe_slippery"][-1, :, 0]).mean() < -0.002


def test_calibration_offset_shifts_the_observed_cloud_only(base):
    ro = _run(LIFT, ["calibration-offset"], offset_x=0.01, offset_y=-0.02, offset_z=0.005)
    np.testing.assert_allclose(ro.vertices - base["lift"], np.broadcast_to([0.01, -0.02, 0.005], ro.vertices.shape),
                               atol=1e-12)
    np.testing.assert_array_equal(ro.gripper, _run(LIFT).gripper)


def test_point_noise_has_its_std_and_is_seeded(base):
    a = _run(LIFT, ["point-noise"], seed=1, noise_std=0.005).vertices
    b = _run(LIFT, ["point-noise"], seed=1, noise_std=0.005).vertices
    c = _run(LIFT, ["point-noise"], seed=2, noise_std=0.005).vertices
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert abs(np.std(a - base["lift"]) - 0.005) < 0.0005  # 11 x 25 x 3 = 825 draws: 2.5% std error


def test_time_offset_shows_the_lift_ahead(base):
    ro = _run(LIFT, ["time-offset"], time_offset=0.05)
    dt = LIFT.times[1] - LIFT.times[0]
    w = 0.05 / dt - np.floor(0.05 / dt)
    k = int(np.floor(0.05 / dt))
    expect = (1 - w) * base["lift"][3 + k] + w * base["lift"][4 + k]
    np.testing.assert_allclose(ro.vertices[3], expect, atol=1e-12)
    assert ro.vertices[5, :, 2].mean() > base["lift"][5, :, 2].mean()  # rising cloth seen later in its rise
    np.testing.assert_allclose(ro.vertices[-1], base["lift"][-1], atol=1e-12)  # held at the last frame


def test_table_unseen_hides_the_cloth_near_the_table_from_observer_metric_and_measurement(base):
    """table-unseen moves no vertex; the observer, the metric, the synthetic measurement and check's
    summaries see only points above the resting cloth + unseen_height (the highest 10% where none is)."""
    from softsbi.perception.pointcloud import PointCloudObserver, rollout_clouds
    from softsbi.workflows.measurement import simulate_recording
    from softsbi.workflows.criticism.statistics import FEATURE_NAMES, trajectory_features
    h = 0.02
    ro = _run(LIFT, ["table-unseen"], unseen_height=h)
    np.testing.assert_array_equal(ro.vertices, base["lift"])
    z_cut = base["lift"][0, :, 2].min() + h
    assert ro.info["min_visible_z"] == pytest.approx(z_cut)
    x = PointCloudObserver(64).observe(ro, np.random.default_rng(0)).points
    x0 = PointCloudObserver(64).observe(_run(LIFT), np.random.default_rng(0)).points
    mid = 5  # partly lifted: part of the cloth still lies on the table
    assert (x[mid, :, 2] > z_cut).all() and (x0[mid, :, 2] <= z_cut).any()
    assert (x[0, :, 2] > z_cut).sum() == 0  # flat cloth: only the fallback (its highest points) stands in
    rec = simulate_recording("mujoco-flex", LIFT, {**SIM.param_space(LIFT).midpoint(), "unseen_height": h},
                             backend_options={"grid": 5}, effects=["table-unseen"], n_points=32, n_dense=200)
    assert rec.dense.shape == (11, 200, 3) and (rec.dense[mid, :, 2] > z_cut).all()
    # summaries: the rollout's threshold adds to the run's own (none here)
    clouds = rollout_clouds(ro, 200, np.random.default_rng(1))
    f_seen = trajectory_features(clouds, z_cut)
    k = len(FEATURE_NAMES)
    assert f_seen[mid * k + 8] > trajectory_features(clouds)[mid * k + 8]  # 50% height quantile rises


def test_table_unseen_adds_to_the_fits_sensor_in_the_job_metric():
    from softsbi.workflows.fit.jobs import JobItem, SimContext, simulate_job
    clouds = rollout_clouds_of(_run(LIFT))
    kw = dict(backend="mujoco-flex", backend_options={"grid": 5}, scenario=LIFT.to_json(), effects=[],
              observer="pointcloud", observer_options={"n_points": 32}, param_names=SIM.param_space(LIFT).names,
              fixed={}, dense=clouds, n_dense=200, keep_rollout=True)
    theta = {**SIM.param_space(LIFT).midpoint(), "unseen_height": 0.02}
    plain = simulate_job(SimContext(**kw), JobItem(SIM.param_space(LIFT).midpoint(), 0, effects=[]))
    hidden = simulate_job(SimContext(**kw), JobItem(theta, 0, effects=["table-unseen"]))
    assert hidden.min_visible_z == pytest.approx(clouds[0][:, 2].min() + 0.02, abs=0.003)
    assert plain.min_visible_z is None
    # the nominal rollout against its own full clouds: close; with the flat cloth unseen: the early frames differ
    assert hidden.chamfer[0] > 2 * plain.chamfer[0]


def rollout_clouds_of(ro):
    from softsbi.perception.pointcloud import rollout_clouds
    return rollout_clouds(ro, 200, np.random.default_rng(7))


@pytest.mark.parametrize("name,values,check", [
    ("generic-constant", {"const_ax": 2.0}, lambda d: d[-1, :, 0].mean() > 0.01),
    ("generic-linear-drag", {"lin_kh": 30.0, "lin_kv": 30.0}, lambda d: d[5, :, 2].mean() < -0.0005),
    ("generic-quadratic-drag", {"quad_c": 20.0}, lambda d: d[5, :, 2].mean() < -0.0002),
    ("generic-height-force", {"height_kz": 20.0}, lambda d: d[-1, :, 2].mean() > 0.001),
])
def test_generic_terms_push_the_stated_way(base, name, values, check):
    v = _run(LIFT, [name], **values).vertices
    assert check(v - base["lift"]), name
