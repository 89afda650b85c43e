"""softsbi.open_run: a finished run's posterior in physical units (the public API)."""
import numpy as np
import pytest

import softsbi
from softsbi.core.errors import SoftsbiError
from softsbi.core.types import Param, ParamSpace
from softsbi.core.defaults import CheckSettings

pytestmark = pytest.mark.integration

pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
from toy_helpers import toy_measurement  # noqa: E402


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("api") / "run"
    softsbi.fit(toy_measurement(), out, backend="toy-gauss", estimator="mdnn", rounds=2, sims_per_round=60,
                n_points=8, n_eval=5, n_dense=32, workers=1, seed=3, plots=False,
                estimator_options={"max_epochs": 30, "hidden": [16]})
    return out


def test_open_run_posterior_matches_the_report_in_physical_units(toy_run):
    run = softsbi.open_run(toy_run)
    post = run.posterior
    assert post.names == ["a", "b"] and run.config.backend == "toy-gauss"
    s = post.sample(4000)
    assert s.shape == (4000, 2) and np.all((s >= -1) & (s <= 1))
    for n in post.names:  # the fit's own summaries, from an independent set of draws
        sd = run.report.posterior_std[n]
        assert abs(post.mean[n] - run.report.posterior_mean[n]) < 0.1 * sd + 1e-9
        lo, hi = post.interval(0.9)[n]
        assert abs(lo - run.report.posterior_q05[n]) < 0.2 * sd and abs(hi - run.report.posterior_q95[n]) < 0.2 * sd


def test_open_run_and_load_run_give_the_typed_report_json(toy_run, tmp_path):
    """run.report is a FitReport (attributes, as the README's example reads it) that gives back report.json; a
    report.json without its posterior median is refused in one line naming the fit's command."""
    import json
    import shutil

    from softsbi.core.results.fitreport import FitReport
    from softsbi.core.results import ResultDamaged
    from softsbi.workflows.fit.runs import load_run
    doc = json.loads((toy_run / "report.json").read_text())
    run = softsbi.open_run(toy_run)
    assert isinstance(run.report, FitReport) and run.report.to_json() == doc
    assert run.report.chamfer_posterior_m == doc["chamfer_posterior_m"] and run.report.names == ["a", "b"]
    assert run.report.per_round[-1].round == 1 and run.report.best_fit.theta == doc["best_fit"]["theta"]
    view = load_run(toy_run, None)
    assert view.report == run.report and view.post_complete and len(view.post_theta) == 5
    assert not load_run(toy_run, 3).post_complete
    broken = tmp_path / "run"
    shutil.copytree(toy_run, broken)
    (broken / "report.json").write_text(json.dumps({k: v for k, v in doc.items() if k != "posterior_median"}))
    with pytest.raises(ResultDamaged, match=r"lacks 'posterior_median'.*`softsbi fit \.\.\. --out "):
        softsbi.open_run(broken)


def test_log_prob_is_a_normalised_density_in_physical_units(toy_run):
    post = softsbi.open_run(toy_run).posterior
    rng = np.random.default_rng(0)
    grid = rng.uniform(-1, 1, (200_000, 2))  # the prior box, volume 4
    mass = 4.0 * np.exp(post.log_prob(grid)).mean()
    assert mass == pytest.approx(1.0, abs=0.1)
    assert np.all(post.log_prob(np.array([[1.5, 0.0]])) == -np.inf)  # outside the prior box


def test_log_prob_has_the_jacobian_of_log_scaled_parameters():
    from softsbi.workflows.fit.runs import Posterior

    class UniformUnit:  # uniform on the unit square
        def log_prob(self, u):
            return np.where(np.all((u >= 0) & (u <= 1), -1), 0.0, -np.inf)

    space = ParamSpace([Param("k", 1.0, 100.0, "N/m", log=True), Param("x", 0.0, 2.0, "m")])
    post = Posterior(space, UniformUnit())
    theta = np.array([[10.0, 1.0]])
    # log-uniform on [1, 100]: p(k) = 1 / (k ln 100); uniform on [0, 2]: 1/2
    assert post.log_prob(theta)[0] == pytest.approx(-np.log(10.0 * np.log(100.0)) - np.log(2.0))


def test_fit_refuses_an_unknown_setting_and_open_run_an_unfinished_run(tmp_path):
    with pytest.raises(SoftsbiError, match="unknown fit setting 'round'.*Did you mean 'rounds'"):
        softsbi.fit(toy_measurement(), tmp_path / "x", backend="toy-gauss", round=2)
    with pytest.raises(SoftsbiError):
        softsbi.open_run(tmp_path / "nothing-here")


def test_the_python_api_checks_types_and_frames_at_entry(tmp_path):
    """Each of these raised a TypeError or IndexError (the frames only after a whole round was simulated, and
    the run then resumed only with the same bad setting); effects="wind" was read as the effects w, i, n, d."""
    rec = toy_measurement(T=4)
    cases = [({"rounds": "two"}, "field 'rounds': Input should be a valid integer"),
             ({"bounds": {"a": 5}}, "field 'bounds.a': Input should be a valid tuple (got 5)"),
             ({"effects": "toy-wind"}, "field 'effects': Input should be a valid list (got 'toy-wind')"),
             ({"frames": [100]}, "--frames 100 selects frame 100, but the recording has 4 frames (0 to 3)"),
             ({"seed": -1}, "--seed must be >= 0 (got -1)")]
    for kw, message in cases:
        with pytest.raises(SoftsbiError) as err:
            softsbi.fit(rec, tmp_path / "run", **{"backend": "toy-gauss", "sims_per_round": 10, "workers": 1, **kw})
        assert message in str(err.value), (kw, str(err.value))
        assert not (tmp_path / "run").exists(), kw
    with pytest.raises(SoftsbiError, match="takes a Recording .* or the path of a recording folder, got int"):
        softsbi.fit(123, tmp_path / "run")
    with pytest.raises(SoftsbiError, match="'.*nowhere' does not exist"):
        softsbi.fit(tmp_path / "nowhere", tmp_path / "run")  # a path is read as `fit --observed PATH` reads it
    with pytest.raises(SoftsbiError, match="takes a scenario name, a scenario file path or a Scenario, got int"):
        softsbi.simulate(123)
    with pytest.raises(SoftsbiError, match=r"takes a list of effect names, e.g. \['wind'\]"):
        softsbi.simulate("lift", effects="wind")


def test_compare_refuses_an_out_that_is_a_file_before_checking_either_run(toy_run, tmp_path, monkeypatch):
    import softsbi.workflows.criticism.compare as compare

    def no_check(*a, **k):
        raise AssertionError("checked a run before refusing the output folder")
    monkeypatch.setattr(compare, "check_run", no_check)
    afile = tmp_path / "afile"
    afile.write_text("x")
    with pytest.raises(SoftsbiError, match=f"--out '{afile}' is a file; give a folder"):
        compare.compare_runs(toy_run, toy_run, afile)
    with pytest.raises(SoftsbiError, match="not a run directory"):
        compare.compare_runs(toy_run, tmp_path, tmp_path / "o")  # the second run, before the first's check


def test_a_posterior_predictive_worse_than_the_prior_says_what_it_means(toy_run, capsys):
    """The fit prints the sentences softsbi.report.fit_text renders from its report.json (their wording:
    tests/report/test_fit_text.py): with the posterior predictive's Chamfer above the prior's, one more, the note
    that the model cannot reach the data."""
    import json

    from toy_helpers import printed_fit_report
    rep = json.loads((toy_run / "report.json").read_text())
    # every posterior-predictive Chamfer says its rollouts: the report keeps their number (n_eval)
    assert rep["chamfer_posterior_n"] == 5 and rep["chamfer_prior_m"] > 0 and rep["chamfer_posterior_m"] > 0
    rep["chamfer_prior_m"], rep["chamfer_posterior_m"] = 0.0907, 0.0937  # the "9.07 cm -> 9.37 cm"
    _, worse = printed_fit_report(rep, toy_run, capsys)
    rep["chamfer_posterior_m"] = 0.05
    _, better = printed_fit_report(rep, toy_run, capsys)
    k = next(i for i, (w, b) in enumerate(zip(worse, better)) if w != b)  # the Chamfer line: its numbers changed
    # the note comes right after it and goes with it; every other line stays
    assert len(worse) == len(better) + 1 and worse[:k] == better[:k] and worse[k + 2:] == better[k + 1:]


def test_estimates_of_switched_off_effects_print_as_zero():
    """A switched-off effect's estimate (8.7e-22 is rounding) prints as 0 (the sentence: tests/report/test_text.py,
    test_an_estimate_at_a_switched_off_value_reads_zero)."""
    from softsbi.report.text import ZERO_PRINTED, num
    assert [num(v) for v in (8.74e-22, 0.0, 1.29e-14, -3e-13, ZERO_PRINTED / 2)] == ["0"] * 5
    assert num(0.0123) == "0.0123" and num(-2e-12) == "-2e-12"


def test_check_refuses_fewer_rollouts_than_it_needs_before_simulating(toy_run, monkeypatch):
    """`check --n-eval 3` said "only 3 of 3 rollouts succeeded" after simulating them (the rule is >= 5)."""
    import softsbi.workflows.criticism.check as check
    monkeypatch.setattr(check, "PosteriorPredictive", lambda *a, **k: pytest.fail("simulated before refusing"))
    with pytest.raises(SoftsbiError, match=r"--n-eval must be >= 5 \(got 3\): the null's first stage and the "
                                           r"check's error maps need that many posterior rollouts"):
        check.check_run(toy_run, settings=CheckSettings(n_eval=3))


def test_the_fit_report_points_to_check_when_the_intervals_miss_more_hidden_values_than_chance(toy_run, capsys):
    """The hint (truth_miss_hint, worded in tests/report/test_fit_text.py) is the first line under the table when
    the intervals miss both hidden values, and absent when they miss one."""
    import json

    from toy_helpers import printed_fit_report
    from softsbi.report.text import truth_miss_hint
    rep = json.loads((toy_run / "report.json").read_text())
    names = [p["name"] for p in rep["parameters"]]
    rep["truth"] = {n: 0.0 for n in names}
    rep["truth_in_90pct_interval"] = {n: False for n in names}  # both missed: p = 0.01
    table, missed = printed_fit_report(rep, toy_run, capsys)
    hint = truth_miss_hint(rep["truth_in_90pct_interval"], str(toy_run))
    assert hint is not None and missed[0] == hint and str(toy_run) in hint  # it names this run for `softsbi check`
    assert [r[-1] for r in table.rows] == ["NO", "NO"]  # the table's "inside 90%?" column
    rep["truth_in_90pct_interval"] = {n: k > 0 for k, n in enumerate(names)}  # one missed: chance
    table, chance = printed_fit_report(rep, toy_run, capsys)
    assert truth_miss_hint(rep["truth_in_90pct_interval"], str(toy_run)) is None and chance == missed[1:]
    assert [r[-1] for r in table.rows] == ["NO", "yes"]
