"""Tests of softsbi.backends.scenarios (lift scenario derivation from the DiffCloud data)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from softsbi.backends import scenarios as S
from softsbi.core.errors import DataError

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
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
    out = S.overlay_png(sc, r, np.random.default_rng(0).normal(size=(100, 3)) * 0.1, tmp_path / "o.png")
    assert out.is_file() and out.stat().st_size > 10_000
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
