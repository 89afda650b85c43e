"""Model-error workflow: effects, posterior predictive check, diagnosis, compare."""
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from softsbi.cli import app
from softsbi.workflows.check import check_run
from softsbi.core.store import RunStore
from softsbi.workflows import diagnose as dg
from softsbi.workflows.diagnose import diagnose_run
from softsbi.core.errors import ParameterError
from softsbi.workflows.fit import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording
from softsbi.workflows.runs import load_run
from softsbi.workflows.stats import PM_ROLLOUTS, posterior_mean_chamfer
from softsbi.plugins import registry

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
    run_fit(tmp_path / name, meas, cfg)
    return tmp_path / name


@pytest.fixture(scope="module")
def toy_runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("diag")
    return _fit(tmp, "hidden", 0.45), _fit(tmp, "control", 0.0)


def test_check_finds_misspecification_only_with_the_hidden_effect(toy_runs):
    hidden, control = toy_runs
    h = check_run(hidden, n_eval=30, workers=1)
    c = check_run(control, n_eval=30, workers=1)
    assert (hidden / "check.png").stat().st_size > 10_000 and (hidden / "check.json").exists()
    assert len(h["chamfer_per_frame_m"]["mean"]) == 4
    assert np.array(h["region_error_m"]).shape == (4, 9)
    assert [p["phase"] for p in h["phases"]] == ["early", "middle", "late"]
    hm, cm = h["misspecification"], c["misspecification"]
    # beyond all 30 rollouts, 2/31 > 0.01: the null was extended to the cap before deciding
    assert hm["misspecified"] and hm["extended"] and hm["n_null"] == 200 and hm["tests"] == 2
    o, d = hm["omnibus"], hm["directional"]
    # two tests on one null, Bonferroni-combined: the joint p is twice the smaller one, never below 2/201
    assert d["effect"] == "toy-wind" and d["family"] == 1 and o["n_null"] == d["n_null"] == 200
    assert hm["p_value"] == pytest.approx(min(1.0, 2 * min(o["p_value"], d["p_value"])))
    assert hm["p_value"] >= 2 / 201 and "200 null simulations" in hm["p_text"] and "Bonferroni" in hm["rule"]
    assert not cm["misspecified"] and cm["p_value"] > 0.01 and cm["p_value"] >= 2 / (cm["n_null"] + 1)
    assert cm["p_value"] == pytest.approx(min(1.0, 2 * min(cm["omnibus"]["p_value"], cm["directional"]["p_value"])))
    assert "null simulations" in h["summary"] and "200 null simulations" in hm["rule"]
    # the hidden wind grows over time: the late phase is the worst
    assert h["phases"][-1]["chamfer_m"] > h["phases"][0]["chamfer_m"]


def test_posterior_mean_rollout_scores_the_point_estimate_with_the_fits_metric(toy_runs):
    """posterior_mean_chamfer: PM_ROLLOUTS rollouts at the report's posterior mean, scored like the report's
    posterior-predictive Chamfer; on a well-specified fit the point estimate does not score worse than the
    posterior predictive (which adds the posterior's width), and a point far from the posterior scores worse."""
    _, control = toy_runs
    run = load_run(control)
    pm = posterior_mean_chamfer(run, workers=1)
    assert pm["n"] == PM_ROLLOUTS and pm["chamfer_se_m"] > 0  # the seeds change the toy's per-frame noise
    assert pm["chamfer_m"] <= run.report["chamfer_posterior_m"] + 2 * pm["chamfer_se_m"]
    assert posterior_mean_chamfer(run, n=1, workers=1)["chamfer_m"] == pytest.approx(
        posterior_mean_chamfer(run, n=1, workers=1)["chamfer_m"])  # fixed seeds: reproducible
    far = dict(run.report["posterior_mean"])
    q = run.space.params[0]
    far[q.name] = q.high if far[q.name] < (q.low + q.high) / 2 else q.low
    moved = dataclasses.replace(run, report=dict(run.report, posterior_mean=far))
    assert posterior_mean_chamfer(moved, workers=1)["chamfer_m"] > pm["chamfer_m"]
    assert posterior_mean_chamfer(dataclasses.replace(run, report={}), workers=1) is None


def test_diagnose_names_the_hidden_effect_and_refit_lowers_the_error(toy_runs):
    hidden, control = toy_runs
    d = diagnose_run(hidden, workers=1, confirm=1, confirm_budget={"rounds": 2, "sims_per_round": 150})
    assert d["verdict"] == "missing-effect" and d["summary"].startswith("Missing physics effect: toy-wind")
    assert d["ranking"][0]["effect"] == "toy-wind"
    assert d["significant"] == ["toy-wind"] and d["selected"] == "toy-wind"
    assert d["ranking"][0]["estimate"]["wind"] == pytest.approx(0.45, abs=0.12)
    # diagnose's first verdict is check's test on the same null: identical numbers
    chk = check_run(hidden, workers=1, plot=False)["misspecification"]
    for k in ("statistic", "p_value", "n_null", "misspecified"):
        assert d["misspecification"][k] == chk[k], k
    assert d["ranking"][0]["adjusted_p_value"] >= 1 / (d["n_null"] + 1)
    # what the named effect leaves: a small fraction, stated with its own Monte-Carlo p-value
    assert d["remaining"]["effects"] == ["toy-wind"] and d["remaining"]["fraction"] < 0.3
    assert d["remaining"]["p_value"] >= 1 / (d["n_null"] + 1)
    conf = d["confirmed"][0]
    # the refit with the named effect passes check's test: the effect accounts for the misfit
    after = conf["misspecification_after"]
    assert not after["misspecified"] and after["p_value"] > 0.01 and "inside the posterior predictive" in d["summary"]
    # the toy's Chamfer has a floor from its 5 cm per-frame noise: a clear drop is what we can ask here
    # (the >= 40% criterion is measured on the MuJoCo cases in benchmarks/hidden_effect.py)
    assert conf["chamfer_after_m"] < 0.8 * conf["chamfer_before_m"]
    # the energy score (the Chamfer less half the rollouts' spread) of the same posterior predictives: the
    # nominal's is stored with the diagnosis, the refit's is lower, and the sentence gives both numbers
    assert d["energy"]["chamfer_m"] == pytest.approx(conf["chamfer_before_m"])
    assert conf["energy_before_m"] == d["energy"]["energy_m"] < conf["chamfer_before_m"]
    assert conf["energy_after_m"] < conf["energy_before_m"] - 3 * conf["energy_after_se_m"]
    assert conf["energy_drop"] == pytest.approx(1 - conf["energy_after_m"] / conf["energy_before_m"])
    assert f"energy score from {conf['energy_before_m'] * 100:.2f} to {conf['energy_after_m'] * 100:.2f} cm" in d["summary"]
    # the fitted point estimate: rollouts at the nominal fit's and the refit's posterior means (seeds PM_SEED + k)
    # through the fit's own job; the refit's is lower and the sentence gives both numbers
    pm = posterior_mean_chamfer(load_run(hidden), workers=1)
    assert pm["n"] == PM_ROLLOUTS and conf["pm_chamfer_before_m"] == pm["chamfer_m"]
    refit_pm = posterior_mean_chamfer(load_run(hidden / "refit-toy-wind"), workers=1)
    assert conf["pm_chamfer_after_m"] == refit_pm["chamfer_m"] < 0.8 * pm["chamfer_m"]
    assert conf["pm_drop"] == pytest.approx(1 - conf["pm_chamfer_after_m"] / conf["pm_chamfer_before_m"])
    assert (f"posterior-mean rollout's from {conf['pm_chamfer_before_m'] * 100:.2f} to "
            f"{conf['pm_chamfer_after_m'] * 100:.2f} cm") in d["summary"]
    # the refit's bounds pressed by the added effect's parameters only (the refit's report holds all of its own)
    refit_rep = json.loads((hidden / "refit-toy-wind" / "report.json").read_text())
    assert conf["at_bounds"] == [b for b in refit_rep["posterior_at_bounds"] if b["param"] == "wind"]
    # the refit's estimate of the added effect (its posterior mean and 90% interval, with the unit), which the
    # sentence gives; the hidden wind (0.45) lies inside it
    est = conf["estimates"]["wind"]
    assert list(conf["estimates"]) == ["wind"]
    assert (est["mean"], est["q05"], est["q95"]) == tuple(refit_rep[f"posterior_{q}"]["wind"] for q in ("mean", "q05", "q95"))
    assert est["q05"] < 0.45 < est["q95"]
    assert f"The refit estimates wind = {est['mean']:.3g}" in d["summary"]
    assert f"(90% interval {est['q05']:.3g} to {est['q95']:.3g}" in d["summary"]
    saved = json.loads((hidden / "diagnosis.json").read_text())
    assert saved["verdict"] == "missing-effect" and saved["significant"] and saved["rules"][0].startswith("1. ")
    c = diagnose_run(control, workers=1, confirm=1)
    assert c["verdict"] == "nothing-missing"
    assert c["significant"] == [] and c["confirmed"] == [] and c["selected"] is None
    assert c["summary"].startswith("Nothing missing")
    chk_c = check_run(control, workers=1, plot=False)["misspecification"]
    assert c["misspecification"]["p_value"] == chk_c["p_value"] and not chk_c["misspecified"]
    # compare before/after
    res = runner.invoke(app, ["compare", str(hidden), conf["run"], "--workers", "1", "--n-eval", "20"])
    assert res.exit_code == 0, res.output
    out = json.loads((hidden / "refit-toy-wind" / "compare.json").read_text())
    assert out["table"][0]["b"] < out["table"][0]["a"]
    energy = next(r for r in out["table"] if r["what"].startswith("energy score"))
    assert energy["b"] < energy["a"] and "energy score" in out["summary"]
    assert energy["a"] == pytest.approx(out["table"][0]["a"] - out["check_a"]["energy"]["spread_m"] / 2)
    # the fitted point estimates, as diagnose scored them
    pm_row = next(r for r in out["table"] if r["what"].startswith("posterior-mean rollout"))
    assert (pm_row["a"], pm_row["b"]) == (conf["pm_chamfer_before_m"], conf["pm_chamfer_after_m"])
    assert [out["posterior_mean_chamfer"][k]["chamfer_m"] for k in "ab"] == [pm_row["a"], pm_row["b"]]
    assert f"posterior-mean rollout {pm_row['a'] * 100:.2f} -> {pm_row['b'] * 100:.2f} cm" in out["summary"]
    assert (hidden / "refit-toy-wind" / "compare.png").stat().st_size > 10_000


def test_check_and_diagnose_share_one_null(toy_runs, monkeypatch):
    """One pool of posterior-predictive rollouts serves both commands (the demo's path): diagnose
    simulates no further null rollouts, and its first verdict is check's."""
    from softsbi.workflows.stats import PosteriorPredictive
    hidden, _ = toy_runs
    pool = PosteriorPredictive(hidden, workers=1)
    chk = check_run(hidden, workers=1, plot=False, pool=pool)["misspecification"]
    n = pool.requested
    d = diagnose_run(hidden, workers=1, confirm=0, pool=pool)
    assert pool.requested == n == chk["n_null"] and d["misspecification"] == chk


def test_misspecified_by_nothing_installed_names_where_and_the_generic_term(toy_runs, monkeypatch):
    """The hidden wind's class marked as a generic force term: no named candidate is left, so the
    verdict is the third one, with the residual's shape and how much the generic term explains."""
    hidden, _ = toy_runs
    monkeypatch.setattr(toy.ToyWind, "generic", True, raising=False)
    d = diagnose_run(hidden, workers=1, confirm=0)
    assert d["verdict"] == "misspecified-unexplained" and d["significant"] == [] and d["selected"] is None
    assert d["generic"] == "toy-wind" and d["ranking"][0]["generic"]
    assert d["summary"].startswith("Misspecified by nothing installed")
    assert "Best generic force term: toy-wind explains" in d["summary"]
    res = d["residual"]
    # the toy wind grows over time: the late frames are flagged, the first is not
    assert res["frames_flagged"] and res["frames_flagged"][-1] == 3 and 0 not in res["frames_flagged"]
    assert res["phases"][-1]["fraction_flagged"] == 1.0
    assert len(res["worst_regions"]) == 2 and len(res["centroid_offset_cm"]) == 3


def test_cli_check_and_diagnose(toy_runs):
    hidden, _ = toy_runs
    res = runner.invoke(app, ["check", str(hidden), "--workers", "1", "--n-eval", "20"])
    assert res.exit_code == 0, res.output
    assert "misspecification test" in res.output and "decision rule" in res.output
    assert "null simulations" in res.output
    res = runner.invoke(app, ["diagnose", str(hidden), "--workers", "1", "--confirm", "0"])
    assert res.exit_code == 0, res.output
    assert "toy-wind" in res.output and "verdict: missing-effect" in res.output and "decision rule 2." in res.output
    res = runner.invoke(app, ["diagnose", str(hidden), "--effect", "wind", "--workers", "1"])
    assert res.exit_code == 2 and "cannot apply" in res.output


def test_refits_decide_between_near_collinear_candidates(monkeypatch, tmp_path):
    """Two effects both pass the rule on their own: both are refitted and the one whose refit
    lowers the error most is selected, even if the linearised screening ranked it second."""
    from softsbi.workflows import diagnose as dg

    def rank(name, exceed, frac, generic=False):
        return {"effect": name, "description": name, "kind": "physics", "generic": generic, "statistic": 1.0,
                "explained_fraction": frac, "adjusted_exceed": exceed, "n_null": 120,
                "adjusted_p_value": (exceed + 1) / 121, "adjusted_p_text": f"p = {(exceed + 1) / 121:.2g}",
                "estimate": {"k": 1.0}}
    out = {"ranking": [rank("extra-damping", 0, 0.35), rank("air-drag", 0, 0.30), rank("wind", 5, 0.2),
                       rank("grip", 0, 0.05), rank("const-force", 0, 0.5, generic=True)],
           "significant": ["extra-damping"], "alpha": 0.01, "min_explained": 0.1, "confirmed": [],
           "selected": "extra-damping", "verdict": "missing-effect",
           "misspecification": {"p_text": "p <= 1/121 (beyond all 120 null simulations)", "misspecified": True}}
    assert dg.candidates_to_confirm(out, 2) == ["extra-damping", "air-drag"]
    # wind: p too large; grip: < 10 %; the generic term is not a named effect
    assert dg.candidates_to_confirm(out, 5) == ["extra-damping", "air-drag"]
    assert dg.format_p(out["ranking"][0]) == "p <= 1/121" and dg.format_p(out["ranking"][2]) == "p = 0.05"
    after = {"extra-damping": 0.015, "air-drag": 0.009}
    monkeypatch.setattr(dg, "confirm_effect", lambda run, name, budget, workers, **stat: {
        "effect": name, "run": str(tmp_path / name), "chamfer_before_m": 0.025, "chamfer_after_m": after[name],
        "drop": 1 - after[name] / 0.025, "posterior_mean": {}})
    seen = []
    dg.confirm_candidates(dg.RunView.__new__(dg.RunView), out, 2, progress=seen.append)
    assert seen == ["extra-damping", "air-drag"]
    assert out["selected"] == "air-drag" and [c["effect"] for c in out["confirmed"]] == ["air-drag", "extra-damping"]
    assert out["final_ranking"] == ["air-drag", "extra-damping", "wind", "grip", "const-force"]
    assert "favour air-drag" in out["summary"] and "64% lower" in out["summary"]
    # the third verdict refits the best generic term only
    out3 = dict(out, verdict="misspecified-unexplained", significant=[], confirmed=[])
    assert dg.candidates_to_confirm(out3, 2) == ["const-force"]
    assert dg.candidates_to_confirm(dict(out, verdict="nothing-missing"), 2) == []


def test_refits_within_their_monte_carlo_error_are_not_told_apart(monkeypatch, tmp_path):
    """Two refits that both explain the misfit (check accepts each, each lowers the error): the one with the
    larger drop is listed first, but when their posterior-predictive Chamfers differ by less than two standard
    errors the diagnosis says the data cannot tell them apart instead of "the data favour" it (measured: a
    hidden time offset in a lift, whose grip-compliance refit came out 0.06 +- 0.05 cm lower)."""
    from softsbi.workflows import diagnose as dg

    def rank(name):
        return {"effect": name, "description": name, "kind": "physics", "generic": False, "statistic": 1.0,
                "explained_fraction": 0.2, "adjusted_exceed": 0, "n_null": 200, "adjusted_p_value": 1 / 201,
                "adjusted_p_text": "p <= 1/201", "estimate": {"k": 1.0}}

    def diagnose_with(after, se, estimates=None):
        out = {"ranking": [rank("time-offset"), rank("grip-compliance")], "significant": ["time-offset"],
               "alpha": 0.01, "min_explained": 0.1, "confirmed": [], "selected": "time-offset",
               "verdict": "missing-effect",
               "misspecification": {"p_text": "p <= 2/201", "misspecified": True}}
        accepted = {"p_text": "p = 1", "misspecified": False, "alpha": 0.2}
        monkeypatch.setattr(dg, "_mimicry", lambda a, b: None)  # the standard-error rule alone (mimicry: below)
        monkeypatch.setattr(dg, "confirm_effect", lambda run, name, budget, workers, **kw: {
            "effect": name, "run": str(tmp_path / name), "chamfer_before_m": 0.011, "chamfer_after_m": after[name],
            "chamfer_after_se_m": se, "drop": 1 - after[name] / 0.011, "posterior_mean": {},
            "misspecification_after": accepted, "estimates": (estimates or {}).get(name, {})})
        return dg.confirm_candidates(dg.RunView.__new__(dg.RunView), out, 2)

    close = diagnose_with({"time-offset": 0.01079, "grip-compliance": 0.01020}, 0.00035)
    assert close["verdict"] == "missing-effect" and close["selected"] == "grip-compliance"
    assert [t["effect"] for t in close["indistinguishable"]] == ["time-offset"]
    assert "cannot tell grip-compliance from time-offset" in close["summary"] and "favour" not in close["summary"]
    assert any(r.endswith("-> indistinguishable") for r in close["rules"])
    far = diagnose_with({"time-offset": 0.01079, "grip-compliance": 0.00800}, 0.00035)
    assert far["selected"] == "grip-compliance" and far["indistinguishable"] == []
    assert "favour grip-compliance" in far["summary"] and any(r.endswith("-> told apart") for r in far["rules"])
    # refits resumed from a diagnosis stored before standard errors were kept: told apart, as they were then
    old = diagnose_with({"time-offset": 0.01079, "grip-compliance": 0.01020}, None)
    assert old["indistinguishable"] == [] and "favour grip-compliance" in old["summary"]
    assert any("no standard error stored" in r for r in old["rules"])
    # the refit that lost also explains the misfit, but the data barely inform its added parameter: the sentence
    # does not claim more than this budget shows (verdict and name unchanged)
    loose = {"time-offset": {"time_offset": {"mean": 0.0, "width_ratio": 0.7, "informed": False}},
             "grip-compliance": {"grip_timeconst": {"mean": 0.1, "width_ratio": 0.3, "informed": True}}}
    unsettled = diagnose_with({"time-offset": 0.01079, "grip-compliance": 0.00800}, 0.00035, loose)
    assert unsettled["selected"] == "grip-compliance" and unsettled["verdict"] == "missing-effect"
    assert "favour grip-compliance at this refit budget." in unsettled["summary"]
    assert "the data barely inform time_offset in it: it may not have converged" in unsettled["summary"]
    # the winner's own parameter uninformed changes nothing in that sentence (its refit says how to continue it)
    swapped = {"time-offset": {"time_offset": {"mean": 0.0, "width_ratio": 0.3, "informed": True}},
               "grip-compliance": {"grip_timeconst": {"mean": 0.1, "width_ratio": 0.7, "informed": False}}}
    settled = diagnose_with({"time-offset": 0.01079, "grip-compliance": 0.00800}, 0.00035, swapped)
    assert "favour grip-compliance." in settled["summary"] and "in it: it may not have converged" not in settled["summary"]


def test_a_sensor_effect_that_reproduces_the_physics_effect_is_not_told_apart_by_the_better_fit(monkeypatch, tmp_path):
    """Two refits that both explain the misfit, a sensor effect (time offset) and a physics effect (soft grasp), whose
    Chamfers differ by many standard errors: told apart only if the time offset reproduces less than half of the
    motion the soft grasp adds at its refit's estimates (measured: 64-90% in lifts, where the time-offset refit,
    trained with sensor draws, out-fitted the right grip refit). The measure is kept on the physics refit, so a
    resumed diagnosis does not simulate it again. Pairs of two physics effects (refitted on an equal footing, where
    the better fit is evidence: measured, thirtieth session) or two sensor effects are not measured."""
    from softsbi.workflows import diagnose as dg

    def rank(name, kind):
        return {"effect": name, "description": name, "kind": kind, "generic": False, "statistic": 1.0,
                "explained_fraction": 0.2, "adjusted_exceed": 0, "n_null": 200, "adjusted_p_value": 1 / 201,
                "adjusted_p_text": "p <= 1/201", "estimate": {"k": 1.0}}

    calls = []

    def diagnose_with(share, names=("time-offset", "grip-compliance")):
        def mimicry(refit, physics, standin):
            calls.append((physics, standin))
            kind = dg.effect_kind(dg.registry().effect(standin))
            return {"physics": physics, "standin": standin, "standin_kind": kind, "effect_m": 0.0046,
                    "residual_m": 0.0046 * (1 - share), "share": share,
                    "standin_estimate": {"time_offset": -0.032} if kind == "sensor" else {"damping_rate": 2.5}}
        monkeypatch.setattr(dg, "physics_mimicry", mimicry)
        monkeypatch.setattr(dg, "load_run", lambda path: path)
        out = {"ranking": [rank(n, dg.effect_kind(dg.registry().effect(n))) for n in names],
               "significant": [names[0]], "alpha": 0.01, "min_explained": 0.1, "confirmed": [],
               "verdict": "missing-effect", "misspecification": {"p_text": "p <= 2/201", "misspecified": True}}
        accepted = {"p_text": "p = 1", "misspecified": False, "alpha": 0.2}
        after = {names[0]: 0.00828, names[1]: 0.01110}
        monkeypatch.setattr(dg, "confirm_effect", lambda run, name, budget, workers, **kw: {
            "effect": name, "run": str(tmp_path / name), "chamfer_before_m": 0.0126, "chamfer_after_m": after[name],
            "chamfer_after_se_m": 0.0002, "drop": 1 - after[name] / 0.0126, "posterior_mean": {},
            "misspecification_after": accepted, "estimates": {}})
        return dg.confirm_candidates(dg.RunView.__new__(dg.RunView), out, 2)

    mimicked = diagnose_with(0.9)
    assert mimicked["selected"] == "time-offset" and mimicked["verdict"] == "missing-effect"
    assert [t["effect"] for t in mimicked["indistinguishable"]] == ["grip-compliance"]
    assert calls == [("grip-compliance", "time-offset")]
    assert "cannot tell time-offset from grip-compliance" in mimicked["summary"]
    assert "reproduces 90% of the motion grip-compliance adds" in mimicked["summary"]
    assert mimicked["summary"].startswith("Missing sensor effect: time-offset (") and \
        "), or grip-compliance (physics effect): the data cannot tell the two apart (below)." in mimicked["summary"]
    assert "time_offset = -0.032 s" in mimicked["summary"]
    assert "favour" not in mimicked["summary"]
    assert any("time-offset reproduces 90% of grip-compliance's -> indistinguishable" in r for r in mimicked["rules"])
    # kept on the physics refit: deciding again from the stored refits does not measure it again
    grip = next(c for c in mimicked["confirmed"] if c["effect"] == "grip-compliance")
    assert grip["mimicry"]["time-offset"]["share"] == 0.9
    dg.confirm_candidates(dg.RunView.__new__(dg.RunView), mimicked, 2)
    assert calls == [("grip-compliance", "time-offset")]
    assert [t["effect"] for t in mimicked["indistinguishable"]] == ["grip-compliance"]
    # a sensor effect that reproduces little of it: the better fit tells them apart, as before
    apart = diagnose_with(0.2)
    assert apart["indistinguishable"] == [] and "favour time-offset" in apart["summary"]
    assert any("reproduces 20% of grip-compliance's -> told apart" in r for r in apart["rules"])
    # a measure that fails (a third-party transform that raises): a warning, no claim, the diagnosis goes on
    def broken(refit, physics, sensor):
        raise ValueError("transform failed")
    out = {"ranking": mimicked["ranking"], "significant": ["time-offset"], "alpha": 0.01, "min_explained": 0.1,
           "confirmed": [], "verdict": "missing-effect",
           "misspecification": {"p_text": "p <= 2/201", "misspecified": True}}
    monkeypatch.setattr(dg, "physics_mimicry", broken)
    with pytest.warns(UserWarning, match="mimicry of grip-compliance by time-offset not measured: transform failed"):
        failed = dg.confirm_candidates(dg.RunView.__new__(dg.RunView), out, 2)
    assert failed["selected"] == "time-offset" and failed["indistinguishable"] == [] and "favour" in failed["summary"]
    # two physics effects (refits on an equal footing: the better fit is evidence) or two sensor effects: no measure
    for pair in (("air-drag", "extra-damping"), ("time-offset", "calibration-offset")):
        calls.clear()
        other = diagnose_with(0.9, pair)
        assert calls == [] and other["indistinguishable"] == [] and "mimicry" not in other["ties"][0]
        assert f"favour {pair[0]}" in other["summary"]


def test_a_significant_physics_candidate_a_named_sensor_effect_stands_in_for_is_refitted_too(monkeypatch, tmp_path):
    """Only the time offset passed rule 2 and its refit explains the misfit; the soft grasp is significant but below
    the share (measured: a hidden soft grasp in the rope winding, 9.6% of the residual, adjusted p 0.02). When the
    time offset reproduces at least half of the soft grasp's motion at the nominal fit's estimates, the soft grasp is
    refitted too (within --confirm) and the two are listed as indistinguishable; when it reproduces little, or
    --confirm leaves no room, it is not."""
    from softsbi.workflows import diagnose as dg

    def rank(name, kind, share, p):
        return {"effect": name, "description": name, "kind": kind, "generic": False, "statistic": 1.0,
                "explained_fraction": share, "adjusted_exceed": 0, "n_null": 200, "adjusted_p_value": p,
                "adjusted_p_text": f"p = {p:g}", "estimate": {"k": 1.0}}

    def diagnose_with(share, confirm=2):
        seen, refitted = [], []

        def mimicry(run, physics, sensor, estimate=None):
            seen.append((physics, sensor, estimate))
            return {"physics": physics, "sensor": sensor, "effect_m": 0.005, "residual_m": 0.005 * (1 - share),
                    "share": share, "sensor_estimate": {"time_offset": -0.05}}
        monkeypatch.setattr(dg, "physics_mimicry", mimicry)
        monkeypatch.setattr(dg, "load_run", lambda path: path)
        out = {"ranking": [rank("time-offset", "sensor", 0.49, 0.005), rank("grip-compliance", "physics", 0.096, 0.02),
                           rank("sticky-patch", "physics", 0.04, 0.09)],
               "significant": ["time-offset"], "alpha": 0.05, "min_explained": 0.1, "confirmed": [],
               "verdict": "missing-effect", "misspecification": {"p_text": "p <= 2/201", "misspecified": True}}
        accepted = {"p_text": "p = 0.5", "misspecified": False, "alpha": 0.2}
        after = {"time-offset": 0.0075, "grip-compliance": 0.0105}

        def confirm_effect(run, name, budget, workers, **kw):
            refitted.append(name)
            return {"effect": name, "run": str(tmp_path / name), "chamfer_before_m": 0.0125,
                    "chamfer_after_m": after[name], "chamfer_after_se_m": 0.0002, "drop": 1 - after[name] / 0.0125,
                    "posterior_mean": {}, "misspecification_after": accepted, "estimates": {}}
        monkeypatch.setattr(dg, "confirm_effect", confirm_effect)
        return dg.confirm_candidates(dg.RunView.__new__(dg.RunView), out, confirm), seen, refitted

    out, seen, refitted = diagnose_with(0.7)
    assert refitted == ["time-offset", "grip-compliance"] and out["refit_mimicked"] == ["grip-compliance"]
    assert seen[0] == ("grip-compliance", "time-offset", {"k": 1.0})  # the screening's estimate, at the nominal fit
    assert "sticky-patch" not in [s[0] for s in seen]  # not significant at alpha
    assert out["selected"] == "time-offset" and [t["effect"] for t in out["indistinguishable"]] == ["grip-compliance"]
    assert "cannot tell time-offset from grip-compliance" in out["summary"]
    assert any("is refitted too" in r and "time-offset reproduces 70% of it -> refit" in r for r in out["rules"])
    little, _, refitted = diagnose_with(0.3)
    assert refitted == ["time-offset"] and not little.get("refit_mimicked") and little["indistinguishable"] == []
    full, seen, refitted = diagnose_with(0.7, confirm=1)
    assert refitted == ["time-offset"] and seen == [] and full["selected"] == "time-offset"


def test_a_refit_that_moves_toward_the_measurement_explains_it_though_its_chamfer_rises(monkeypatch, tmp_path):
    """Rule 3 with a sensor effect: a point-noise refit raises the Chamfer between the clouds (noise on both
    adds to their distance) yet check accepts it and its rollouts' summaries moved toward the measurement
    (summary bias 41% lower, 11 standard errors): the effect is named. A refit that check accepts only through
    a wider posterior predictive (bias 4% lower, 0.5 standard errors), one whose small fall is significant
    (8% < 10%), one stored without the bias, and a physics effect with the same numbers (its Chamfer 5% higher,
    4.3 standard errors of the difference) are not confirmed; a physics effect whose Chamfer moves less than its
    Monte-Carlo error (+0.01 cm, standard error 0.04 cm) is, on the same bias."""
    from softsbi.workflows import diagnose as dg

    rank = {"effect": "point-noise", "description": "noise", "kind": "sensor", "generic": False, "statistic": 1.0,
            "explained_fraction": 0.21, "adjusted_exceed": 0, "n_null": 200, "adjusted_p_value": 1 / 201,
            "adjusted_p_text": "p <= 1/201", "estimate": {"noise_std": 0.004}}

    def diagnose_with(bias, after=0.01205, se=0.0001):
        out = {"ranking": [rank], "significant": ["point-noise"], "alpha": 0.01, "min_explained": 0.1,
               "confirmed": [], "selected": "point-noise", "verdict": "missing-effect",
               "misspecification": {"p_text": "p <= 2/201", "misspecified": True}}
        monkeypatch.setattr(dg, "confirm_effect", lambda run, name, budget, workers, **kw: {
            "effect": name, "run": str(tmp_path / name), "chamfer_before_m": 0.01144, "chamfer_after_m": after,
            "chamfer_after_se_m": se, "chamfer_before_se_m": se, "drop": 1 - after / 0.01144, "posterior_mean": {},
            "misspecification_after": {"p_text": "p = 0.45", "misspecified": False, "alpha": 0.2}, **bias})
        return dg.confirm_candidates(dg.RunView.__new__(dg.RunView), out, 1)

    named = diagnose_with({"bias_fall": 0.41, "bias_fall_z": 11.0})
    assert named["verdict"] == "missing-effect" and named["selected"] == "point-noise"
    assert "moved toward the measurement" in named["summary"] and "5% higher" in named["summary"]
    assert any("summary bias 41% lower, z = 11.0" in r and r.endswith("-> explained") for r in named["rules"])
    for bias in ({"bias_fall": 0.04, "bias_fall_z": 0.5}, {"bias_fall": 0.08, "bias_fall_z": 3.0}, {}):
        wide = diagnose_with(bias)
        assert wide["verdict"] == "misspecified-unexplained" and wide["selected"] is None, bias
        assert wide["partial"] == "point-noise" and "not confirmed" in wide["summary"]
        assert any(r.endswith("not confirmed (the error does not fall)") for r in wide["rules"])
    assert "Nor did its rollouts move toward the measurement" in diagnose_with({"bias_fall": 0.04,
                                                                                  "bias_fall_z": 0.5})["summary"]
    # a physics effect changes the motion, which the Chamfer measures: with a Chamfer significantly higher
    # (0.061 cm, standard error of the difference 0.014 cm) the same bias does not confirm it
    rank["kind"] = "physics"
    physics = diagnose_with({"bias_fall": 0.41, "bias_fall_z": 11.0})
    assert physics["verdict"] == "misspecified-unexplained" and "moved toward the measurement all" not in physics["summary"]
    assert ("with a Chamfer higher by less than 2 standard errors and 10%: +0.06 cm, standard error of the "
            "difference 0.01 cm") in physics["summary"]
    # ... nor without the nominal's standard error (a refit stored before it was kept)
    assert dg._moves_toward({"bias_fall": 0.41, "bias_fall_z": 11.0, "chamfer_before_m": 0.01144,
                             "chamfer_after_m": 0.01145, "chamfer_after_se_m": 0.0003}) is False
    # a physics effect too small in the data for the Chamfer to see: it moves by less than its Monte-Carlo error
    small = diagnose_with({"bias_fall": 0.41, "bias_fall_z": 11.0}, after=0.01145, se=0.0003)
    assert small["verdict"] == "missing-effect" and small["selected"] == "point-noise"
    assert "moved toward the measurement all the same" in small["summary"]
    assert "+0.00 cm, standard error of the difference 0.04 cm" in small["summary"]
    assert not diagnose_with({"bias_fall": 0.04, "bias_fall_z": 0.5}, after=0.01145, se=0.0003)["named_effects"]


def test_a_resumed_diagnosis_judges_a_stored_pair_refit_as_a_pair(monkeypatch, tmp_path):
    """No single refit explains the misfit, the refit with both screened effects does: both are named. Deciding
    again on the stored diagnosis (a resumed or redecided one, whose refits include the pair) gives the same
    verdict: the pair is judged as a pair, never selected as if it were one effect."""
    from softsbi.workflows import diagnose as dg

    def rank(name):
        return {"effect": name, "description": name, "kind": "physics", "generic": False, "statistic": 1.0,
                "explained_fraction": 0.3, "adjusted_exceed": 0, "n_null": 200, "adjusted_p_value": 1 / 201,
                "adjusted_p_text": "p <= 1/201", "estimate": {"k": 1.0}}

    def refit(run, name, budget, workers, **kw):
        name = name if isinstance(name, str) else "+".join(name)
        ok = "+" in name
        return {"effect": name, "run": str(tmp_path / name), "chamfer_before_m": 0.03,
                "chamfer_after_m": 0.012 if ok else 0.02, "chamfer_after_se_m": 0.0005,
                "drop": 1 - (0.012 if ok else 0.02) / 0.03, "posterior_mean": {},
                "misspecification_after": {"p_text": "p = 0.5" if ok else "p = 0.065", "misspecified": not ok,
                                           "alpha": 0.2}}

    monkeypatch.setattr(dg, "confirm_effect", refit)
    out = {"ranking": [rank("wind"), rank("calibration-offset")], "significant": ["wind", "calibration-offset"],
           "alpha": 0.01, "min_explained": 0.1, "confirmed": [], "selected": "wind", "verdict": "missing-effect",
           "misspecification": {"p_text": "p <= 2/201", "misspecified": True}}
    view = dg.RunView.__new__(dg.RunView)
    first = dg.confirm_candidates(view, out, 2)
    assert first["named_effects"] == ["wind", "calibration-offset"] and first["selected"] == "wind"
    assert [c["effect"] for c in first["confirmed"]][-1] == "wind+calibration-offset"
    again = dg.confirm_candidates(view, json.loads(json.dumps(first)), 2)
    assert (again["verdict"], again["selected"], again["named_effects"]) == ("missing-effect", "wind",
                                                                             ["wind", "calibration-offset"])
    assert "Refitting with both" in again["summary"]


def test_a_rejected_refit_that_lowered_the_error_says_how_to_continue_it(toy_runs, tmp_path):
    """A refit that lowers the error while check still rejects it may not have converged: its sentence gives the
    command that continues it, and that command's mechanism (a refit confirmed again with more rounds) resumes the
    stored refit, keeping its rounds, instead of starting over."""
    hidden, _ = toy_runs
    c = {"effect": "toy-wind", "run": str(hidden / "refit-toy-wind"), "drop": 0.07, "budget": {"rounds": 3, "sims_per_round": 100},
         "misspecification_after": {"misspecified": True, "p_text": "p = 0.06", "alpha": 0.2}}
    hint = (f"`softsbi diagnose {hidden} --confirm-rounds 6 --confirm-sims 100` continues the stored refits from "
            f"round 4 to 6")
    assert hint in dg._continue_hint(c)
    # no hint where the error did not fall, where check accepts, or for a refit stored before its budget was kept
    assert dg._continue_hint({**c, "drop": -0.1}) == ""
    assert dg._continue_hint({**c, "misspecification_after": {"misspecified": False}}) == ""
    assert dg._continue_hint({k: v for k, v in c.items() if k != "budget"}) == ""
    # a refit that check accepts while the data barely inform its added parameter may not have converged either
    loose = {**c, "drop": 0.04, "misspecification_after": {"misspecified": False, "p_text": "p = 1", "alpha": 0.2},
             "estimates": {"wind_speed": {"mean": 1.0, "width_ratio": 0.68, "informed": False},
                           "gust": {"mean": 0.1, "width_ratio": 0.3, "informed": True}}}
    h = dg._continue_hint(loose)
    assert "barely inform wind_speed (its 90% interval spans 68% of the prior's)" in h and "gust" not in h and hint in h
    tight = {**loose, "estimates": {"wind_speed": {"mean": 1.0, "width_ratio": 0.3, "informed": True}}}
    assert dg._continue_hint(tight) == ""
    # estimates stored before their width was kept say nothing
    assert dg._continue_hint({**loose, "estimates": {"wind_speed": {"mean": 1.0}}}) == ""
    # a copy of the nominal run without the other tests' refits, so this refit starts from nothing
    nominal = tmp_path / "hidden"
    shutil.copytree(hidden, nominal, ignore=shutil.ignore_patterns("refit-*"))
    run = load_run(nominal)
    first = dg.confirm_effect(run, "toy-wind", {"rounds": 1, "sims_per_round": 100}, workers=1, n_null=12, max_null=12,
                              widen=False)
    out = Path(first["run"])
    assert first["budget"] == {"rounds": 1, "sims_per_round": 100} and out == nominal / "refit-toy-wind"
    # each added parameter's estimate keeps how much the data narrowed it (the refit report's contraction)
    report = json.loads((out / "report.json").read_text())
    assert first["estimates"]
    for k, e in first["estimates"].items():
        assert e["width_ratio"] == report["contraction"][k]["width_ratio"]
        assert e["informed"] == report["contraction"][k]["informed"]
    theta0 = RunStore.open(out / "run.zarr", mode="r").round_data(0)["theta"].copy()
    again = dg.confirm_effect(run, "toy-wind", {"rounds": 2, "sims_per_round": 100}, workers=1, n_null=12,
                              max_null=12, widen=False)
    store = RunStore.open(out / "run.zarr", mode="r")
    assert again["budget"]["rounds"] == 2 and store.completed_rounds() == [0, 1]
    np.testing.assert_array_equal(store.round_data(0)["theta"], theta0)
