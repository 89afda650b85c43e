"""softsbi calibrate / softsbi.calibrate_run on a small toy-gauss run."""
import json

import numpy as np
import pytest
from typer.testing import CliRunner

import softsbi
from softsbi.cli import app
from softsbi.core.errors import SoftsbiError
from softsbi.core.results.fitreport import CalibrationResult
from softsbi.core.store import RunStore
from softsbi.workflows.lock import RunLocked, run_lock

pytestmark = pytest.mark.integration

pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
from toy_helpers import toy_measurement  # noqa: E402

OPTS = {"max_epochs": 30, "hidden": [16]}


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("cal") / "run"
    softsbi.fit(toy_measurement(), out, backend="toy-gauss", estimator="mdnn", rounds=2, sims_per_round=60,
                n_points=8, n_eval=5, n_dense=32, workers=1, seed=3, plots=False, estimator_options=OPTS)
    return out


def _simulated(monkeypatch):
    """The sizes of the batches of test simulations calibrate simulates (softsbi.workflows.tasks.calibrate.run_jobs)."""
    import softsbi.workflows.tasks.calibrate as calibrate
    sizes = []
    run_jobs = calibrate.run_jobs
    monkeypatch.setattr(calibrate, "run_jobs", lambda ctx, jobs, *a, **k: sizes.append(len(jobs)) or
                        run_jobs(ctx, jobs, *a, **k))
    return sizes


def test_calibrate_run_writes_json_and_png_and_resumes(toy_run, monkeypatch):
    said = []
    simulated = _simulated(monkeypatch)
    out = softsbi.calibrate_run(toy_run, n_test=50, n_draws=300, workers=1, message=said.append)
    assert simulated == [50] and said  # one block of test simulations, its progress told to `message`
    assert isinstance(out, CalibrationResult)
    assert out.n_test + out.n_test_failed == 50 and out.n_train == 120
    assert out.refit_max_mean_difference < 1e-6  # the re-trained estimator is the run's
    c = out.coverage
    assert c.levels[0] == 0 and c.hpd[-1] == 1 and np.all(np.diff(c.hpd) >= 0)
    assert c.band_lo[18] < 0.9 < c.band_hi[18]
    assert c.band_simultaneous_lo[18] <= c.band_lo[18] and c.band_simultaneous_hi[18] >= c.band_hi[18]
    outside = [g for g, h, lo, hi in zip(c.levels, c.hpd, c.band_lo, c.band_hi) if not lo <= h <= hi]
    assert list(c.outside_pointwise) == outside and isinstance(c.inside_simultaneous, bool)
    assert out.verdict_90 in ("calibrated", "over-confident", "under-confident")
    assert len(out.sbc.histograms) == 2 and sum(out.sbc.histograms[0]) == out.n_test
    doc = json.loads((toy_run / "calibration.json").read_text())
    assert doc["coverage"]["at_90"] == c.at_90
    assert CalibrationResult.from_json(doc) == out and doc == out.to_json()  # the file is the result
    assert (toy_run / "calibration.png").stat().st_size > 20_000
    # test cases come from both rounds' proposals (the prior and round 1's posterior), as the training data
    arrays, attrs = RunStore.open(toy_run / "run.zarr").read_group("calibration")
    assert set(np.unique(arrays["round"])) == {0, 1} and attrs["proposals"][0] == "prior"
    # a larger n_test adds to the stored test simulations; the first 50 are kept
    simulated.clear()
    out2 = softsbi.calibrate_run(toy_run, n_test=100, n_draws=300, workers=1, message=said.append, write=False)
    assert simulated == [50] and out2.n_test + out2.n_test_failed == 100  # the second block only
    arrays2, _ = RunStore.open(toy_run / "run.zarr").read_group("calibration")
    np.testing.assert_array_equal(arrays2["u"][:50], arrays["u"])
    # a different estimator setting is trained on the same stored simulations and shares the test cases
    simulated.clear()
    ens = softsbi.calibrate_run(toy_run, n_test=100, n_draws=300, workers=1, estimator="mdnn",
                                estimator_options={**OPTS, "ensemble": 2}, message=said.append, write=False)
    assert simulated == [] and ens.estimator_options["ensemble"] == 2


def test_calibrate_refuses_a_locked_run_and_a_tiny_test_set(toy_run):
    with run_lock(toy_run):
        with pytest.raises(RunLocked):
            softsbi.calibrate_run(toy_run, n_test=50, workers=1)
    with pytest.raises(SoftsbiError, match="n-test"):
        softsbi.calibrate_run(toy_run, n_test=5)


def test_cli_calibrate_table_and_json(toy_run):
    runner = CliRunner()
    res = runner.invoke(app, ["calibrate", str(toy_run), "--n-test", "50", "--n-draws", "300", "--workers", "1"])
    assert res.exit_code == 0, res.output
    # the table and one line per diagnostic, as softsbi.report.fit_text renders them from calibration.json (their
    # wording: tests/report/test_fit_text.py); the verdict and the files written
    from softsbi.report.fit_text import calibration_lines, calibration_table
    cal = CalibrationResult.from_json(json.loads((toy_run / "calibration.json").read_text()))
    table = calibration_table(cal)
    printed = res.output.splitlines()
    assert table.title in printed and all(line in printed for line in calibration_lines(cal))
    assert [r[0] for r in table.rows] == ["50%", "90%"] and f"verdict: {cal.verdict}" in printed
    assert str(toy_run / "calibration.json") in res.output and str(toy_run / "calibration.png") in res.output
    # the whole curve's band: Bonferroni over the 3 diagnostics (1 - 0.05/3), simultaneous over the 19 inner levels
    c = cal.coverage
    assert c.band_simultaneous_confidence == pytest.approx(1 - 0.05 / 3) and len(c.levels) - 2 == 19
    res = runner.invoke(app, ["calibrate", str(toy_run), "--n-test", "50", "--n-draws", "300", "--workers", "1",
                              "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output[res.output.index("\n{") + 1:])  # progress notices go to stderr, mixed in here
    assert doc["verdict"] and doc["n_test"] + doc["n_test_failed"] == 50
    res = runner.invoke(app, ["calibrate", str(toy_run / "nope")])
    assert res.exit_code == 2 and "error:" in res.output


def test_report_and_fit_table_show_contraction(toy_run, capsys):
    from toy_helpers import printed_fit_report
    rep = json.loads((toy_run / "report.json").read_text())
    con = rep["contraction"]
    assert set(con) == {"a", "b"} and rep["informed_max_width_ratio"] == 0.5
    for n, c in con.items():
        assert 0 < c["width_ratio"] <= 1.2 and c["informed"] == (c["width_ratio"] <= 0.5)
        assert np.isclose(c["q05"], rep["posterior_q05"][n]) and c["scale"] == "linear"
    # the table's width / prior column: each width ratio, and whether the data inform it (the wording:
    # tests/report/test_fit_text.py)
    table, _ = printed_fit_report(rep, toy_run, capsys)
    for n, *_, width in (row[:5] for row in table.rows):
        ratio = f"{con[n]['width_ratio']:.2f}"
        assert width.startswith(ratio) and (width == ratio) == con[n]["informed"]


def test_calibrate_retrains_with_the_options_the_runs_effects_asked_for(tmp_path, monkeypatch):
    """A run whose model has an effect that asks the estimator for options (Effect.estimator_options, as point
    noise asks for the thickness summary) is calibrated with the estimator its fit trained, not the bare one."""
    from softsbi.plugins import registry
    monkeypatch.setattr(registry().effect("toy-wind"), "estimator_options", dict(OPTS), raising=False)
    out = tmp_path / "run"
    softsbi.fit(toy_measurement(), out, backend="toy-gauss", estimator="mdnn", effects=["toy-wind"], rounds=1,
                sims_per_round=60, n_points=8, n_eval=5, n_dense=32, workers=1, seed=3, plots=False)
    cal = softsbi.calibrate_run(out, n_test=20, n_draws=200, workers=1)
    assert cal.estimator_options == OPTS
    assert cal.refit_max_mean_difference < 1e-6  # the re-trained estimator is the run's
