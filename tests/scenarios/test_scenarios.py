"""Tests of softsbi.scenarios.builtin (lift scenario derivation from the DiffCloud data)."""
from __future__ import annotations


import numpy as np
import pytest

from softsbi.scenarios import builtin as S
from softsbi.core.errors import DataError
from toy_helpers import DATA


LIFT = DATA / "diffcloud_lift"
needs_data = pytest.mark.skipif(not (LIFT / "lift_traj.npy").is_file(),
                                reason=f"DiffCloud lift data not found at {LIFT} (../shared/data beside the repo)")
RECORDINGS = sorted(p.name for p in LIFT.glob("lift_*") if p.is_dir()) if LIFT.is_dir() else []


def test_default_scenario_needs_no_files():
    sc = S.lift_scenario(None)
    assert sc.name == "lift"
    assert sc.gripper.shape == (25, 3) and sc.times.shape == (25,)
    np.testing.assert_allclose(sc.times, np.arange(25) * 0.04)
    assert sc.object["kind"] == "cloth"
    assert sc.object["size"] == pytest.approx(0.2777, abs=1e-3)
    np.testing.assert_allclose(sc.object["corner"], sc.gripper[0, :2])
    np.testing.assert_allclose(np.linalg.norm(sc.object["direction"]), 1.0)
    # starts just above the table (3 mm, as recorded), ends ~31 cm higher and ~19 cm back (-y)
    assert 0.0 < sc.gripper[0, 2] - sc.table_z < 0.01
    assert sc.gripper[-1, 2] - sc.gripper[0, 2] == pytest.approx(0.309, abs=0.005)
    assert sc.gripper[-1, 1] - sc.gripper[0, 1] == pytest.approx(-0.192, abs=0.005)
    # the gripper moves back along the cloth diagonal
    step = sc.gripper[-1, :2] - sc.gripper[0, :2]
    assert np.dot(step / np.linalg.norm(step), sc.object["direction"]) > 0.99
    # smooth: starts and ends at rest
    v = np.diff(sc.gripper, axis=0)
    assert np.linalg.norm(v[0]) < 0.2 * np.linalg.norm(v).max()
    assert np.linalg.norm(v[-1]) < 0.2 * np.linalg.norm(v).max()


def test_frames_and_validation():
    sc = S.lift_scenario(None, n_frames=11, frame_dt=0.1)
    assert sc.gripper.shape == (11, 3)
    np.testing.assert_allclose(sc.times[-1], 1.0)
    with pytest.raises(ValueError):
        S.lift_scenario(None, n_frames=1)
    with pytest.raises(ValueError):
        S.lift_scenario(None, frame_dt=0.0)
    with pytest.raises(DataError):
        S.lift_scenario("/nonexistent/lift_tan")


def test_transform_roundtrip():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(50, 3))
    cfg = S.DEFAULT_TRANSFORM
    np.testing.assert_allclose(S.lift_frame_to_real(S.real_to_lift_frame(p, cfg), cfg), p, atol=1e-12)
    np.testing.assert_allclose(S.real_to_lift_frame(p, cfg), S.real_to_sim(p, cfg) * 0.35)
    np.testing.assert_allclose(S.sim_units_to_metres(np.ones((2, 3))), 0.35 * np.ones((2, 3)))
    # Rz(+90): robot +y maps to sim +x, robot +x to sim -y
    d = S.real_to_sim(np.array([[0.0, 0.35, 0.0]]), cfg) - S.real_to_sim(np.zeros((1, 3)), cfg)
    np.testing.assert_allclose(d, [[1.0, 0.0, 0.0]], atol=1e-12)


@needs_data
def test_default_path_close_to_recorded():
    traj = np.load(LIFT / "lift_traj.npy")
    rec = S.real_to_lift_frame(traj, S.recording_transform(LIFT))  # default yaml in the parent folder
    default = S.lift_scenario(None)
    assert np.abs(default.gripper - rec).max() < 0.01
    # and relative to the table, within 1 cm of every recording's commanded path
    for name in RECORDINGS:
        sc = S.lift_scenario(LIFT / name, grasp_offset="none")
        dz = (sc.gripper[:, 2] - sc.table_z) - (default.gripper[:, 2] - default.table_z)
        assert np.abs(dz).max() < 0.01, name


@needs_data
@pytest.mark.parametrize("name", RECORDINGS)
def test_table_z_matches_cloud(name):
    sc = S.lift_scenario(LIFT / name)
    clouds = S.load_recording(LIFT / name)
    assert clouds.shape[1:] == (3500, 3)
    low = np.percentile(clouds[..., 2], 1)
    assert abs(low - sc.table_z) < 0.01, (name, low, sc.table_z)
    # the commanded path starts within 1 cm above the table
    assert 0.0 < sc.gripper[0, 2] - sc.table_z < 0.01


@needs_data
def test_table_height_groups():
    tan = S.lift_scenario(LIFT / "lift_tan")
    red = S.lift_scenario(LIFT / "lift_redblack")
    assert tan.table_z == pytest.approx(S.PLANE_Z_SIM * 0.35, abs=1e-9)  # plane.obj for c_z = -0.02
    assert red.table_z / 0.35 == pytest.approx(0.2142, abs=1e-3)  # c_z = 0 recordings


@needs_data
def test_grasp_offset_places_corner_like_diffcloud():
    cmd = S.lift_scenario(LIFT / "lift_tan", grasp_offset="none")
    sc = S.lift_scenario(LIFT / "lift_tan")
    off = np.asarray(sc.options["grasp_offset_estimate"])
    assert off[:2] == pytest.approx([-0.057, -0.024], abs=0.006)
    np.testing.assert_allclose(sc.gripper[:, 2], cmd.gripper[:, 2])
    # the offset-corrected corner lands on DiffCloud's grasped node 13; the commanded one does not
    assert np.linalg.norm(np.asarray(sc.object["corner"]) - S.ARCSIM_CORNER) < 0.015
    assert np.linalg.norm(np.asarray(cmd.object["corner"]) - S.ARCSIM_CORNER) > 0.04
    # the corrected path passes through the top of the hanging cloth in the last frame
    last = S.load_recording(LIFT / "lift_tan", frames=range(24, 25))[0]
    top = last[np.argsort(last[:, 2])[-35:]].mean(0)
    assert np.linalg.norm(top - sc.gripper[-1]) < np.linalg.norm(top - cmd.gripper[-1])
    assert np.linalg.norm(top[:2] - sc.gripper[-1, :2]) < 0.02


@needs_data
def test_every_lift_recording_lies_in_one_task_moved_by_its_calibration_and_grasp_offsets():
    import json
    from softsbi.workflows.fit.bank import rollout_key
    from softsbi.workflows.fit.config import resume_identity
    tasks = {n: S.lift_task(LIFT / n) for n in RECORDINGS}
    same = {json.dumps(resume_identity("scenario", sc.to_json()), sort_keys=True) for sc, _ in tasks.values()}
    assert len(same) == 1  # one task: the recording's folder is provenance only
    keys = {rollout_key("mujoco-flex", {}, sc.to_json(), [], {"bend": 1e-4}, 0) for sc, _ in tasks.values()}
    assert len(keys) == 1
    for n, (sc, shift) in tasks.items():
        own = S.lift_scenario(LIFT / n)
        # the recording's own lift (its calibration, grasp offset applied) moved rigidly by the translation
        np.testing.assert_allclose(own.gripper + shift, sc.gripper, atol=1e-12, err_msg=n)
        assert own.table_z + shift[2] == pytest.approx(sc.table_z, abs=1e-12)
    # the calibration groups differ by 2 cm of height (compensation z); the grasp offsets move them sideways
    assert {round(float(t[2]), 6) for _, t in tasks.values()} == {0.0, 0.02}
    assert max(np.linalg.norm(t[:2]) for _, t in tasks.values()) > 0.02


@needs_data
def test_a_lift_simulated_in_the_task_is_the_recordings_own_lift_moved():
    from softsbi.workflows.api import simulate
    own = S.lift_scenario(LIFT / "lift_tan", n_frames=6)
    task, shift = S.lift_task(LIFT / "lift_tan", n_frames=6)
    a, b = simulate(own, {"yaw": 8.0}, grid=5), simulate(task, {"yaw": 8.0}, grid=5)
    assert a.status == b.status == 0
    np.testing.assert_allclose(a.vertices + shift, b.vertices, atol=1e-9)


@needs_data
def test_cloth_size_agrees_with_hanging_cloud():
    # the hanging sheet's horizontal extent is about its diagonal (a little less: the side corners
    # sag), so width / sqrt(2) is a lower estimate of the side: it must lie inside the mujoco-flex
    # ``scale`` prior and within 20 % below the nominal DiffCloud size
    from softsbi.backends.mujoco_flex import MujocoFlex
    scale = MujocoFlex().param_space(S.lift_scenario(None))["scale"]
    for name in ("lift_tan", "lift_paper", "lift_paper2"):  # navy/polka: partial last frames
        last = S.load_recording(LIFT / name, frames=range(24, 25))[0]
        side = (np.percentile(last[:, 0], 99.5) - np.percentile(last[:, 0], 0.5)) / np.sqrt(2)
        assert scale.low <= side <= scale.high, name
        assert 0.8 * S.NOMINAL_SIZE <= side <= 1.02 * S.NOMINAL_SIZE, (name, side)


def test_overlay_png(tmp_path):
    from softsbi.core.types import Rollout
    sc = S.lift_scenario(None)
    v = np.zeros((25, 4, 3))
    r = Rollout(times=sc.times, gripper=sc.gripper, vertices=v, faces=np.zeros((0, 3), int))
    from softsbi.report import plot_scenario_overlay
    out = plot_scenario_overlay(sc, r, np.random.default_rng(0).normal(size=(100, 3)) * 0.1, tmp_path / "o.png")
    assert out.is_file() and out.stat().st_size > 10_000
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_placement_yaw_only_for_recordings_and_rotates_the_diagonal():
    from softsbi.backends.mujoco_flex import MujocoFlex
    assert "yaw_bounds" not in S.lift_scenario(None).object
    assert S.placement_params(S.lift_scenario(None)) == []
    sc = S.lift_scenario(None)
    np.testing.assert_allclose(S.placed_direction(sc, {"yaw": 90.0}), [1.0, 0.0], atol=1e-12)  # CCW from above
    np.testing.assert_allclose(S.placed_direction(sc, {}), [0.0, -1.0], atol=1e-12)
    sc.object["yaw_bounds"] = [-45.0, 45.0]
    assert MujocoFlex().param_space(sc).names[-1] == "yaw"
    for bad in ([10.0, -10.0], ["a", 1], [0.0, float("inf")]):
        sc.object["yaw_bounds"] = bad
        with pytest.raises(DataError, match="yaw_bounds"):
            S.placement_params(sc)


@needs_data
def test_placement_yaw_both_backends_place_the_cloth_alike():
    from softsbi.backends.mujoco_flex import MujocoFlex
    from softsbi.backends.pybullet_massspring import PybulletMassSpring
    sc = S.lift_scenario(LIFT / "lift_tan")
    assert sc.object["yaw_bounds"] == list(S.YAW_BOUNDS)
    theta = {"bend": 3e-5, "stretch": 50.0, "friction": 0.5, "scale": 0.25, "mass": 0.2, "yaw": 30.0}
    pb_theta = theta  # one physical meaning per name on both backends (issue 15 item 6)
    starts = []
    for sim, th in ((MujocoFlex(grid=7), theta), (PybulletMassSpring(grid=7), pb_theta)):
        assert sim.param_space(sc).names == ["bend", "stretch", "friction", "scale", "mass", "yaw"]
        v0 = sim.simulate(sc, th).vertices[0]
        far = v0[np.argmax(np.linalg.norm(v0[:, :2] - sc.object["corner"], axis=1))]
        diag = far[:2] - np.asarray(sc.object["corner"])
        starts.append(diag)
        assert np.linalg.norm(diag) == pytest.approx(0.25 * np.sqrt(2), rel=0.03)
        np.testing.assert_allclose(diag / np.linalg.norm(diag), S.placed_direction(sc, theta), atol=0.02)
    np.testing.assert_allclose(starts[0], starts[1], atol=0.01)


@needs_data
def test_lift_tan_early_frames_prefer_a_rotated_placement():
    """The measured reason for ``yaw``: lift_tan's cloth was not laid like DiffCloud's diamond."""
    from softsbi.backends.mujoco_flex import MujocoFlex
    from softsbi.core.metrics import chamfer
    from softsbi.perception.pointcloud import rollout_clouds
    sc = S.lift_scenario(LIFT / "lift_tan")
    real = S.load_recording(LIFT / "lift_tan")
    sim = MujocoFlex(grid=7)
    early = {}
    for yaw in (0.0, 30.0):
        ro = sim.simulate(sc, {"bend": 3e-5, "stretch": 50.0, "friction": 0.7, "scale": 0.25, "mass": 0.24,
                               "yaw": yaw})
        clouds = rollout_clouds(ro, 400, np.random.default_rng(0))
        early[yaw] = np.mean([chamfer(clouds[f], real[f][::4]) for f in range(10)])
    assert early[30.0] < 0.7 * early[0.0]
