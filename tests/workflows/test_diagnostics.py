"""Model-error workflow: effects, posterior predictive check, diagnosis, compare."""
import dataclasses
import json
import re
import shutil
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from softsbi.cli import app
from softsbi.core.errors import ParameterError
from softsbi.core.results.comparison import CompareResult, Metric
from softsbi.core.results import CheckResult, Diagnosis, ResultDamaged, from_json
from softsbi.core.store import RunStore
from softsbi.workflows.criticism.check import check_run, stored_result
from softsbi.workflows.criticism.diagnose import diagnose_run, load_diagnosis, refit_model
from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording
from softsbi.workflows.fit.runs import load_run
from softsbi.workflows.criticism.stats import PM_ROLLOUTS, posterior_mean_chamfer, run_features
from softsbi.plugins import registry
from softsbi.core.defaults import CheckSettings, DiagnoseSettings

pytestmark = pytest.mark.integration

toy = pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
runner = CliRunner()


def test_mujoco_effects_are_plugins_and_change_the_rollout():
    from softsbi.backends.mujoco_flex import MujocoFlex
    from softsbi.scenarios.builtin import lift_scenario
    reg = registry()
    assert {"air-drag", "wind", "extra-damping", "grip-compliance"} <= set(reg.names("effect"))
    sim = MujocoFlex(grid=5)
    sc = lift_scenario(None)
    base = sim.param_space(sc).midpoint()
    r0 = sim.simulate(sc, base)
    for name, on in [("wind", {"wind_x": 0.0, "wind_y": 1.5}), ("grip-compliance", {"grip_timeconst": 0.3}),
                     ("extra-damping", {"damping_rate": 30.0}), ("air-drag", {"air_density": 6.0})]:
        eff = reg.effect(name)()
        assert set(on) == set(eff.param_space().names)
        r = sim.simulate(sc, {**base, **on}, effects=[name])
        assert r.ok, r.reason
        moved = np.linalg.norm(r.vertices - r0.vertices, axis=-1).mean(1).max()
        assert moved > 0.005, f"{name} moved the cloth by only {moved * 100:.2f} cm"
    # each effect at its nominal value is the nominal model
    for name in ("air-drag", "grip-compliance", "extra-damping"):
        r = sim.simulate(sc, {**base, **reg.effect(name)().nominal()}, effects=[name])
        np.testing.assert_allclose(r.vertices, r0.vertices, atol=1e-9, err_msg=name)
    with pytest.raises(ParameterError, match="wind_x"):
        sim.simulate(sc, {**base, "wind_x": float("nan"), "wind_y": 0.0}, effects=["wind"])
    with pytest.raises(ParameterError, match="supported effects"):
        sim.simulate(sc, base, effects=["toy-wind"])


def _fit(tmp_path, name, wind):
    truth = {"a": 0.3, "b": -0.2}
    effects = []
    if wind:
        truth["wind"] = wind
        effects = ["toy-wind"]
    meas = simulate_recording("toy-gauss", toy.toy_scenario(4), truth, effects=effects, n_points=16,
                                n_dense=64, seed=11)
    cfg = FitConfig(backend="toy-gauss", estimator="rkhs", rounds=2, sims_per_round=150, workers=1, n_points=16,
                    n_eval=30, n_dense=64, seed=2, estimator_options={"max_epochs": 80, "hidden": [64, 64]})
    run_fit(tmp_path / name, meas, cfg, make_plots=False)
    return tmp_path / name


@pytest.fixture(scope="module")
def toy_runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("diag")
    return _fit(tmp, "hidden", 0.45), _fit(tmp, "control", 0.0)


def test_check_finds_misspecification_only_with_the_hidden_effect(toy_runs):
    hidden, control = toy_runs
    h = check_run(hidden, settings=CheckSettings(n_eval=30, workers=1))
    c = check_run(control, settings=CheckSettings(n_eval=30, workers=1))
    assert (hidden / "check.png").stat().st_size > 10_000 and (hidden / "check.json").exists()
    assert len(h.chamfer.mean) == len(h.times_s) == 4
    assert np.array(h.region_error_m).shape == (4, 9)
    assert [p.phase for p in h.phases] == ["early", "middle", "late"]
    ht, ct = h.test, c.test
    # beyond all 30 rollouts: a rejection is decided at the cap only, so the null was extended before deciding
    assert ht.misspecified and ht.n_null == 200 and ht.tests == 2
    o, d = ht.omnibus, ht.directional
    # two tests on one null, combined by the null's own minima: never below 1/201, nor above Bonferroni's
    assert ht.directional_effect == "toy-wind" and ht.family == ("toy-wind",) and o.n == d.n == 200
    assert ht.p_value == ht.combined.value <= min(1.0, 2 * min(o.value, d.value)) + 1 / 201
    assert ht.p_value >= 1 / 201 == ht.resolution
    assert not ct.misspecified and ct.p_value > 0.05 and ct.p_value >= 1 / (ct.n_null + 1)
    assert ct.p_value == ct.combined.value <= min(1.0, 2 * min(ct.omnibus.value, ct.directional.value)) + 1 / 31
    # the hidden wind grows over time: the late phase is the worst, and the late frames are the ones flagged
    assert h.phases[-1].chamfer_m > h.phases[0].chamfer_m
    assert h.residual.frames_flagged and h.residual.frames_flagged[-1] == 3 and c.residual is None
    # the energy score of the same rollouts: the check's Chamfer less half the rollouts' spread
    assert h.energy.n == h.n_rollouts == 30 and h.energy.chamfer_m == pytest.approx(h.chamfer_mean_m)
    assert h.energy.energy_m == pytest.approx(h.chamfer_mean_m - h.energy.spread_m / 2)
    # stored: the same command reads the same result back from check.json
    assert check_run(hidden, settings=CheckSettings(n_eval=30, workers=1)) == h


def test_posterior_mean_rollout_scores_the_point_estimate_with_the_fits_metric(toy_runs):
    """posterior_mean_chamfer: PM_ROLLOUTS rollouts at the report's posterior mean, scored like the report's
    posterior-predictive Chamfer; on a well-specified fit the point estimate does not score worse than the
    posterior predictive (which adds the posterior's width), and a point far from the posterior scores worse."""
    _, control = toy_runs
    run = load_run(control)
    pm = posterior_mean_chamfer(run, workers=1)
    assert pm["n"] == PM_ROLLOUTS and pm["chamfer_se_m"] > 0  # the seeds change the toy's per-frame noise
    assert pm["chamfer_m"] <= run.report.chamfer_posterior_m + 2 * pm["chamfer_se_m"]
    assert posterior_mean_chamfer(run, n=1, workers=1)["chamfer_m"] == pytest.approx(
        posterior_mean_chamfer(run, n=1, workers=1)["chamfer_m"])  # fixed seeds: reproducible
    far = dict(run.report.posterior_mean)
    q = run.space.params[0]
    far[q.name] = q.high if far[q.name] < (q.low + q.high) / 2 else q.low
    moved = dataclasses.replace(run, report=dataclasses.replace(run.report, posterior_mean=far))
    assert posterior_mean_chamfer(moved, workers=1)["chamfer_m"] > pm["chamfer_m"]
    no_mean = dataclasses.replace(run.report, posterior_mean={})  # a report without a posterior mean
    assert posterior_mean_chamfer(dataclasses.replace(run, report=no_mean), workers=1) is None


def test_diagnose_names_the_hidden_effect_and_refit_lowers_the_error(toy_runs):
    hidden, control = toy_runs
    d = diagnose_run(
        hidden, plots=False, settings=DiagnoseSettings(workers=1, confirm=1, refit_rounds=2, refit_sims=150)
    )
    assert d.verdict == "missing-effect" and d.decision.named == ("toy-wind",)
    top = d.ranking[0]
    assert top.effect == "toy-wind" and top.estimate["wind"] == pytest.approx(0.45, abs=0.12)
    assert top.adjusted.value >= 1 / (d.test.n_null + 1)
    # diagnose's detection is check's test on the same null: identical numbers
    chk = check_run(hidden, plot=False, settings=CheckSettings(workers=1))
    assert d.test == chk.test and d.ranking == chk.ranking
    (r,) = d.refits
    # the refit with the named effect passes check's test at the diagnosis' level, over the family less its effect
    assert r.effects == ("toy-wind",) and r.adequate and r.test.alpha == d.alpha and r.test.p_value > d.alpha
    assert r.test.family == ()
    assert (r.rounds, r.sims_per_round) == (2, 150)
    # the toy's Chamfer has a floor from its 5 cm per-frame noise: a clear drop is what we can ask here
    # (the >= 40% criterion is measured on the MuJoCo cases in benchmarks/diagnosis.py)
    assert chk.energy.chamfer_m == pytest.approx(load_run(hidden).report.chamfer_posterior_m)
    assert r.chamfer_m < 0.8 * chk.energy.chamfer_m
    # the energy score of the two posterior predictives of check's summaries, in the nominal's scale: the refit's is
    # lower by more than k_se standard errors, and the decision's gain is the difference of the two
    assert r.score.value < d.nominal.value - 3 * r.score.se and d.decision.gain.z > d.k_se
    assert d.decision.gain.difference == pytest.approx(d.nominal.value - r.score.value)
    # the refit's estimate of the added effect (its posterior mean and 90% interval, with the unit), its width and
    # the prior bound it presses, from its report; the hidden wind (0.45) lies inside the interval
    refit_rep = json.loads((hidden / "refit-toy-wind" / "report.json").read_text())
    (est,) = r.estimates
    assert est.name == "wind" and est.unit == "m"
    assert (est.mean, est.q05, est.q95) == tuple(refit_rep[f"posterior_{q}"]["wind"] for q in ("mean", "q05", "q95"))
    assert est.width_ratio == refit_rep["contraction"]["wind"]["width_ratio"]
    assert est.pressed == next((b["side"] for b in refit_rep["posterior_at_bounds"] if b["param"] == "wind"), None)
    assert est.q05 < 0.45 < est.q95
    assert load_diagnosis(hidden) == d
    c = diagnose_run(control, plots=False, settings=DiagnoseSettings(workers=1, confirm=1))
    assert c.verdict == "nothing-missing" and c.refits == () and c.decision.named == ()
    assert c.residual is None and c.generic is None
    chk_c = check_run(control, plot=False, settings=CheckSettings(workers=1))
    assert c.test == chk_c.test and not chk_c.test.misspecified
    # compare before/after
    res = runner.invoke(app, ["compare", str(hidden), r.run, "--workers", "1", "--n-eval", "20"])
    assert res.exit_code == 0, res.output
    out = from_json(CompareResult, json.loads((hidden / "refit-toy-wind" / "compare.json").read_text()))
    assert out.rows[0].metric is Metric.CHAMFER and out.rows[0].b < out.rows[0].a
    assert out.label_b.endswith("toy-wind") and out.same_sensor
    energy = out.row(Metric.ENERGY_CHAMFER)
    assert energy.b < energy.a and energy.a == pytest.approx(out.rows[0].a - out.check_a.energy.spread_m / 2)
    # the fitted point estimates: rollouts at the nominal fit's and the refit's posterior means (seeds PM_SEED + k)
    # through the fit's own job; the refit's is lower
    pm = posterior_mean_chamfer(load_run(hidden), workers=1)
    refit_pm = posterior_mean_chamfer(load_run(hidden / "refit-toy-wind"), workers=1)
    pm_row = out.row(Metric.POSTERIOR_MEAN)
    assert pm["n"] == PM_ROLLOUTS and (pm_row.a, pm_row.b) == (pm["chamfer_m"], refit_pm["chamfer_m"])
    assert pm_row.b < 0.8 * pm_row.a
    assert [ch.posterior_mean["chamfer_m"] for ch in (out.check_a, out.check_b)] == [pm_row.a, pm_row.b]
    assert (hidden / "refit-toy-wind" / "compare.png").stat().st_size > 10_000


def test_check_and_diagnose_share_one_null(toy_runs):
    """One pool of posterior-predictive rollouts serves both commands (the demo's path): diagnose
    simulates no further null rollouts, and its detection is check's test."""
    from softsbi.workflows.criticism.stats import PosteriorPredictive
    hidden, _ = toy_runs
    pool = PosteriorPredictive(hidden, workers=1)
    chk = check_run(hidden, plot=False, pool=pool, recompute=True, settings=CheckSettings(workers=1))
    n = pool.requested
    d = diagnose_run(hidden, pool=pool, recompute=True, plots=False, settings=DiagnoseSettings(workers=1, confirm=0))
    assert pool.requested == n == chk.test.n_null and d.test == chk.test
    assert d.ranking == chk.ranking and d.residual == chk.residual


def test_misspecified_by_nothing_installed_names_where_and_the_generic_term(toy_runs, tmp_path, monkeypatch):
    """The hidden wind's class marked as a generic force term: no named candidate is left to refit, so the
    verdict is the third one, with the residual's shape and how much the generic term explains. (A copy of the
    run without its stored check, which holds the candidates' flags as they were.)"""
    hidden, _ = toy_runs
    run = tmp_path / "hidden"
    shutil.copytree(hidden, run, ignore=shutil.ignore_patterns("refit-*", "check.*", "diagnosis.json"))
    monkeypatch.setattr(toy.ToyWind, "generic", True, raising=False)
    d = diagnose_run(run, plots=False, settings=DiagnoseSettings(workers=1))
    assert d.test.misspecified and d.verdict == "misspecified-unexplained"
    assert d.refits == () and d.decision.named == () and d.decision.partial == ()
    assert d.generic.effect == "toy-wind" and d.ranking[0].generic
    assert d.confirm is not None and d.ranking[0].effect == "toy-wind" and d.ranking[0].explained > 0
    res = d.residual
    # the toy wind grows over time: the late frames are flagged, the first is not
    assert res.frames_flagged and res.frames_flagged[-1] == 3 and 0 not in res.frames_flagged
    assert res.phases[-1]["fraction_flagged"] == 1.0
    assert len(res.worst_regions) == 2 and len(res.centroid_offset_cm) == 3


def test_cli_check_and_diagnose(toy_runs):
    hidden, _ = toy_runs
    res = runner.invoke(app, ["check", str(hidden), "--workers", "1", "--n-eval", "20"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["check", str(hidden), "--workers", "1", "--n-eval", "20", "--json"])  # stored: reused
    chk = from_json(CheckResult, json.loads(res.stdout))
    assert chk.test.misspecified and chk.test.directional_effect == "toy-wind" and chk.test.n_null == 200
    res = runner.invoke(app, ["diagnose", str(hidden), "--workers", "1", "--confirm", "1", "--refit-rounds", "2",
                              "--refit-sims", "150"])
    assert res.exit_code == 0, res.output
    row = next(ln for ln in res.output.splitlines() if ln.startswith("| toy-wind"))
    assert row.rstrip(" |").endswith("named")
    res = runner.invoke(app, ["diagnose", str(hidden), "--workers", "1", "--confirm", "1", "--refit-rounds", "2",
                              "--refit-sims", "150", "--json"])  # stored: reused
    d = from_json(Diagnosis, json.loads(res.stdout))
    assert d.verdict == "missing-effect" and d.decision.named == ("toy-wind",)
    res = runner.invoke(app, ["diagnose", str(hidden), "--effect", "wind", "--workers", "1"])
    assert res.exit_code == 2 and "'toy-gauss'" in res.output and "wind" in res.output  # the backend and the flag


def count_run_loads(monkeypatch) -> list[Path]:
    """Record the run directory of every ``load_run`` / ``open_run`` call, wherever softsbi imported them from."""
    import softsbi.workflows.fit.runs as runs
    loads: list[Path] = []
    for name in ("load_run", "open_run"):
        orig = getattr(runs, name)

        def counted(run_dir, *args, _orig=orig, **kwargs):
            loads.append(Path(run_dir).resolve())
            return _orig(run_dir, *args, **kwargs)
        for mod in [m for n, m in sys.modules.items() if n.startswith("softsbi")]:
            if getattr(mod, name, None) is orig:
                monkeypatch.setattr(mod, name, counted)
    return loads


def test_a_diagnosis_loads_the_nominal_run_and_each_refit_once(toy_runs, tmp_path, monkeypatch):
    """One loaded run per command: the nominal fit is loaded once per diagnosis (its null, its check, its score and
    the posterior draws that extend the null share it) and each refit once (its check and score share it); they
    were loaded 4 and 3 times."""
    hidden, _ = toy_runs
    nominal = tmp_path / "hidden"
    shutil.copytree(hidden, nominal, ignore=shutil.ignore_patterns("refit-*", "check.json", "diagnosis.json"))
    loads = count_run_loads(monkeypatch)
    # a null of 12 extended to 40: beyond the fit's 30 evaluation samples, so posterior draws are made too
    d = diagnose_run(
        nominal,
        plots=False,
        settings=DiagnoseSettings(workers=1, confirm=1, refit_rounds=1, refit_sims=100, n_null=12, max_null=40),
    )
    refits = [Path(r.run).resolve() for r in d.refits]
    assert d.test.n_null > 30 and refits
    assert Counter(loads) == {nominal.resolve(): 1, **{r: 1 for r in refits}}


def test_a_refit_resumes_its_stored_rounds_and_keeps_how_much_the_data_narrowed_each_estimate(toy_runs, tmp_path):
    """A refit with more rounds (a larger refit budget) continues the stored refit, keeping its rounds, instead of
    starting over; each added parameter's estimate keeps the refit report's contraction."""
    hidden, _ = toy_runs
    # a copy of the nominal run without the other tests' refits, so this refit starts from nothing
    nominal = tmp_path / "hidden"
    shutil.copytree(hidden, nominal, ignore=shutil.ignore_patterns("refit-*"))
    run = load_run(nominal)
    # a level the 12-rollout null resolves (2/13 <= 0.2), so the refit's check stays at 12 rollouts
    scale = np.ones(len(run_features(run, run.dense)))
    first = refit_model(
        run,
        ["toy-wind"],
        ["toy-wind"],
        scale=scale,
        rounds=1,
        sims_per_round=100,
        settings=DiagnoseSettings(alpha=0.2, n_null=12, max_null=12, workers=1),
    )
    out = Path(first.run)
    assert (first.rounds, first.sims_per_round) == (1, 100) and out == nominal / "refit-toy-wind"
    assert first.test.n_null == 12 and first.test.alpha == 0.2 and first.score.n == 12
    report = json.loads((out / "report.json").read_text())
    chk = json.loads((out / "check.json").read_text())  # its Chamfer is its check's, over the nominal's rollouts
    assert first.estimates and (first.chamfer_m, first.chamfer_n) == (chk["chamfer_mean_m"], chk["n_rollouts"])
    for e in first.estimates:
        assert e.width_ratio == report["contraction"][e.name]["width_ratio"]
        assert e.informed == report["contraction"][e.name]["informed"]
    theta0 = RunStore.open(out / "run.zarr", mode="r").round_data(0)["theta"].copy()
    again = refit_model(
        run,
        ["toy-wind"],
        ["toy-wind"],
        scale=scale,
        rounds=2,
        sims_per_round=100,
        settings=DiagnoseSettings(alpha=0.2, n_null=12, max_null=12, workers=1),
    )
    store = RunStore.open(out / "run.zarr", mode="r")
    assert again.rounds == 2 and store.completed_rounds() == [0, 1]
    np.testing.assert_array_equal(store.round_data(0)["theta"], theta0)


def test_a_diagnosis_written_before_typed_results_is_one_line_and_computed_again(tmp_path):
    """An older diagnosis.json (no schema, its own field names): load_diagnosis refuses it in one line naming the
    file and the command that writes it again; diagnose's stored-result lookup says in one line that it cannot be
    used and computes it again (returns None), even under the same key. A file that is not JSON: the same."""
    old = {"run": "nominal", "candidates": ["wind", "extra-damping"], "alpha": 0.01, "verdict": "missing-effect",
           "selected": "wind", "simulations": 260, "seconds": 12.5, "key": {"report": "abc"},
           "misspecification": {"omnibus": {"exceed": 0, "n_null": 200}, "alpha": 0.01},
           "ranking": [{"effect": "wind", "kind": "physics", "explained_fraction": 0.6, "adjusted_exceed": 0,
                        "n_null": 200}]}
    path = tmp_path / "diagnosis.json"
    path.write_text(json.dumps(old))
    with pytest.raises(ResultDamaged) as err:
        load_diagnosis(tmp_path)
    assert err.value.path == path and "'schema'" in err.value.problem and "\n" not in str(err.value)
    # the one command it names, the one that writes the file again: diagnose of the run holding it
    (command,) = re.findall(r"`([^`]*)`", str(err.value))
    assert command.split() == ["softsbi", "diagnose", str(tmp_path)]
    said = []
    assert stored_result(path, Diagnosis, {"report": "abc"}, said.append) is None
    assert len(said) == 1 and str(path) in said[0] and "\n" not in said[0]
    path.write_text("{not json")
    with pytest.raises(ResultDamaged) as err:
        load_diagnosis(tmp_path)
    assert err.value.path == path and err.value.problem.startswith("not valid JSON") and "\n" not in str(err.value)
