"""The fit's and calibrate's tables and sentences (softsbi/report/fit_text.py), rendered from hand-built results."""
from pathlib import Path

import numpy as np

from softsbi.core.results.fitreport import CalibrationResult
from softsbi.inference.contraction import bound_sentence
from softsbi.report.fit_text import (TextTable, best_fit_lines, calibration_lines, calibration_table,
                                     fit_report_lines, posterior_table)
from softsbi.workflows.fit.prior_widening import widening_sentence

RUN = Path("runs") / "lift"


def _report(**kw):
    rep = {"parameters": [{"name": "bend", "unit": "N*m"}, {"name": "mass", "unit": "kg"}],
           "contraction": {"bend": {"scale": "log", "center": 2e-4, "spread": 3.1, "width_ratio": 0.2,
                                    "informed": True},
                           "mass": {"scale": "linear", "center": 0.05, "spread": 0.01, "width_ratio": 0.8,
                                    "informed": False}},
           "posterior_q05": {"bend": 1e-4, "mass": 0.03}, "posterior_q95": {"bend": 4e-4, "mass": 0.07},
           "simulations": 600, "failed_simulations": 2, "wall_time_s": 123.4}
    return dict(rep, **kw)


def test_the_posterior_table_has_one_row_per_parameter_and_the_hidden_values_only_when_known():
    t = posterior_table(_report())
    assert isinstance(t, TextTable) and t.title == "Posterior (physical units)"
    assert t.columns == ("parameter", "unit", "estimate", "90% interval", "width / prior")
    assert t.rows == (("bend", "N*m", "0.0002 ×/÷ 3.1", "[0.0001, 0.0004]", "0.20"),
                      ("mass", "kg", "0.05 ± 0.01", "[0.03, 0.07]", "0.80 not informed"))
    t = posterior_table(_report(truth={"bend": 3e-4}, truth_in_90pct_interval={"bend": True, "mass": None}))
    assert t.columns[-2:] == ("hidden value", "inside 90%?")
    assert [r[-2:] for r in t.rows] == [("0.0003", "yes"), ("-", "-")]


def test_the_report_lines_come_in_order_and_end_with_what_was_written():
    rep = _report(posterior_at_bounds=[{"param": "mass", "side": "upper", "bound": 0.1, "unit": "kg", "mass": 0.4,
                                        "suggested_bounds": None}],
                  best_fit={"theta": {"bend": 2.5e-4, "mass": 0.06}, "chamfer_m": 0.0123, "source": "posterior",
                            "simulations_searched": 600},
                  chamfer_prior_m=0.05, chamfer_posterior_m=0.02, chamfer_posterior_n=30)
    lines = fit_report_lines(rep, RUN, widened=["prior widened after round 1: mass [0, 0.1] -> [0, 0.2]"])
    assert len(lines) == 6 and lines[0].startswith("estimate: mean ± std")
    assert lines[1].startswith("Note: mass's posterior presses against its upper prior bound 0.1 kg")
    assert lines[2] == "Note: prior widened after round 1: mass [0, 0.1] -> [0, 0.2]."
    assert lines[3] == ("Best fit: bend=0.00025 N*m, mass=0.06 kg; Chamfer 1.23 cm (posterior; the lowest of 600 "
                        "simulations; its rollout in clouds.png and softsbi view)")
    assert lines[4].startswith("Chamfer to the measurement: prior 5.00 cm -> posterior predictive 2.00 cm "
                               "(n=30 rollouts)")
    assert lines[5] == (f"600 simulations (2 failed), 123 s. Outputs in {RUN}: report.json, run.zarr, "
                        f"chamfer_rounds.png, posterior_pairs.png, clouds.png")


def test_a_posterior_worse_than_the_prior_adds_a_note_and_no_best_fit_adds_no_line():
    rep = _report(chamfer_prior_m=0.02, chamfer_posterior_m=0.03)
    lines = fit_report_lines(rep, RUN)
    assert len(lines) == 4 and lines[2].endswith(f"`softsbi check {RUN}` shows where and when it misses")
    assert best_fit_lines(rep) == []
    refined = {"theta": {"bend": 1e-4}, "mask_chamfer_px": 3.456, "source": "refine",
               "simulations_searched": 80, "refine": {"simulations": 40}}
    assert best_fit_lines(_report(best_fit=refined)) == [
        "Best fit: bend=0.0001 N*m; mask Chamfer 3.46 px (refine; the lowest of 80 simulations, 40 of them by CMA-ES "
        "from the posterior; its rollout in clouds.png and softsbi view)"]


#: how to read the posterior table: the line under it, whatever the fit
HOW_TO_READ = ("estimate: mean ± std, or geometric mean ×/÷ multiplicative spread for log-scaled parameters; width / "
               "prior: the 90% interval's width over the prior's in the parameter's own scale (log for log-scaled "
               "ones); above 0.5 the data do not inform the parameter")
WRITTEN = (f"600 simulations (2 failed), 123 s. Outputs in {RUN}: report.json, run.zarr, chamfer_rounds.png, "
           f"posterior_pairs.png, clouds.png")


def test_the_chamfer_line_says_its_rollouts_and_a_posterior_worse_than_the_prior_that_the_model_cannot_reach_it():
    """The issue's fit: 9.07 cm at the prior, 9.37 cm at the posterior predictive (5 rollouts): the line and the
    note that the model cannot reach the data; at 5.00 cm the line alone."""
    worse = fit_report_lines(_report(chamfer_prior_m=0.0907, chamfer_posterior_m=0.0937, chamfer_posterior_n=5), RUN)
    assert worse == [
        HOW_TO_READ,
        "Chamfer to the measurement: prior 9.07 cm -> posterior predictive 9.37 cm (n=5 rollouts) (3% higher)",
        "Note: rollouts at the posterior miss the measurement by more than rollouts at the prior: what the fit matched "
        "(the observed state) does not bring the simulated object closer, a sign that the model cannot reach the "
        f"data; `softsbi check {RUN}` shows where and when it misses",
        WRITTEN]
    better = fit_report_lines(_report(chamfer_prior_m=0.0907, chamfer_posterior_m=0.05, chamfer_posterior_n=5), RUN)
    assert better == [
        HOW_TO_READ,
        "Chamfer to the measurement: prior 9.07 cm -> posterior predictive 5.00 cm (n=5 rollouts) (45% lower)",
        WRITTEN]
    # a report without the number of rollouts (written before it was kept) says none
    assert fit_report_lines(_report(chamfer_prior_m=0.0907, chamfer_posterior_m=0.05), RUN)[1] == (
        "Chamfer to the measurement: prior 9.07 cm -> posterior predictive 5.00 cm (45% lower)")


def test_the_report_opens_with_the_hint_to_check_when_the_intervals_miss_more_hidden_values_than_chance():
    """A simulated recording's two hidden values both outside their 90% intervals (p = 0.01): the first line
    points to `softsbi check` of the run; one of two missed happens by chance: no hint; without hidden values the
    verdicts are not read."""
    both = {"bend": False, "mass": False}
    lines = fit_report_lines(_report(truth={"bend": 3e-4, "mass": 0.0}, truth_in_90pct_interval=both), RUN)
    assert lines == [
        "Note: the 90% intervals miss 2 of 2 hidden values, more than chance allows (p = 0.01 <= 0.05): the model "
        f"may lack an effect; `softsbi check {RUN}` shows where and when it misses the measurement.",
        HOW_TO_READ, WRITTEN]
    one = {"bend": False, "mass": True}
    assert fit_report_lines(_report(truth={"bend": 3e-4, "mass": 0.0}, truth_in_90pct_interval=one), RUN) == [
        HOW_TO_READ, WRITTEN]
    assert fit_report_lines(_report(truth_in_90pct_interval=both), RUN) == [HOW_TO_READ, WRITTEN]


#: the end of every pressed bound's sentence: what it may mean
SUSPECT = "suspect an effect the model lacks and compensates for here (softsbi check, softsbi diagnose)"


def test_a_bound_the_posterior_presses_is_named_in_its_units_with_the_wider_prior_to_try():
    """A bound that is not a physical limit: the wider prior (``suggested_bounds``, half the log range outward for
    a log-scaled stretch: 1000 -> 3.162e+04 N/m); a physical limit (None): no --bounds; an entry stored before the
    suggestion was: the flag with placeholders."""
    wider = {"param": "stretch", "side": "upper", "bound": 1000.0, "unit": "N/m", "mass": 0.8,
             "suggested_bounds": [1.0, 10 ** 4.5]}
    assert bound_sentence(wider) == (
        "stretch's posterior presses against its upper prior bound 1000 N/m (80% of its mass within 5% of the "
        "range from it): the data would put it beyond; widen the prior (--bounds stretch=1:3.162e+04) if such values "
        f"are physical, or {SUSPECT}")
    limit = {"param": "friction", "side": "lower", "bound": 0.0, "unit": "1", "mass": 0.3, "suggested_bounds": None}
    assert bound_sentence(limit) == (
        "friction's posterior presses against its lower prior bound 0 (30% of its mass within 5% of the range from "
        "it): the data would put it beyond; the bound is the parameter's physical limit, so no wider prior can help: "
        f"{SUSPECT}")
    older = {"param": "a", "side": "upper", "bound": 0.05, "unit": "1", "mass": 0.42}
    said = ("a's posterior presses against its upper prior bound 0.05 (42% of its mass within 5% of the range from "
            f"it): the data would put it beyond; widen the prior (--bounds a=LOW:HIGHER) if such values are physical, "
            f"or {SUSPECT}")
    assert bound_sentence(older) == said
    assert bound_sentence(dict(older, side="lower")) == said.replace("upper", "lower").replace("LOW:HIGHER",
                                                                                              "LOWER:HIGH")
    # in the fit's report: one note per pressed bound, after how to read the table; none when none is pressed
    assert fit_report_lines(_report(posterior_at_bounds=[older]), RUN) == [HOW_TO_READ, f"Note: {said}.", WRITTEN]
    assert fit_report_lines(_report(posterior_at_bounds=[]), RUN) == [HOW_TO_READ, WRITTEN]


def test_a_widened_prior_is_a_note_before_the_best_fit():
    """``--widen`` moved a's upper bound after round 1 (36% of its posterior mass pressed it): the note says which
    bound moved, from what to what, and why; then the best fit."""
    w = {"after_round": 0, "before": {"a": [-1.0, 1.0]}, "bounds": {"a": [-1.0, 2.0]},
         "pressed": [{"param": "a", "side": "upper", "bound": 1.0, "unit": "1", "mass": 0.36}]}
    widened = ("prior widened after round 1: a [-1, 1] -> [-1, 2] (upper bound) (a's posterior presses against its "
               "upper prior bound 1 (36% of its mass within 5% of the range from it))")
    assert widening_sentence(w) == widened
    both = {"after_round": 2, "before": {"a": [-1.0, 1.0]}, "bounds": {"a": [-2.0, 2.0]}, "pressed": []}
    assert widening_sentence(both) == "prior widened after round 3: a [-1, 1] -> [-2, 2] (lower and upper bound)"
    rep = _report(widened=[w], best_fit={"theta": {"bend": 2.5e-4, "mass": 0.06}, "chamfer_m": 0.0123,
                                         "source": "round 1", "simulations_searched": 60})
    assert fit_report_lines(rep, RUN, [widening_sentence(w)]) == [
        HOW_TO_READ, f"Note: {widened}.",
        "Best fit: bend=0.00025 N*m, mass=0.06 kg; Chamfer 1.23 cm (round 1; the lowest of 60 simulations; its "
        "rollout in clouds.png and softsbi view)",
        WRITTEN]


def _ranks(u, L=1000):
    """SBC ranks ``0..L`` whose normalised values are ``u``."""
    return np.floor(np.asarray(u) * (L + 1)).clip(0, L).astype(int)


def test_the_calibration_verdict_names_what_rejects():
    """calibrate's ``verdict:`` line (softsbi.inference.calibration.verdict) from hand-built ranks and coverage:
    the parameters whose SBC ranks reject, by shape; TARP; the joint coverage with the levels outside its band."""
    from softsbi.inference import calibration as cal
    rng = np.random.default_rng(0)
    N, L = 300, 1000
    ranks = np.stack([_ranks(rng.random(N)), _ranks(rng.beta(0.6, 0.6, N)), _ranks(rng.beta(2.5, 2.5, N)),
                      _ranks(rng.beta(0.8, 1.6, N)), _ranks(1 - rng.beta(0.8, 1.6, N))], 1)
    cov = cal.expected_coverage(np.linspace(0, 1, N, endpoint=False) + 0.5 / N)  # exactly calibrated
    v = cal.verdict(cov, N, {"ks_pvalue": 0.5, "atc": 0.0}, ranks, L, 10, ["uniform", "yaw", "friction", "stretch",
                                                                             "mass"])
    assert v["verdict"] == "not calibrated: yaw too narrow; friction too wide; stretch biased high; mass biased low"
    uni = _ranks(rng.random((N, 2)))
    assert cal.verdict(cov, N, {"ks_pvalue": 0.5, "atc": 0.0}, uni, L, 10, ["a", "b"])["verdict"] == "calibrated"
    tarp = cal.verdict(cov, N, {"ks_pvalue": 1e-6, "atc": -0.09}, uni, L, 10, ["a", "b"])
    assert tarp["verdict"] == "not calibrated: TARP rejects (over-confident, KS p=1e-06)"
    low = np.clip(cov - 0.12 * np.sin(np.pi * cal.LEVELS), 0, 1)  # below the diagonal: over-confident
    joint = cal.verdict(low, N, {"ks_pvalue": 0.5, "atc": 0.0}, uni, L, 10, ["a", "b"])
    assert joint["verdict"] == ("not calibrated: joint coverage over-confident (HPD coverage outside its band at 25%, "
                                "30%, 35%, 40%, 45%, 50%, 55%, 60%, 65%, 70%)")


def test_calibrate_names_the_training_report_of_the_stored_task_that_served_round_1(monkeypatch):
    """A run whose first round was a stored task's posterior: calibrate's line gives the task's training report
    (hand-built: 30 held-out prior simulations, coverage 0.48 and 0.87); a round trained here: no line."""
    from types import SimpleNamespace

    import softsbi.workflows.tasks.calibrate as calibrate
    digest = "0123456789abcdef" * 4
    report = SimpleNamespace(n_test=30, coverage=SimpleNamespace(at_50=0.48, at_90=0.87), verdict="calibrated")
    tasks = {digest: SimpleNamespace(digest=digest, report=report)}
    monkeypatch.setattr(calibrate, "task_store_of", lambda sim_bank: SimpleNamespace(get=tasks.get))
    served = {"trained_here": False, "task": digest}
    assert calibrate.trained_task_line(served, "default") == (
        "round 1's posterior is stored task 0123456789ab's, measured when it was trained on 30 held-out prior "
        "simulations: coverage 0.48 at 50%, 0.87 at 90%; calibrated (`softsbi task show 0123456789ab`)")
    assert calibrate.trained_task_line({"trained_here": True}, "default") is None
    tasks[digest] = SimpleNamespace(digest=digest, report=None)  # stored by a fit: no training report
    assert calibrate.trained_task_line(served, "default") is None


def _calibration(inside=True, rejects=False):
    return CalibrationResult.from_json(_calibration_json(inside, rejects))


def _calibration_json(inside, rejects):
    levels = [0.0] + [0.1 * k for k in range(1, 10)] + [1.0]
    return {"run": "runs/x", "n_train": 800, "parameters": ["bend", "mass"],
            "sbc": {"n_bins": 10, "histograms": [[20] * 10, [20] * 10], "band": [10.0, 30.0], "ks_pvalue": [0.5, 0.5]},
            "tarp": {"levels": levels, "coverage": levels},
            "estimator": "rkhs", "n_test": 200, "verdict_50": "calibrated", "verdict_90": "overconfident",
            "verdict": "overconfident",
            "coverage": {"hpd": [0.0] * 11, "band_lo": [0.0] * 11, "band_hi": [1.0] * 11,
                         "band_simultaneous_confidence": 0.95, "at_50": 0.48, "band_50": [0.41, 0.59],
                         "at_90": 0.81, "band_90": [0.85, 0.95], "levels": [0.0] + [0.1 * k for k in range(1, 10)]
                         + [1.0], "inside_simultaneous": inside, "outside_pointwise": [] if inside else [0.9]},
            "diagnostics": {"coverage": {"direction": "overconfident"},
                            "tarp": {"ks_pvalue": 0.2, "level": 0.0167, "atc": -0.012, "rejects": rejects,
                                     "direction": "overconfident"},
                            "sbc": {"level": 0.0042, "parameters": [
                                {"name": "bend", "rejects": rejects, "shapes": ["too-narrow"] if rejects else []},
                                {"name": "mass", "rejects": False, "shapes": []}]}}}


def test_the_calibration_table_has_the_50_and_90_percent_levels():
    t = calibration_table(_calibration())
    assert t.title == "Calibration of 'rkhs' on 200 fresh test simulations"
    assert t.columns[2] == "calibrated range (95.0%, whole curve)"
    assert t.rows == (("50%", "0.48", "[0.41, 0.59]", "calibrated"), ("90%", "0.81", "[0.85, 0.95]", "overconfident"))


def test_the_calibration_lines_name_what_each_diagnostic_rejects():
    ok = calibration_lines(_calibration())
    assert ok == ["joint coverage (HPD): inside the simultaneous 95.0% band over 9 levels; inside the pointwise 95% "
                  "band at every level",
                  "TARP: KS p=0.2 (rejects below 0.0167), ATC -0.012: consistent with calibrated",
                  "SBC per parameter (KS, mean, spread and histogram band, each at 0.0042: Bonferroni over 2 "
                  "parameters): every rank histogram uniform"]
    bad = calibration_lines(_calibration(inside=False, rejects=True))
    assert bad[0].startswith("joint coverage (HPD): OUTSIDE the simultaneous 95.0% band over 9 levels "
                             "(overconfident); outside the pointwise 95% band at 90%")
    assert bad[1].endswith("rejects (overconfident)")
    assert bad[2].endswith("bend too narrow (U-shaped ranks: the truth often lies in the posterior's tails); "
                           "uniform: mass")
