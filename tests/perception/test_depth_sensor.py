"""The virtual depth sensor (softsbi.perception.depth_sensor): rendering, back-projection, occlusion,
robot mask, crop, calibration errors, and the DiffCloud lift frames."""
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from softsbi.core.camera import Camera
from softsbi.core.errors import DataError
from softsbi.perception.depth_sensor import VirtualDepthSensor, rasterize_depth
from softsbi.perception.pointcloud import sample_surface

pytestmark = pytest.mark.integration

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "diffcloud_lift"
OPEN = ((-np.inf,) * 3, (np.inf,) * 3)


def grid_square(side: float, z: float, n: int = 5, centre=(0.0, 0.0)):
    """A flat square mesh ``(n*n, 3)`` vertices, ``(2 (n-1)^2, 3)`` faces, side ``side`` m at height ``z``."""
    x = np.linspace(-side / 2, side / 2, n)
    X, Y = np.meshgrid(x + centre[0], x + centre[1])
    v = np.stack([X.ravel(), Y.ravel(), np.full(n * n, z)], axis=1)
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            f += [(a, a + 1, a + n), (a + 1, a + n + 1, a + n)]
    return v, np.array(f)


def down_camera(height=1.0, size=(160, 120)):
    return Camera.look_at((0, 0, height), (0, 0, 0), up=(0, 1, 0), fovy_deg=40, width=size[0], height=size[1])


def sensor(cams, **kw):
    kw.setdefault("crop_min", OPEN[0])
    kw.setdefault("crop_max", OPEN[1])
    kw.setdefault("crop_clearance", 0.0)
    kw.setdefault("mask_radius", 0.0)
    kw.setdefault("outlier_k", 0)
    kw.setdefault("n_points", 0)
    return VirtualDepthSensor(tuple(cams), **kw)


def test_flat_square_is_fully_seen_and_back_projects_onto_itself():
    cam = down_camera()
    v, f = grid_square(0.3, 0.1)
    s = sensor([cam])
    cloud = s.observe(v, f, None, np.random.default_rng(0))
    footprint = 0.9 / cam.fy  # one pixel at 0.9 m depth, m
    assert np.allclose(cloud[:, 2], 0.1, atol=1e-9)  # on the plane
    assert np.all(np.abs(cloud[:, :2]) <= 0.15 + 1e-9)  # inside the square
    # the pixel count is the square's area in pixels (within a one-pixel border)
    px = (0.3 / footprint) ** 2
    assert abs(len(cloud) - px) < 4 * 0.3 / footprint + 4
    # every surface point has a back-projected pixel within a pixel's half-diagonal (one pixel's
    # diagonal at the square's border, where the nearest pixel centre inside may be a pixel away)
    surf = sample_surface(v, f, 2000, np.random.default_rng(1))
    d, _ = cKDTree(cloud).query(surf)
    inner = np.abs(surf[:, :2]).max(axis=1) < 0.15 - footprint
    assert d[inner].max() < 0.75 * footprint and d.max() < 1.5 * footprint
    assert s.seen(surf, v, f, None).all()


def test_square_under_another_is_occluded():
    cam = down_camera()
    v1, f1 = grid_square(0.2, 0.1)
    v2, f2 = grid_square(0.3, 0.2)
    v = np.concatenate([v1, v2])
    f = np.concatenate([f1, f2 + len(v1)])
    s = sensor([cam])
    cloud = s.observe(v, f, None, np.random.default_rng(0))
    assert len(cloud) > 100 and np.allclose(cloud[:, 2], 0.2, atol=1e-9)
    assert not s.seen(sample_surface(v1, f1, 500, np.random.default_rng(2)), v, f, None).any()
    # seen from the side of the stack (a second camera) the lower square shows again
    side = Camera.look_at((1.0, 0, 0.15), (0, 0, 0.15), up=(0, 0, 1), fovy_deg=40, width=160, height=120)
    tilted = v.copy()
    tilted[: len(v1), 0] += 0.3  # move the lower square out from under the upper one
    assert (np.abs(sensor([cam, side]).observe(tilted, f, None, np.random.default_rng(0))[:, 2] - 0.1) < 1e-9).any()


def test_crop_removes_points_below_the_plane():
    cam = down_camera()
    v, f = grid_square(0.3, 0.0)
    v[:, 2] = 0.1 + 0.5 * v[:, 0]  # a ramp from z 0.025 to 0.175 m
    s = sensor([cam], crop_min=(-np.inf, -np.inf, 0.08), crop_clearance=0.01)
    cloud = s.observe(v, f, None, np.random.default_rng(0))
    full = sensor([cam]).observe(v, f, None, np.random.default_rng(0))
    assert cloud[:, 2].min() >= 0.09 and len(cloud) > 100
    assert (full[:, 2] < 0.09).sum() == len(full) - len(cloud)


def test_gripper_mask_removes_a_disc_and_subsampling_draws_n_points():
    cam = down_camera()
    v, f = grid_square(0.3, 0.1)
    s = sensor([cam], mask_radius=0.03, mask_lift=0.0)
    cloud = s.observe(v, f, np.array([0.0, 0.0, 0.1]), np.random.default_rng(0))
    r = np.linalg.norm(cloud[:, :2], axis=1)
    assert r.min() > 0.025 and r.min() < 0.04  # a hole of about the sphere's radius
    s3 = sensor([cam], n_points=3500)
    assert s3.observe(v, f, None, np.random.default_rng(0)).shape == (3500, 3)
    assert sensor([cam], crop_min=(-np.inf, -np.inf, 1.0)).observe(v, f, None, np.random.default_rng(0)).shape == (0, 3)


def test_rasterized_depth_matches_the_plane():
    cam = down_camera()
    v, f = grid_square(0.3, 0.1)
    d = rasterize_depth(cam, v, f)
    assert np.allclose(d[np.isfinite(d)], 0.9)
    assert np.isinf(d[0, 0])  # outside the square


def test_bad_calibration_gives_one_clear_line(tmp_path):
    with pytest.raises(DataError) as e:
        VirtualDepthSensor.from_calibration([tmp_path / "nope"])
    assert "nope" in str(e.value) and "\n" not in str(e.value)
    bad = tmp_path / "calib"
    bad.mkdir()
    np.save(bad / "intrinsics.npy", np.ones(3))
    np.save(bad / "trc.npy", np.eye(4)[:3])
    with pytest.raises(DataError) as e:
        VirtualDepthSensor.from_calibration([bad])
    assert "intrinsics" in str(e.value) and "(4,)" in str(e.value) and "\n" not in str(e.value)  # file, shape
    with pytest.raises(DataError):
        VirtualDepthSensor(())


@pytest.mark.skipif(not (DATA / "calib_overhead").is_dir(), reason="needs ../shared/data/diffcloud_lift")
def test_diffcloud_lift_frames_real_points_project_into_both_cameras_and_flat_cloth_is_unseen():
    from softsbi.scenarios.builtin import lift_scenario, load_recording
    rec = DATA / "lift_tan"
    s = VirtualDepthSensor.for_diffcloud_recording(rec)
    real = load_recording(rec)[24]
    for cam, (c0, c1) in zip(s._scene_cams, s.columns):
        uv, z = cam.project(real)
        inside = (z > 0) & (uv[:, 0] >= c0) & (uv[:, 0] < c1) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        assert inside.mean() > 0.99
    # the crop plane maps onto the scenario's table (robot z 0.075 m -> lift frame)
    sc = lift_scenario(rec)
    assert abs(s._lo[2] - s.crop_clearance - 0.075) < 1e-12
    plane = (np.array([0.7, 0.1, 0.075, 1.0]) @ np.linalg.inv(s.scene_to_robot).T)[2]
    assert abs(plane - sc.table_z) < 1e-4
    v, f = grid_square(0.25, sc.table_z + 0.003, centre=sc.gripper[0, :2] + np.array([0.0, -0.12]))
    assert s.observe(v, f, sc.gripper[0], np.random.default_rng(0)).shape == (0, 3)
    v[:, 2] += 0.05  # the same cloth 5 cm up is seen
    assert s.observe(v, f, None, np.random.default_rng(0)).shape == (3500, 3)


def test_statistical_outlier_filter_removes_an_isolated_point():
    from softsbi.perception.depth_sensor import statistical_outliers
    g = np.stack(np.meshgrid(np.arange(20), np.arange(20), [0.0]), -1).reshape(-1, 3) * 0.01
    pts = np.vstack([g, [[1.0, 1.0, 1.0]]])
    out = statistical_outliers(pts, 8, 0.5)
    assert out[-1] and out.mean() < 0.3
    assert not statistical_outliers(pts, 0, 0.5).any()


def test_sensor_json_round_trip_and_camera_chamfer_fallback():
    from softsbi.perception.depth_sensor import camera_chamfer_per_frame
    cam = down_camera()
    s = sensor([cam], crop_min=(-np.inf, -np.inf, 0.05), mask_radius=0.02)
    s2 = VirtualDepthSensor.from_json(s.to_json())
    v, f = grid_square(0.3, 0.1)
    np.testing.assert_array_equal(s.observe(v, f, np.zeros(3), np.random.default_rng(0)),
                                  s2.observe(v, f, np.zeros(3), np.random.default_rng(0)))
    flat = v.copy()
    flat[:, 2] = 0.0  # below the crop: nothing seen, the highest 10% of the surface samples stand in
    V = np.stack([v, flat])
    surf = [sample_surface(x, f, 200, np.random.default_rng(1)) for x in V]
    meas = [v[:, :] + [0, 0, 0.01], flat + [0, 0, 0.02]]
    bi, one = camera_chamfer_per_frame(s, V, f, None, meas, surf, np.random.default_rng(0))
    from softsbi.core.metrics import chamfer_terms
    stand_in = surf[1][np.argsort(surf[1][:, 2])[-20:]]
    sm, ms = chamfer_terms(stand_in, meas[1])
    assert one[0] == pytest.approx(0.01, abs=0.004)  # the seen square vs the same square 1 cm up
    assert one[1] == pytest.approx(ms) and bi[1] == pytest.approx(0.5 * (sm + ms))
    with pytest.raises(DataError):
        VirtualDepthSensor.from_json({"cameras": []})


def test_views_or_highest_keeps_seen_views_and_stands_in_the_highest_tenth_for_an_empty_one():
    from softsbi.core.errors import ShapeError
    from softsbi.perception.depth_sensor import views_or_highest
    rng = np.random.default_rng(0)
    seen = rng.random((5, 3))
    surface = [rng.random((40, 3)), rng.random((40, 3))]
    out = views_or_highest([seen, np.zeros((0, 3))], surface)
    assert out[0] is seen  # a view with points is used as the sensor made it
    top = np.sort(surface[1][:, 2])[-4:]  # 10% of 40 points, the highest
    np.testing.assert_array_equal(np.sort(out[1][:, 2]), top)
    with pytest.raises(ShapeError, match="frame counts differ"):
        views_or_highest([seen], surface)


@pytest.mark.skipif(not (DATA / "calib_overhead").is_dir(), reason="needs ../shared/data/diffcloud_lift")
def test_the_sensor_in_the_shared_lift_task_sees_what_it_sees_in_the_recordings_own_lift():
    from softsbi.scenarios.builtin import lift_scenario, lift_task
    from softsbi.workflows.api import simulate
    own = lift_scenario(DATA / "lift_tan", n_frames=4)
    task, shift = lift_task(DATA / "lift_tan", n_frames=4)
    a, b = simulate(own, {"yaw": 8.0}, grid=5), simulate(task, {"yaw": 8.0}, grid=5)
    mine = VirtualDepthSensor.for_diffcloud_recording(DATA / "lift_tan", n_points=0)
    shared = VirtualDepthSensor.for_diffcloud_recording(DATA / "lift_tan", n_points=0, scenario=task)
    seen_own = mine.observe_rollout(a.vertices, a.faces, a.gripper, np.random.default_rng(0))
    seen_task = shared.observe_rollout(b.vertices, b.faces, b.gripper, np.random.default_rng(0))
    assert sum(len(c) for c in seen_own) > 100
    for c_own, c_task in zip(seen_own, seen_task):
        np.testing.assert_allclose(c_own + shift, c_task, atol=1e-6)


@pytest.mark.skipif(not (DATA / "calib_overhead").is_dir(), reason="needs ../shared/data/diffcloud_lift")
def test_fit_with_the_camera_sensor_runs_on_a_real_recording(tmp_path):
    import json
    from softsbi.workflows.fit.run import FitConfig, run_fit
    from softsbi.workflows.measurement import load_recording
    from softsbi.workflows.fit.runs import load_run
    meas = load_recording(DATA / "lift_tan", n_points=16, n_dense=200)
    cfg = FitConfig(backend="mujoco-flex", backend_options={"grid": 5}, estimator="rkhs", rounds=1,
                    sims_per_round=10, n_eval=2, n_points=16, n_dense=200, workers=1, seed=0, sensor="camera",
                    fixed={"bend": 3e-5, "stretch": 70.0, "friction": 0.8, "mass": 0.22},
                    estimator_options={"max_epochs": 5, "hidden": [16, 16]})
    run_fit(tmp_path / "run", meas, cfg, make_plots=False)
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["metric_sensor"] == "camera" and rep["metric_min_z_m"] is None
    per_frame = np.array(rep["chamfer_posterior_per_frame_m"])
    assert per_frame.shape == (25,) and np.all(np.isfinite(per_frame)) and 0 < rep["chamfer_posterior_m"] < 0.2
    # re-simulating the fit's evaluation samples through its stored context reproduces its camera metric
    view = load_run(tmp_path / "run", n_eval=2)
    renders = []
    inner = VirtualDepthSensor._camera_points
    with pytest.MonkeyPatch.context() as mp:  # count the sensor's renders (workers=1 runs in this process)
        mp.setattr(VirtualDepthSensor, "_camera_points", lambda self, *a: renders.append(1) or inner(self, *a))
        ok, _ = view.posterior_rollouts(workers=1)
    assert len(ok) == 2
    assert len(renders) == 2 * 25  # the observer and the metric share one render per frame (shared_renders)
    np.testing.assert_allclose(np.mean([r.chamfer for r in ok], axis=0), per_frame, rtol=1e-12)
    # check's and diagnose's summaries see the rollouts through the same virtual sensor, on the fit's frames:
    # the cloth still on the table is unseen, so they differ from the full surface's
    from softsbi.workflows.criticism.stats import rollout_features, run_frames, sampled_points
    from softsbi.workflows.criticism.statistics import FEATURE_NAMES, trajectory_features
    frames = run_frames(view)
    f_cam = rollout_features(view, ok[0], 5)
    f_full = trajectory_features(sampled_points(ok[0].vertices, ok[0].faces, view.dense.shape[1], 5),
                                 None, frames)
    assert f_cam.shape == f_full.shape == (len(frames) * len(FEATURE_NAMES),) and np.all(np.isfinite(f_cam))
    assert np.abs(f_cam - f_full).max() > 0.01  # what the camera sees is not the whole cloth
    np.testing.assert_array_equal(rollout_features(view, ok[0], 5), f_cam)  # seeded
    with pytest.raises(Exception, match="sensor must be"):
        FitConfig(sensor="lidar").validate()


def test_pointcloud_observer_draws_from_the_camera_view():
    from softsbi.core.types import Rollout
    from softsbi.perception.pointcloud import PointCloudObserver
    cam = down_camera()
    s = sensor([cam], crop_min=(-np.inf, -np.inf, 0.05), outlier_k=0)
    v, f = grid_square(0.3, 0.1)
    hidden_v, hidden_f = grid_square(0.1, 0.0)  # a small square on the "table", below the crop
    V = np.stack([np.concatenate([v, hidden_v]), np.concatenate([v - [0, 0, 0.1], hidden_v])])
    F = np.concatenate([f, hidden_f + len(v)])
    ro = Rollout(times=np.array([0.0, 0.1]), gripper=np.zeros((2, 3)), vertices=V, faces=F)
    obs = PointCloudObserver(n_points=32, camera=s.to_json()).observe(ro, np.random.default_rng(0))
    assert np.allclose(obs.points[0][:, 2], 0.1)  # only the seen square, never the one under the crop
    assert obs.points[1][:, 2].max() <= 0.0 + 1e-12  # nothing seen: the highest surface samples stand in


def test_shared_renders_render_each_frame_once_and_keep_the_draws():
    cam = down_camera()
    v, f = grid_square(0.3, 0.1)
    V = np.stack([v, v + [0.0, 0.0, 0.05]])
    s = sensor([cam], mask_radius=0.02, n_points=500)
    g = np.zeros((2, 3))
    plain = [s.observe_rollout(V, f, g, np.random.default_rng(3)) for _ in range(2)]
    calls = []
    inner = VirtualDepthSensor._camera_points
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(VirtualDepthSensor, "_camera_points", lambda self, *a: calls.append(1) or inner(self, *a))
        with s.shared_renders():
            shared = [s.observe_rollout(V, f, g, np.random.default_rng(3)) for _ in range(2)]
            moved = s.observe(V[0] + [0.01, 0.0, 0.0], f, g[0], np.random.default_rng(3))  # another frame
            with s.shared_renders():  # nested: still shared
                s.observe(V[1], f, g[1], np.random.default_rng(0))
        assert len(calls) == 3  # two frames, then the moved one; the repeats reuse the renders
        s.observe(V[0], f, g[0], np.random.default_rng(0))
        assert len(calls) == 4  # outside the block nothing is kept
    # the same rng draws as rendering every time: identical clouds
    for a, b in zip(plain, shared):
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)
    assert not np.array_equal(moved, shared[0][0])
    assert not s._shared["memo"] and s._shared["depth"] == 0
