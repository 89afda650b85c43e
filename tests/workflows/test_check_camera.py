"""Issue 17: check, diagnose's region errors and compare of a fit through the virtual depth sensor
(``FitConfig.sensor = "camera"``) see the simulated cloth as that sensor does."""
import warnings
from pathlib import Path

import numpy as np
import pytest

from softsbi.core.camera import Camera
from softsbi.perception.depth_sensor import VirtualDepthSensor
from softsbi.workflows.criticism.check import material_regions, region_errors, surface_points
from softsbi.core.defaults import CheckSettings

pytestmark = pytest.mark.integration

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "diffcloud_lift"
needs_data = pytest.mark.skipif(not (DATA / "calib_overhead").is_dir(), reason="needs ../shared/data/diffcloud_lift")


def _grid(n=9, side=0.3):
    """A flat square cloth ``(n*n, 3)`` on the table (z = 0) and its ``(2 (n-1)^2, 3)`` faces."""
    x = np.linspace(0, side, n)
    X, Y = np.meshgrid(x, x)
    v = np.stack([X.ravel(), Y.ravel(), np.zeros(n * n)], axis=1)
    f = [(i * n + j, i * n + j + 1, i * n + j + n) for i in range(n - 1) for j in range(n - 1)]
    f += [(i * n + j + 1, i * n + j + n + 1, i * n + j + n) for i in range(n - 1) for j in range(n - 1)]
    return v, np.array(f)


def test_camera_region_errors_leave_out_the_cloth_lying_flat():
    flat, faces = _grid()
    lifted = flat.copy()
    lifted[:, 2] = np.maximum(0.15 - flat[:, 1], 0.0)  # one edge raised, the rest on the table
    verts = np.stack([flat, lifted])
    cam = Camera.look_at((0.15, 0.4, 1.0), (0.15, 0.15, 0.0), up=(0, 1, 0), fovy_deg=30, width=160, height=120)
    # the crop plane 1 cm above the table hides the cloth lying on it, as DiffCloud's crop hides the real one
    sensor = VirtualDepthSensor((cam,), crop_min=(-np.inf, -np.inf, 0.01), crop_max=(np.inf,) * 3,
                                crop_clearance=0.0, mask_radius=0.0, n_points=0)
    measured = [sensor.observe(v, faces, None, np.random.default_rng(0)) for v in verts]
    assert len(measured[0]) == 0 and len(measured[1]) > 100
    measured[0] = lifted[lifted[:, 2] > 0.01]  # frame 0: the sensor saw nothing; some cloud to compare with
    labels, names = material_regions(flat, np.array([0.15, 0.0, 0.0]))
    full = region_errors(verts, faces, labels, measured, len(names))
    seen = region_errors(verts, faces, labels, measured, len(names), camera=sensor)
    pts = surface_points(verts, faces)[1]
    lab = np.concatenate([labels, labels[faces[:, 0]]])
    low = np.array([pts[lab == r, 2].max() <= 0.01 for r in range(len(names))])  # regions wholly on the table
    assert low.any() and (~low).any()
    # frame 1: the regions on the table are not compared; the full clouds blame them by their distance to
    # the raised edge; what the camera sees of the raised edge matches its own cloud to a fraction of a cm
    assert np.isnan(seen[1, low]).all() and np.all(full[1, low] > 0.02)
    assert np.isfinite(seen[1, ~low]).all() and np.nanmax(seen[1]) < 0.01
    part = ~low & (full[1] > seen[1] + 0.005)  # regions partly on the table: only their lifted part is compared
    assert part.any()
    # frame 0: nothing seen; the highest surface points stand in (the metric's fallback), so some region is defined
    assert np.isfinite(seen[0]).any() and np.isnan(seen[0]).any()
    with pytest.raises(Exception, match="one sensor model"):
        region_errors(verts, faces, labels, measured, len(names), min_z=0.01, camera=sensor)


@pytest.fixture(scope="module")
def lift_runs(tmp_path_factory):
    """Small fits of lift_tan: through the camera (seed 0), and two with ``sensor="height"`` and no height cut
    (``min_height=0``, seeds 0 and 1): their metric_min_z is None like the camera fit's, so only the sensor
    kind tells the camera fit apart from them."""
    from softsbi.workflows.fit.run import FitConfig, run_fit
    from softsbi.workflows.measurement import load_recording
    tmp = tmp_path_factory.mktemp("camfit")
    meas = load_recording(DATA / "lift_tan", n_points=16, n_dense=200)
    runs = {}
    for name, sensor, seed, min_h in (("camera", "camera", 0, None), ("height", "height", 0, 0.0),
                                      ("height2", "height", 1, 0.0)):
        cfg = FitConfig(backend="mujoco-flex", backend_options={"grid": 5}, estimator="rkhs", rounds=1,
                        sims_per_round=10, n_eval=6, n_points=16, n_dense=200, workers=1, seed=seed, sensor=sensor,
                        min_height=min_h,
                        fixed={"bend": 3e-5, "stretch": 70.0, "friction": 0.8, "mass": 0.22},
                        estimator_options={"max_epochs": 5, "hidden": [16, 16]})
        run_fit(tmp / name, meas, cfg, make_plots=False)
        runs[name] = tmp / name
    return runs


@pytest.mark.slow
@needs_data
def test_check_of_a_camera_fit_compares_what_the_camera_sees(lift_runs):
    from softsbi.workflows.criticism.check import check_run, rollout_region_errors, run_sensor, sensor_model
    from softsbi.workflows.fit.runs import load_run
    from softsbi.workflows.criticism.stats import sampled_points
    view = load_run(lift_runs["camera"], n_eval=6)
    sensor = run_sensor(view)
    assert sensor is not None and sensor_model(view)["kind"] == "camera"
    assert run_sensor(load_run(lift_runs["height"], n_eval=6)) is None
    ok, _ = view.posterior_rollouts(workers=1)
    labels, names = material_regions(ok[0].vertices[0], view.scenario.gripper[0])
    lab = np.concatenate([labels, labels[ok[0].faces[:, 0]]])
    table = view.scenario.table_z
    hidden = 0
    for r in ok:
        cam = rollout_region_errors(view, r, labels, len(names), view.dense)
        full = region_errors(r.vertices, r.faces, labels, view.dense, len(names))
        pts = surface_points(r.vertices, r.faces)
        for t in range(len(pts)):
            if not sensor.seen(pts[t], r.vertices[t], r.faces, r.gripper[t]).any():
                continue  # nothing seen: the metric's fallback (highest points) stands in
            # a region lying on the table (below the crop plane) is not compared; the full clouds compare it
            low = np.array([pts[t][lab == k, 2].max() < table + 0.004 for k in range(len(names))])
            assert np.isnan(cam[t, low]).all() and np.isfinite(full[t, low]).all()
            hidden += int(low.sum())
        assert np.isfinite(cam[-1]).all()  # the cloth hanging at the end: every region is seen
    assert hidden > 0  # the lift's early frames have cloth lying on the table
    # check's region errors are these, averaged over its rollouts (the same samples and seeds)
    # a level the 6-rollout null resolves (2/7 <= 0.5): the test is not what this checks
    chk = check_run(lift_runs["camera"], plot=False, settings=CheckSettings(n_eval=6, workers=1, alpha=0.5, max_null=6))
    assert chk.metric_sensor == "camera"
    reg = np.array([rollout_region_errors(view, r, labels, len(names), view.dense) for r in ok])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # (frame, region) pairs no rollout's camera sees
        mean = np.nanmean(reg, axis=0)
    np.testing.assert_allclose(chk.region_error_m, np.nan_to_num(mean), rtol=1e-12)
    compared = np.array(chk.region_compared)
    assert np.array_equal(compared, np.isfinite(mean)) and not compared.all()  # unseen cells are flagged, not 0 cm
    # diagnose's null: another rollout stands in for the measurement, seen through the same camera, so its
    # cloth lying on the table is not blamed on the regions the camera sees
    r, o = ok[0], ok[1]
    other = sampled_points(o.vertices, o.faces, view.dense.shape[1], 1000 + o.sample)
    through = rollout_region_errors(view, r, labels, len(names), other, o)
    raw = rollout_region_errors(view, r, labels, len(names), other)
    mid = slice(8, 15)  # the cloth partly lifted
    assert np.nanmean(through[mid]) < np.nanmean(raw[mid])
    assert np.array_equal(np.isnan(through[mid]), np.isnan(raw[mid]))  # same simulated side, same regions
    # diagnose's residual shape runs through this path on a camera fit
    from softsbi.workflows.criticism.check import residual_shape
    from softsbi.workflows.criticism.stats import PosteriorPredictive
    shape = residual_shape(view, PosteriorPredictive(view, workers=1).ensure(6), 6)
    exc = shape.region_excess_cm
    assert list(exc) == names and any(v is not None and np.isfinite(v) for v in exc.values())


@pytest.mark.slow
@needs_data
def test_compare_warns_when_the_sensor_kind_differs(lift_runs, tmp_path):
    from softsbi.report.text import compare_summary
    from softsbi.workflows.criticism.compare import compare_runs
    warn = "different sensor models (--sensor / --min-height / --frames)"
    # compare checks at the default level 0.05, which needs a null cap of at least 39
    mixed = compare_runs(
        lift_runs["height"],
        lift_runs["camera"],
        tmp_path / "mixed",
        settings=CheckSettings(n_eval=6, workers=1, max_null=39),
    )
    assert not mixed.same_sensor and warn in compare_summary(mixed)
    assert mixed.check_a.metric_sensor == "none" and mixed.check_b.metric_sensor == "camera"  # no height cut
    same = compare_runs(
        lift_runs["height"],
        lift_runs["height2"],
        tmp_path / "same",
        settings=CheckSettings(n_eval=6, workers=1, max_null=39),
    )
    assert same.same_sensor
    assert (tmp_path / "same" / "compare.png").is_file()
