"""diagnose's verdicts: on hand-built refits (the decision and the refits it proposes, as diagnose_run drives them),
how a refit is set up, and on a MuJoCo lift measurement (slow: it fits the nominal model)."""
import types

import pytest

from result_helpers import candidate, joint, refit, score
from softsbi.core.results import Diagnosis
from softsbi.effects.builtin import ExtraDamping, Wind
from softsbi.scenarios.builtin import lift_scenario
from softsbi.workflows.criticism.check import check_run
from softsbi.workflows.criticism.decide import decide, next_refit
from softsbi.workflows.criticism.diagnose import diagnose_run
from softsbi.workflows.criticism.evidence import REFIT_PROPOSAL
from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording
from softsbi.plugins import registry
from softsbi.core.defaults import CheckSettings, DiagnoseSettings

OPTS = {"grid": 5}


def _hidden_wind_fit(tmp_path):
    sc = lift_scenario(None)
    space = registry().simulator("mujoco-flex")(**OPTS).param_space(sc)
    truth = {**space.midpoint(), "wind_x": 0.0, "wind_y": 1.8}
    meas = simulate_recording("mujoco-flex", sc, truth, backend_options=OPTS, effects=["wind"], n_dense=300)
    cfg = FitConfig(backend="mujoco-flex", backend_options=OPTS, rounds=2, sims_per_round=60, workers=1, n_eval=30,
                    n_dense=300, seed=0)
    run_fit(tmp_path / "nominal", meas, cfg)
    return tmp_path / "nominal"


@pytest.mark.slow
def test_generic_force_terms_give_the_third_verdict_with_where_and_how_much(tmp_path, monkeypatch):
    """A hidden wind; wind and extra damping marked as generic force terms (as the generic library's constant /
    drag effects are): no named candidate is left to refit, so the verdict is misspecified-unexplained, with the
    residual's shape and the best generic term; check agrees. Without the flag the wind is refitted and named."""
    run = _hidden_wind_fit(tmp_path)
    monkeypatch.setattr(Wind, "generic", True, raising=False)
    monkeypatch.setattr(ExtraDamping, "generic", True, raising=False)
    d = diagnose_run(run, effects=["wind", "extra-damping"], settings=DiagnoseSettings(workers=1, confirm=2))
    chk = check_run(run, plot=False, effects=["wind", "extra-damping"], settings=CheckSettings(workers=1))
    assert chk.test.misspecified and d.test == chk.test  # one null, one test
    assert d.verdict == "misspecified-unexplained" and d.refits == () and d.decision.named == ()
    assert d.generic.effect == "wind" and d.ranking[0].effect == "wind" and d.ranking[0].generic
    assert d.ranking[0].explained > 0.3
    res = d.residual
    assert res.frames_flagged and len(res.worst_regions) == 2
    # the wind blows along +y: the measured cloth is displaced that way
    assert res.direction == "+y" and res.centroid_offset_cm[1] > 0
    # without the flag the same candidates: the wind is refitted and its refit explains the misfit (recompute: the
    # stored check keeps the candidates' flags as they were)
    monkeypatch.setattr(Wind, "generic", False)
    monkeypatch.setattr(ExtraDamping, "generic", False)
    d2 = diagnose_run(
        run,
        effects=["wind", "extra-damping"],
        recompute=True,
        settings=DiagnoseSettings(workers=1, confirm=1, refit_rounds=2, refit_sims=60),
    )
    assert d2.verdict == "missing-effect" and d2.decision.named == ("wind",)


# ---------------------------------------------------------------------------------------------------------------
# the decision on hand-built refits: the nominal fit misses the measurement (joint test beyond all 200 nulls)

NOMINAL = score(30, 0.5)
REJECTS = joint(0, 0)
RANKING = (candidate("wind", 0.28), candidate("extra-damping", 0.15), candidate("calibration-offset", 0.12,
                                                                               kind="sensor"))


def _outside(value, ranking=()):
    """A refit check rejects (p <= 2/201) with energy score ``value``."""
    return lambda effects: refit(effects, value, joint(0, 0), ranking=ranking)


def _inside(value, p_exceed=100):
    """A refit check accepts (joint p = 2 (p_exceed + 1) / 201) with energy score ``value``."""
    return lambda effects: refit(effects, value, joint(p_exceed, p_exceed))


def diagnose_with(refits: dict, confirm: int = 2, ranking=RANKING) -> Diagnosis:
    """diagnose_run's loop on the fake refits ``{effects: factory}``: refit what next_refit proposes, then decide."""
    made = []
    while (nxt := next_refit(REJECTS, ranking, NOMINAL, made, confirm)) is not None:
        made.append(refits[nxt](nxt))
    return Diagnosis(run="run", candidates=tuple(c.effect for c in ranking), alpha=0.05, k_se=2.0, test=REJECTS,
                     ranking=ranking, nominal=NOMINAL, refits=tuple(made),
                     decision=decide(REJECTS, NOMINAL, made), confirm=confirm)


def test_a_trained_candidate_is_not_informed_when_its_task_informs_none_of_its_own_parameters():
    """uninformed_candidates reads each trained candidate's training report: an effect is listed (with its narrowest
    width) only when every one of its own parameters' held-out widths is above INFORMED_MAX_RATIO; the nominal
    model's parameters in the same report do not count, and a task without a report says nothing."""
    from softsbi.core.results.fitreport import Contraction
    from softsbi.inference.contraction import INFORMED_MAX_RATIO
    from softsbi.workflows.criticism.evidence import uninformed_candidates

    def task(**widths):
        report = types.SimpleNamespace(contraction={k: Contraction(width_ratio=v, informed=v <= INFORMED_MAX_RATIO)
                                                    for k, v in widths.items()})
        return types.SimpleNamespace(report=report), None, None

    trained = {"wind": task(bend=0.1, wind_x=0.9, wind_y=0.45),  # wind_y informed
               "extra-damping": task(bend=0.1, damping_rate=0.91),
               "table-slope": task(bend=0.2, slope_x=0.98, slope_y=0.97),
               "air-drag": (types.SimpleNamespace(report=None), None, None)}
    assert uninformed_candidates(trained) == {"extra-damping": 0.91, "table-slope": 0.97}


def test_a_named_effect_whose_refit_is_still_misspecified_gives_the_third_verdict():
    """The refit re-checked with check's test separates 'the effect explains the misfit' from 'it explains a part
    but the model is still misspecified' (data from another engine): both refits lower the score, check rejects
    both and the pair built on the better one; the one lowering the score most explains a part."""
    d = diagnose_with({("wind",): _outside(25, RANKING[1:]), ("extra-damping",): _outside(28),
                       ("wind", "extra-damping"): _outside(24)})
    assert [r.effects for r in d.refits] == [("wind",), ("extra-damping",), ("wind", "extra-damping")]
    assert d.verdict == "misspecified-unexplained" and d.decision.partial == ("wind",) and d.decision.named == ()
    assert not d.refit(("extra-damping",)).adequate and d.refit(("calibration-offset",)) is None and d.confirm == 2


def test_refits_that_raise_the_score_explain_no_part_and_build_no_pair():
    """Where every refit raises the energy score (real lift_tan: the time-offset refit 5% higher), no refit is
    said to explain a part and no pair is built on one."""
    d = diagnose_with({("wind",): _outside(31.5, RANKING[1:]), ("extra-damping",): _outside(34)})
    assert len(d.refits) == 2 and d.verdict == "misspecified-unexplained" and d.decision.partial == ()
    assert d.decision.gain is None  # no refit lowers the score by more than k_se standard errors


def test_a_refit_that_check_accepts_is_named_over_one_with_a_lower_score_that_check_rejects():
    d = diagnose_with({("wind",): _outside(20), ("extra-damping",): _inside(22)})
    assert d.verdict == "missing-effect" and d.decision.named == ("extra-damping",) and d.decision.partial == ()
    assert not d.refit(("wind",)).adequate


def test_a_refit_that_check_accepts_and_that_lowers_the_score_names_the_effect():
    d = diagnose_with({("wind",): _inside(12)}, confirm=1)
    assert d.verdict == "missing-effect" and d.decision.named == ("wind",) and len(d.refits) == 1
    assert d.decision.gain.z > 2


def test_a_refit_check_accepts_but_whose_score_rises_explains_nothing():
    """Check accepts a refit whose posterior predictive is only wider (real lift_tan2 with time-offset: p = 0.32,
    the error 26% higher): the score does not fall, so the third verdict, with nothing explaining a part."""
    d = diagnose_with({("wind",): _inside(57)}, confirm=1)
    assert d.verdict == "misspecified-unexplained" and d.decision.partial == ()
    assert d.refit(("wind",)).adequate and d.decision.gain is None


def test_a_refit_is_judged_at_the_diagnosis_level():
    """The refit's test decides at the nominal test's alpha (0.05), not at a more lenient one: a wind refit 10% lower
    at joint p = 0.13 (data from another engine) is adequate and named; the same refit tested at 0.2 is not."""
    at = joint(12, 12)  # 2 x 13/201: p = 0.13
    assert at.p_value == pytest.approx(26 / 201) and not at.misspecified
    d = diagnose_with({("wind",): lambda e: refit(e, 0.027, at)}, confirm=1)
    assert d.decision.named == ("wind",)
    lenient = diagnose_with({("wind",): lambda e: refit(e, 0.027, joint(12, 12, alpha=0.2))}, confirm=1)
    assert lenient.verdict == "misspecified-unexplained" and lenient.decision.partial == ("wind",)


def test_a_pair_is_named_only_when_no_single_refit_explains_and_the_pair_does():
    """Singles outside, the pair with the first effect's refit's next candidate inside and lower -> the pair is
    named; the pair outside too -> the third verdict; a single refit that explains the misfit -> no pair refit."""
    lead = (candidate("extra-damping", 0.4), candidate("calibration-offset", 0.1, kind="sensor"))
    refits = {("wind",): _outside(25, lead), ("extra-damping",): _outside(28),
              ("wind", "extra-damping"): _inside(15)}
    d = diagnose_with(refits)
    assert [r.effects for r in d.refits] == [("wind",), ("extra-damping",), ("wind", "extra-damping")]
    assert d.verdict == "missing-effect" and d.decision.named == ("wind", "extra-damping")
    assert d.refit(("calibration-offset",)) is None and d.decision.gain.z > 2  # the pair's gain over wind's refit
    refits[("wind", "extra-damping")] = _outside(20)
    d = diagnose_with(refits)
    assert d.verdict == "misspecified-unexplained" and d.decision.named == () and d.decision.partial == ("wind",)
    refits[("wind",)] = _inside(12)
    d = diagnose_with(refits)
    assert d.decision.named == ("wind",) and not any(len(r.effects) == 2 for r in d.refits)


def test_the_second_effect_of_a_pair_is_what_check_of_the_first_refit_still_finds():
    """The pair adds to the best single refit the first named candidate its own check ranks (a hidden wind + extra
    damping: the nominal's screening ranked the calibration offset second, the wind refit's check ranks a generic
    term, then extra damping), never a generic term; with no named candidate left there, no pair."""
    ranking = (RANKING[0], RANKING[2], RANKING[1])  # wind, calibration-offset, extra-damping
    lead = (candidate("generic-drag", 0.6, generic=True), candidate("extra-damping", 0.4, 2),
            candidate("calibration-offset", 0.1, 60, kind="sensor"))
    refits = {("wind",): _outside(25, lead), ("calibration-offset",): _outside(29),
              ("wind", "extra-damping"): _inside(12)}
    d = diagnose_with(refits, ranking=ranking)
    assert [r.effects for r in d.refits] == [("wind",), ("calibration-offset",), ("wind", "extra-damping")]
    assert d.decision.named == ("wind", "extra-damping")
    refits[("wind",)] = _outside(25, lead[:1])
    d = diagnose_with(refits, ranking=ranking)
    assert len(d.refits) == 2 and d.verdict == "misspecified-unexplained" and d.decision.partial == ("wind",)


def test_a_pair_builds_on_the_refit_that_lowers_the_score_most_not_the_screenings_first():
    """Near-collinear effects tie in the linearised screening (a wind and extra damping in a fling); the refits tell
    them apart: the damping refit lowers the score most, so the pair builds on it (hidden: extra damping +
    calibration offset). With no refit lowering the score, no pair is built."""
    lead = (candidate("calibration-offset", 0.4, kind="sensor"),)
    refits = {("wind",): _outside(28, lead), ("extra-damping",): _outside(15, lead),
              ("extra-damping", "calibration-offset"): _inside(10)}
    d = diagnose_with(refits)
    assert d.refits[-1].effects == ("extra-damping", "calibration-offset")
    assert d.verdict == "missing-effect" and d.decision.named == ("extra-damping", "calibration-offset")
    refits.update({("wind",): _outside(31, lead), ("extra-damping",): _outside(32, lead)})
    d = diagnose_with(refits)
    assert len(d.refits) == 2 and d.verdict == "misspecified-unexplained" and d.decision.partial == ()


# ---------------------------------------------------------------------------------------------------------------
# how a refit is set up


def test_refits_use_truncated_proposals_and_observe_each_simulation_once(monkeypatch, tmp_path):
    """refit_model: the nominal fit's settings with the effects added, truncated proposals, the refit budget where
    given, and no extra sensor draws whatever the nominal fit used (physics and sensor effects on one footing)."""
    import softsbi.workflows.criticism.diagnose as dg
    from softsbi.workflows.fit.config import FitConfig
    seen = {}

    class _Stop(Exception):
        pass

    def fake_fit(out, rec, cfg, **kwargs):
        seen["out"], seen["cfg"] = out, cfg
        raise _Stop

    class _Run:
        config = FitConfig(backend="toy-gauss", rounds=2, sims_per_round=40, proposal="corrected", sensor_draws=4,
                           effects=["time-offset"])
        effects = ["time-offset"]
        path = tmp_path
        report = types.SimpleNamespace(per_round=[types.SimpleNamespace(task=None)])  # round 1 trained in the fit

    monkeypatch.setattr(dg, "run_fit", fake_fit)
    monkeypatch.setattr(dg, "recording_from_run", lambda run: None)
    monkeypatch.setattr(dg, "trained_task", lambda run, effects, sims_per_round=None: None)  # no task trained them
    with pytest.raises(_Stop):
        dg.refit_model(_Run(), ["point-noise"], ["point-noise", "wind"], scale=None)
    cfg = seen["cfg"]
    assert seen["out"] == tmp_path / "refit-point-noise"
    assert cfg.proposal == "truncated" == REFIT_PROPOSAL and cfg.sensor_draws == 0
    # by default the nominal fit's budget
    assert cfg.effects == ["time-offset", "point-noise"] and (cfg.rounds, cfg.sims_per_round) == (2, 40)
    with pytest.raises(_Stop):
        dg.refit_model(_Run(), ["wind", "point-noise"], ["point-noise", "wind"], scale=None, rounds=3,
                       sims_per_round=40)
    assert seen["out"] == tmp_path / "refit-wind+point-noise"
    assert (seen["cfg"].rounds, seen["cfg"].sims_per_round, seen["cfg"].sensor_draws) == (3, 40, 0)
    amortised = _Run()
    amortised.report = types.SimpleNamespace(per_round=[types.SimpleNamespace(task="ab" * 32)])
    with pytest.raises(_Stop):
        dg.refit_model(amortised, ["wind"], ["point-noise", "wind"], scale=None)
    assert seen["cfg"].rounds is None  # the nominal fit stopped at a trained task: so does the refit, where it can

    def fake_amortised(run, effects, root, workers=None, plots=False, callbacks=None):
        seen["amortised"] = (tuple(effects), root)
        raise _Stop

    # a candidate whose model the task trained: its refit is the amortised posterior, unless rounds are asked for
    monkeypatch.setattr(dg, "trained_task", lambda run, effects, sims_per_round=None: ("task", None, None))
    monkeypatch.setattr(dg, "amortised_refit", fake_amortised)
    with pytest.raises(_Stop):
        dg.refit_model(amortised, ["wind"], ["point-noise", "wind"], scale=None)
    assert seen["amortised"] == (("wind",), tmp_path)
    with pytest.raises(_Stop):
        dg.refit_model(amortised, ["wind"], ["point-noise", "wind"], scale=None, rounds=3)
    assert seen["out"] == tmp_path / "refit-wind-sequential" and seen["cfg"].rounds == 3


def test_a_refits_estimates_carry_their_interval_how_much_the_data_narrowed_them_and_the_bound_they_press():
    """estimates(): the added effects' parameters from the refit's report.json (posterior mean, 90% interval,
    width over the prior's, a pressed prior bound with the wider prior to try); the nominal parameters are not
    among them."""
    from softsbi.core.results.fitreport import FitReport
    from softsbi.workflows.criticism.diagnose import estimates
    report = {"posterior_mean": {"bend": 1e-4, "wind_x": 0.1, "wind_y": 1.9},
              "posterior_q05": {"wind_x": -0.3, "wind_y": 1.7}, "posterior_q95": {"wind_x": 0.5, "wind_y": 2.0},
              "contraction": {"wind_x": {"width_ratio": 0.2}, "wind_y": {"width_ratio": 0.075}},
              "posterior_at_bounds": [{"param": "wind_y", "side": "upper", "bound": 2.0, "unit": "m/s", "mass": 0.4,
                                       "suggested_bounds": [-2.0, 4.0]},
                                      {"param": "bend", "side": "lower", "bound": 1e-6, "mass": 0.3}]}
    report = FitReport.from_json({"parameters": [], "posterior_median": {}, **report})
    wx, wy = estimates(report, ["wind"])
    assert (wx.name, wx.unit, wx.mean, wx.q05, wx.q95, wx.width_ratio, wx.pressed) == ("wind_x", "m/s", 0.1, -0.3,
                                                                                      0.5, 0.2, None)
    assert (wy.pressed, wy.suggested_bounds, wy.informed) == ("upper", (-2.0, 4.0), True)
    assert estimates(report, ["extra-damping"]) == ()  # not in this refit
