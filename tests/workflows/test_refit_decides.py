"""Rule 2's share as a screening threshold only: a significant candidate below it is refitted and named only when
its refit explains the misfit (``diagnose.refit_decides``); a sensor effect seen in the local thickness (point
noise) is judged in that summary too (``nominal_thickness_bias``)."""
import types

import numpy as np
import pytest

from softsbi.workflows import diagnose as dg
from softsbi.workflows.stats import run_thickness

toy = pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")


def _rank(name, frac, p, generic=False, kind="sensor"):
    return {"effect": name, "description": name, "kind": kind, "generic": generic, "statistic": 1.0,
            "explained_fraction": frac, "adjusted_exceed": round(p * 201) - 1, "n_null": 200, "adjusted_p_value": p,
            "adjusted_p_text": f"p = {p:.2g}", "estimate": {"noise_std": 0.008}}


def test_refit_decides_is_the_first_significant_named_candidate_whatever_its_share():
    ranking = [_rank("generic-drag", 0.3, 0.005, generic=True), _rank("point-noise", 0.06, 0.02),
               _rank("wind", 0.02, 0.01, kind="physics"), {"effect": "grip", "error": "failed"}]
    assert dg.refit_decides(ranking, 0.05) == "point-noise"
    assert dg.refit_decides(ranking, 0.015) == "wind"  # point noise is not significant at that level
    assert dg.refit_decides(ranking[:1], 0.05) is None and dg.refit_decides(ranking, 0.001) is None


def _weak_diagnosis():
    """What diagnose_run leaves when no named candidate passes rule 2 and refits decide (confirm > 0)."""
    sel = [{"given": [], "best": "point-noise", "adjusted_p_value": 0.02, "adjusted_p_text": "p = 0.02",
            "explained_fraction": 0.06, "accepted": False, "passed_over": []}]
    return {"ranking": [_rank("point-noise", 0.06, 0.02), _rank("generic-drag", 0.2, 0.005, generic=True)],
            "significant": ["point-noise"], "refit_decides": "point-noise", "alpha": 0.05, "min_explained": 0.1,
            "confirmed": [], "selected": "point-noise", "verdict": "missing-effect", "selection": sel,
            "misspecification": {"p_text": "p = 0.04", "misspecified": True}}


def _fake_refits(monkeypatch, fields):
    calls = []

    def fake(run, name, budget, workers, **kw):
        name = name if isinstance(name, str) else "+".join(name)
        calls.append(name)
        after, p, extra = fields[name]
        return {"effect": name, "run": name, "chamfer_before_m": 0.0175, "chamfer_after_m": after,
                "chamfer_after_se_m": 0.0002, "drop": 1 - after / 0.0175, "posterior_mean": {},
                "misspecification_after": {"p_value": p, "p_text": f"p = {p:.2g}", "misspecified": p <= kw["alpha"],
                                           "alpha": kw["alpha"]},
                "ranking_after": [{"effect": "calibration-offset", "kind": "sensor", "generic": False,
                                   "explained_fraction": 0.5, "adjusted_p_value": 0.005, "adjusted_p_text": "p = 0.005"}],
                **extra}
    monkeypatch.setattr(dg, "confirm_effect", fake)
    return calls


def test_a_candidate_below_the_share_is_named_when_its_refit_explains_the_misfit(monkeypatch):
    """Hidden point noise in a fling (mujoco-more 832): ranked first at p = 0.02 with 6% of the residual; its refit
    is accepted by check and its thickness bias falls 73% (z 8.7) while check's summaries hardly move: named, and
    the sentence and rules say the refit decided. The passing generic term is refitted too, for the third verdict."""
    calls = _fake_refits(monkeypatch, {
        "point-noise": (0.0186, 0.71, {"bias_fall": 0.05, "bias_fall_z": 0.4, "thickness_bias_fall": 0.73,
                                       "thickness_bias_fall_z": 8.7}),
        "generic-drag": (0.017, 0.5, {})})
    out = dg.confirm_candidates(dg.RunView.__new__(dg.RunView), _weak_diagnosis(), 2)
    assert calls == ["point-noise", "generic-drag"]
    assert out["verdict"] == "missing-effect" and out["selected"] == "point-noise"
    assert out["named_effects"] == ["point-noise"]
    assert "below the 10% the screening asks for" in out["summary"] and "so its refit decided" in out["summary"]
    assert any(r.startswith("2. with refits, when no named candidate passes") and r.endswith("explains 6% -> refit")
               for r in out["rules"])
    assert any("thickness bias 73% lower, z = 8.7" in r and r.endswith("-> explained") for r in out["rules"])


def test_a_candidate_below_the_share_whose_refit_does_not_explain_stays_the_third_verdict(monkeypatch):
    """The same candidate whose refit check accepts but moves neither the Chamfer nor any bias (a wider posterior
    predictive only): the third verdict, and no pair is built on it (one refit of it, none of a pair), though
    check of its refit ranks another candidate first."""
    calls = _fake_refits(monkeypatch, {"point-noise": (0.0186, 0.71, {"bias_fall": 0.05, "bias_fall_z": 0.4,
                                                                      "thickness_bias_fall": 0.02,
                                                                      "thickness_bias_fall_z": 0.3}),
                                       "generic-drag": (0.017, 0.5, {})})
    out = dg.confirm_candidates(dg.RunView.__new__(dg.RunView), _weak_diagnosis(), 2)
    assert "point-noise+calibration-offset" not in calls and calls.count("point-noise") == 1
    assert out["verdict"] == "misspecified-unexplained" and out["selected"] is None and out["named_effects"] == []
    assert out["partial"] == "point-noise" and out["screening_verdict"] == "missing-effect"
    assert out["summary"].startswith("Misspecified by nothing installed")
    # a refit that check rejects: the same
    _fake_refits(monkeypatch, {"point-noise": (0.015, 0.01, {}), "generic-drag": (0.017, 0.5, {})})
    out = dg.confirm_candidates(dg.RunView.__new__(dg.RunView), _weak_diagnosis(), 1)
    assert out["verdict"] == "misspecified-unexplained" and out["partial"] == "point-noise"


def test_a_sensor_refit_moves_toward_the_measurement_in_check_summaries_or_its_thickness():
    c = {"adds_sensor_effect": True, "bias_fall": 0.05, "bias_fall_z": 0.4}
    assert not dg._moves_toward(c)
    assert dg._moves_toward({**c, "thickness_bias_fall": 0.73, "thickness_bias_fall_z": 8.7})
    assert not dg._moves_toward({**c, "thickness_bias_fall": 0.73, "thickness_bias_fall_z": 1.5})  # within its error
    assert not dg._moves_toward({**c, "thickness_bias_fall": 0.08, "thickness_bias_fall_z": 5.0})  # below the share
    assert not dg._moves_toward({**c, "adds_sensor_effect": False, "thickness_bias_fall": 0.73,
                                 "thickness_bias_fall_z": 8.7})  # a physics effect: the Chamfer decides


def test_only_effects_that_ask_for_the_thickness_summary_are_judged_in_it():
    assert dg.wants_thickness(["point-noise"]) and dg.wants_thickness(["wind", "point-noise"])
    assert not dg.wants_thickness(["time-offset", "calibration-offset", "wind"])
    assert not dg.wants_thickness(["not-installed"])


def test_run_thickness_sees_point_noise_in_the_metric_frames_as_the_sensor_does():
    """A flat 30 cm sheet (1000 points a frame) is 0 thick; 5 mm of noise makes it about 3-5 mm thick; points at
    or below the run's visibility threshold are not seen, and only the metric frames are summarised."""
    rng = np.random.default_rng(0)
    sheet = np.column_stack([rng.uniform(0, 0.3, 1000), rng.uniform(0, 0.3, 1000), np.full(1000, 0.2)])
    noisy = sheet + rng.normal(0, 0.005, sheet.shape)
    low = sheet.copy()
    low[:, 2] = 0.001
    low[:50, 2] = 0.2  # only a few points above the threshold are seen
    run = types.SimpleNamespace(dense=np.stack([sheet, noisy, low]), metric_min_z=0.01, metric_frames=[1, 0])
    t = run_thickness(run, run.dense)
    assert t.shape == (2,) and t[1] < 1e-9 and 0.003 < t[0] < 0.006
    run.metric_frames = [2]
    assert run_thickness(run, run.dense)[0] < 1e-9  # the 50 seen points are flat


def test_diagnose_refits_a_significant_candidate_below_the_share_and_names_it_when_the_refit_explains(toy_runs_refit):
    """End to end on the toy's hidden wind (it explains most of the residual): with rule 2's share set above what
    it explains, diagnose without refits gives the third verdict; with a refit, the refit decides and names it."""
    hidden = toy_runs_refit
    d0 = dg.diagnose_run(hidden, workers=1, confirm=0, min_explained=0.999)
    assert d0["verdict"] == "misspecified-unexplained" and d0["refit_decides"] is None and d0["significant"] == []
    d1 = dg.diagnose_run(hidden, workers=1, confirm=1, min_explained=0.999)
    assert d1["refit_decides"] == "toy-wind" and [c["effect"] for c in d1["confirmed"]] == ["toy-wind"]
    assert d1["verdict"] == "missing-effect" and d1["named_effects"] == ["toy-wind"]
    assert "so its refit decided" in d1["summary"]


@pytest.fixture(scope="module")
def toy_runs_refit(tmp_path_factory):
    """The toy's hidden wind, fitted as test_diagnostics fits it."""
    from softsbi.workflows.fit import FitConfig, run_fit
    from softsbi.workflows.measurement import simulate_recording
    meas = simulate_recording("toy-gauss", toy.toy_scenario(4), {"a": 0.3, "b": -0.2, "wind": 0.45},
                              effects=["toy-wind"], n_points=16, n_dense=64, seed=11)
    out = tmp_path_factory.mktemp("refit_decides") / "hidden"
    run_fit(out, meas, FitConfig(backend="toy-gauss", estimator="rkhs", rounds=2, sims_per_round=150, workers=1,
                                 n_points=16, n_eval=30, n_dense=64, seed=2,
                                 estimator_options={"max_epochs": 80, "hidden": [64, 64]}))
    return out


def test_pool_thickness_reads_the_rollouts_of_the_first_n_summaries_as_the_sensor_sees_them():
    """A pool of a flat sheet and a crumpled one (a fine grid with its vertices jittered by 5 mm): each rollout's
    thickness per metric frame, for the first ``n`` successful rollouts (those of ``features[:n]``)."""
    from softsbi.workflows.stats import pool_thickness, rollout_features
    g = np.linspace(0, 0.3, 21)
    xx, yy = np.meshgrid(g, g)
    flat = np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, 0.2)])
    faces = np.array([[i * 21 + j, i * 21 + j + 1, (i + 1) * 21 + j] for i in range(20) for j in range(20)]
                     + [[i * 21 + j + 1, (i + 1) * 21 + j + 1, (i + 1) * 21 + j] for i in range(20) for j in range(20)])
    rough = flat + np.random.default_rng(1).normal(0, 0.005, flat.shape)
    run = types.SimpleNamespace(dense=np.zeros((3, 800, 3)), metric_min_z=0.01, metric_frames=[1, 2], config={})
    roll = [{"vertices": np.stack([v] * 3), "faces": faces, "sample": i, "info": {}}
            for i, v in enumerate([flat, rough, rough])]
    pool = types.SimpleNamespace(run=run, rollouts=roll,
                                 features=np.array([rollout_features(run, r, 1000 + r["sample"]) for r in roll]))
    t = pool_thickness(pool, 2)
    assert t.shape == (2, 2) and np.all(t[0] < 1e-9) and np.all(t[1] > 0.001)


def test_diagnose_table_marks_the_candidate_a_refit_decided_on(monkeypatch):
    """`softsbi diagnose`'s table: the candidate below rule 2's share reads "refit" in the named column, not
    "yes" (the screening did not name it)."""
    from softsbi.cli import diagnosis_table_rows
    _fake_refits(monkeypatch, {"point-noise": (0.0186, 0.71, {"bias_fall": 0.05, "bias_fall_z": 0.4}),
                               "generic-drag": (0.017, 0.5, {})})
    out = dg.confirm_candidates(dg.RunView.__new__(dg.RunView), _weak_diagnosis(), 2)
    rows = {r[1]: r for r in diagnosis_table_rows({**out, "n_null": 200})}
    assert rows["point-noise"][6] == "refit" and rows["generic-drag"][6] == "no"
