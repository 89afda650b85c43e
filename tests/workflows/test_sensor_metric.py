"""Issue 17: one per-frame distance under the fit's sensor model for the report, check and compare."""
import json

import numpy as np
import pytest

from softsbi.core.metrics import chamfer, one_sided_chamfer
from softsbi.perception.pointcloud import sensor_chamfer_per_frame, sensor_view
from softsbi.workflows.criticism.check import check_run
from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording
from softsbi.core.defaults import CheckSettings

pytestmark = pytest.mark.integration

toy = pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")


def _sheet(rng, z0, z1, n=400):
    """A unit-wide sheet of ``n`` points from height z0 to z1 (m)."""
    u = rng.random((n, 2))
    return np.c_[u[:, 0] * 0.2, np.zeros(n), z0 + u[:, 1] * (z1 - z0)]


def test_sensor_view_hides_flat_cloth_for_both_clouds():
    rng = np.random.default_rng(0)
    hanging = _sheet(rng, 0.05, 0.25)
    flat = np.c_[rng.random((400, 2)) * 0.2 + [0.0, 0.05], np.full(400, 0.002)]  # lying on the table (z = 0)
    simulated = np.concatenate([hanging, flat])
    measured = _sheet(rng, 0.05, 0.25)  # the depth sensor never saw the flat part
    full_bi, full_one = sensor_chamfer_per_frame([simulated], [measured], None)
    bi, one = sensor_chamfer_per_frame([simulated], [measured], 0.01)
    assert full_bi[0] == pytest.approx(chamfer(simulated, measured))
    assert one[0] == pytest.approx(one_sided_chamfer(measured, simulated))
    # the flat cloth the sensor cannot see no longer counts against the simulation
    assert bi[0] < 0.4 * full_bi[0]
    assert bi[0] == pytest.approx(chamfer(hanging, measured))
    # the one-sided measured -> simulated half never looked at the flat part
    assert one[0] == pytest.approx(full_one[0])
    # nothing seen: the highest 10% stand in, so the distance stays defined
    seen = sensor_view(flat, 0.01)
    assert len(seen) == 40 and seen[:, 2].min() >= np.sort(flat[:, 2])[-40]


@pytest.fixture(scope="module")
def sensor_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sensor")
    meas = simulate_recording("toy-gauss", toy.toy_scenario(4), {"a": 0.3, "b": -0.2}, n_points=16, n_dense=64,
                              seed=11)
    cfg = FitConfig(backend="toy-gauss", estimator="rkhs", rounds=1, sims_per_round=60, workers=1, n_points=16,
                    n_eval=12, n_dense=64, seed=2, estimator_options={"max_epochs": 20, "hidden": [32, 32]},
                    min_height=0.01, frames=[1, 2, 3])
    run_fit(tmp / "run", meas, cfg, make_plots=False)
    return tmp / "run"


def test_check_reproduces_the_reports_sensor_faithful_numbers(sensor_run):
    rep = json.loads((sensor_run / "report.json").read_text())
    assert rep["metric_min_z_m"] == pytest.approx(0.01) and rep["metric_frames"] == [1, 2, 3]
    per_frame = np.array(rep["chamfer_posterior_per_frame_m"])
    assert len(per_frame) == 4 and np.isfinite(rep["chamfer_posterior_one_sided_m"])
    # a level the 12-rollout null resolves (2/13 <= 0.2): the test is not what this checks
    chk = check_run(sensor_run, plot=False, settings=CheckSettings(n_eval=12, workers=1, alpha=0.2, max_null=12))
    # the same rollouts, the same sensor model, the same frames: exactly the report's number
    assert chk.chamfer_mean_m == rep["chamfer_posterior_m"]
    assert chk.chamfer_one_sided_mean_m == rep["chamfer_posterior_one_sided_m"]
    np.testing.assert_allclose(chk.chamfer.mean, per_frame, rtol=1e-12)
    # the headline is the mean over the fit's frames, not over every frame
    assert rep["chamfer_posterior_m"] != pytest.approx(per_frame.mean(), rel=1e-9)
    assert (chk.metric_sensor, chk.metric_min_z_m, chk.metric_frames) == ("height", pytest.approx(0.01), (1, 2, 3))
    assert [p.in_fit for p in chk.phases] == [False, True, True]
    # the energy score sees the clouds as the metric does: its Chamfer term is the report's number
    assert chk.energy.chamfer_m == pytest.approx(rep["chamfer_posterior_m"])


def test_region_errors_compare_only_what_the_sensor_sees():
    from softsbi.workflows.criticism.check import material_regions, region_errors
    g = np.linspace(0, 0.3, 7)
    xx, yy = np.meshgrid(g, g)
    flat = np.c_[xx.ravel(), yy.ravel(), np.zeros(xx.size)]  # the cloth on the table (z = 0)
    lifted = flat.copy()
    lifted[:, 2] = np.where(flat[:, 1] < 0.1, 0.2 - flat[:, 1], 0.0)  # one edge raised, the rest flat
    verts = np.stack([flat, lifted])  # (T=2, N, 3), no faces: the vertices are the surface points
    labels, names = material_regions(flat, np.zeros(3))
    measured = np.stack([lifted[lifted[:, 2] > 0.01]] * 2)  # the sensor saw the raised edge only
    full = region_errors(verts, np.zeros((0, 3), int), labels, measured, len(names))
    seen = region_errors(verts, np.zeros((0, 3), int), labels, measured, len(names), min_z=0.01)
    # frame 1: the flat regions are not compared (NaN) and the raised ones match the measurement
    raised = np.unique(labels[lifted[:, 2] > 0.01])
    hidden = np.setdiff1d(np.unique(labels), raised)  # regions lying wholly flat
    assert len(hidden) and np.isnan(seen[1, hidden]).all() and np.isfinite(full[1, hidden]).all()
    assert np.nanmax(seen[1]) < 1e-9 < np.nanmax(full[1])
    # frame 0: nothing is seen; the highest points stand in and every value stays finite where defined
    assert np.isfinite(seen[0]).any()


def test_summaries_see_what_the_sensor_sees():
    """The misspecification test's summary statistics use the fit's sensor model (issue 17/19): a
    measurement without the flat cloth matches a simulation that has it, under the sensor model only."""
    from softsbi.workflows.criticism.statistics import FEATURE_FLOOR, FEATURE_NAMES, trajectory_features
    rng = np.random.default_rng(3)
    hanging = _sheet(rng, 0.05, 0.25, 2000)
    flat = np.c_[rng.random((2000, 2)) * 0.2 + [0.0, 0.05], np.full(2000, 0.002)]
    simulated = [np.concatenate([hanging, flat])] * 3
    measured = [_sheet(rng, 0.05, 0.25, 2000)] * 3
    full = np.abs(trajectory_features(simulated) - trajectory_features(measured)) / FEATURE_FLOOR
    seen = np.abs(trajectory_features(simulated, 0.01) - trajectory_features(measured, 0.01)) / FEATURE_FLOOR
    assert full.max() > 10 and seen.max() < 3  # tens of sensor resolutions vs sampling noise
    # frames: only the named ones, in order
    assert trajectory_features(simulated, 0.01, [2, 0]).shape == (2 * len(FEATURE_NAMES),)


def test_check_and_diagnose_summarise_the_fits_frames_only(sensor_run):
    from softsbi.workflows.fit.runs import load_run
    from softsbi.workflows.criticism.stats import PosteriorPredictive, run_features, run_frames
    from softsbi.workflows.criticism.statistics import FEATURE_NAMES
    run = load_run(sensor_run, 12, 0)
    assert run_frames(run) == [1, 2, 3]
    pool = PosteriorPredictive(run, workers=1).ensure(6)
    assert pool.features.shape == (len(pool.rollouts), 3 * len(FEATURE_NAMES))
    f_obs = run_features(run, run.dense)
    # frame 0 (not fitted) does not enter: changing it leaves the summaries unchanged
    dense = run.dense.copy()
    dense[0] += 1.0
    np.testing.assert_array_equal(run_features(run, dense), f_obs)
