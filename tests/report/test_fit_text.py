"""The fit's and calibrate's tables and sentences (softsbi/report/fit_text.py), rendered from hand-built results."""
from pathlib import Path

from softsbi.core.fitreport import CalibrationResult
from softsbi.report.fit_text import (TextTable, best_fit_lines, calibration_lines, calibration_table,
                                     fit_report_lines, posterior_table)

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
