"""The typed report.json (FitReport) and calibration.json (CalibrationResult): read, written back unchanged, older
files tolerated, damaged ones refused in one line. Hand-built objects in the shape the fit and calibrate write."""
from __future__ import annotations

import copy

import pytest

from softsbi.core.results.fitreport import (BestFitRow, BoundPressure, CalibrationResult, Contraction, FitReport,
                                            ParameterRow, RoundRow)
from softsbi.core.results import ResultDamaged

#: a toy fit's report.json as the fit writes it (per-frame lists shortened)
REPORT = {
    "observed": "simulated:toy-gauss", "backend": "toy-gauss", "estimator": "mdnn", "effects": [],
    "parameters": [{"name": "a", "low": -1.0, "high": 1.0, "unit": "1", "log": False, "description": "toy a"},
                   {"name": "b", "low": 1e-3, "high": 1.0, "unit": "m", "log": True, "description": "toy b",
                    "limits": [0.0, None]}],
    "fixed": {"c": 0.5}, "rounds": 2, "sims_per_round": 60, "simulations": 125, "proposal": "truncated",
    "min_height_m": None, "frames": None, "failed_simulations": 0, "bank_hits": 3,
    "chamfer_prior_m": 0.136, "chamfer_prior_std_m": 0.037, "chamfer_posterior_m": 0.122,
    "chamfer_posterior_std_m": 0.025, "chamfer_posterior_n": 5, "metric_min_z_m": None, "metric_frames": [1, 2],
    "metric_sensor": "height", "chamfer_posterior_one_sided_m": 0.1223, "chamfer_posterior_one_sided_std_m": 0.0254,
    "chamfer_prior_per_frame_m": [0.137, 0.120], "chamfer_posterior_per_frame_m": [0.130, 0.110],
    "chamfer_posterior_one_sided_per_frame_m": [0.1309, 0.1101],
    "posterior_mean": {"a": 0.218, "b": 0.03}, "posterior_std": {"a": 0.43, "b": 0.04},
    "posterior_q05": {"a": -0.57, "b": 0.002}, "posterior_q95": {"a": 0.87, "b": 0.9},
    "posterior_median": {"a": 0.249, "b": 0.03},
    "contraction": {"a": {"scale": "linear", "center": 0.218, "spread": 0.43, "q05": -0.57, "q95": 0.87,
                          "width_ratio": 0.8, "informed": False},
                    "b": {"scale": "log", "center": 0.04, "spread": None, "q05": 0.002, "q95": 0.9,
                          "width_ratio": 0.98, "informed": False}},
    "informed_max_width_ratio": 0.5,
    "posterior_at_bounds": [{"param": "b", "side": "upper", "bound": 1.0, "unit": "m", "mass": 0.2,
                             "suggested_bounds": [0.001, 3.0]}],
    "truth": {"a": 0.3, "b": 0.4},
    "per_round": [{"round": 0, "usable": 60, "failed": 0, "bank_hits": 3, "chamfer_posterior_m": None,
                   "chamfer_posterior_std_m": None, "mass_in_box": 0.87, "train_seconds": 5.7,
                   "posterior_mean": {"a": 0.22, "b": 0.09}},
                  {"round": 1, "usable": 60, "failed": 0, "bank_hits": 0, "chamfer_posterior_m": 0.122,
                   "chamfer_posterior_std_m": 0.025, "mass_in_box": 0.87, "train_seconds": 0.85,
                   "posterior_mean": {"a": 0.23, "b": 0.01}}],
    "wall_time_s": 27.3, "metric": "chamfer_m", "chamfer_reduction": 0.104,
    "truth_in_90pct_interval": {"a": True, "b": True},
    "best_fit": {"theta": {"a": 0.46, "b": 0.77}, "chamfer_m": 0.064, "chamfer_per_frame_m": [0.059, 0.072],
                 "source": "round 1", "simulation": 4, "seed": 2080083688, "simulations_searched": 125,
                 "rollout": "run.zarr/best_fit", "refine": None},
    "widened": [{"after_round": 0, "param": "b"}],
}


def test_a_report_reads_into_typed_fields_and_writes_back_the_same_object():
    r = FitReport.from_json(REPORT)
    assert r.parameters[1] == ParameterRow(name="b", low=1e-3, high=1.0, unit="m", log=True, description="toy b",
                                           limits=(0.0, None))
    assert r.names == ["a", "b"] and r.effects == () and r.metric_frames == (1, 2)
    assert r.chamfer_posterior_m == 0.122 and r.per_round[1] == RoundRow(
        round=1,
        usable=60,
        failed=0,
        bank_hits=0,
        chamfer_posterior_m=0.122,
        chamfer_posterior_std_m=0.025,
        mask_chamfer_posterior_px=None,
        mask_chamfer_posterior_std_px=None,
        mass_in_box=0.87,
        train_seconds=0.85,
        posterior_mean={"a": 0.23, "b": 0.01},
    )
    assert r.contraction["b"] == Contraction(scale="log", center=0.04, spread=None, q05=0.002, q95=0.9,
                                             width_ratio=0.98, informed=False)
    assert r.posterior_at_bounds == (BoundPressure(param="b", side="upper", bound=1.0, unit="m", mass=0.2,
                                                   suggested_bounds=(0.001, 3.0)),)
    assert r.best_fit == BestFitRow(theta={"a": 0.46, "b": 0.77}, value=0.064, per_frame=(0.059, 0.072),
                                    source="round 1", simulation=4, seed=2080083688, simulations_searched=125,
                                    rollout="run.zarr/best_fit", refine=None)
    assert r.interval("a") == (-0.57, 0.87) and r.interval("z") == (None, None)
    assert r.width_ratio("b") == 0.98 and r.width_ratio("z") is None
    assert r.to_json() == REPORT and r.extra == {}
    with pytest.raises(dataclasses_frozen()):
        r.chamfer_posterior_m = 0.0  # type: ignore[misc]


def dataclasses_frozen() -> type:
    import dataclasses
    return dataclasses.FrozenInstanceError


def test_an_image_fits_report_keeps_its_pixel_keys():
    rep = copy.deepcopy(REPORT)
    rep["metric"] = "mask_chamfer_px"
    for k in ("prior", "prior_std", "posterior", "posterior_std"):
        rep[f"mask_chamfer_{k}_px"] = rep.pop(f"chamfer_{k}_m")
        rep[f"chamfer_{k}_m"] = None
    for row in rep["per_round"]:
        row["mask_chamfer_posterior_px"] = row.pop("chamfer_posterior_m")
        row["mask_chamfer_posterior_std_px"] = row.pop("chamfer_posterior_std_m")
    rep["best_fit"]["mask_chamfer_px"] = rep["best_fit"].pop("chamfer_m")
    rep["best_fit"]["mask_chamfer_per_frame_px"] = rep["best_fit"].pop("chamfer_per_frame_m")
    r = FitReport.from_json(rep)
    assert r.chamfer_posterior_m is None and r.mask_chamfer_posterior_px == 0.122
    assert r.per_round[1].mask_chamfer_posterior_px == 0.122 and r.best_fit.value == 0.064
    assert r.to_json() == rep


def test_an_older_report_reads_with_its_missing_keys_as_none_and_keeps_unknown_ones():
    old = {k: REPORT[k] for k in ("parameters", "posterior_median", "posterior_mean", "chamfer_posterior_m")}
    old["per_round"] = [{"round": 0, "usable": 60, "failed": 0}]
    old["a_key_from_elsewhere"] = {"x": 1}
    r = FitReport.from_json(old)
    assert r.contraction == {} and r.posterior_at_bounds == () and r.best_fit is None and r.widened == ()
    assert r.chamfer_prior_m is None and r.chamfer_reduction is None and r.metric == "chamfer_m"
    assert r.per_round[0].bank_hits == 0 and r.per_round[0].chamfer_posterior_m is None
    assert r.extra == {"a_key_from_elsewhere": {"x": 1}}
    back = r.to_json()
    assert back["a_key_from_elsewhere"] == {"x": 1} and back["chamfer_prior_m"] is None
    assert "chamfer_reduction" not in back and "mask_chamfer_posterior_px" not in back
    assert FitReport.from_json(back) == r


def test_a_report_gives_a_parameters_slab_mass_and_the_bound_it_presses_or_none():
    """FitReport.slab_mass and .bound_pressure: one parameter's entries of ``contraction`` and
    ``posterior_at_bounds``; None for a parameter without them and for an older report that lacks them."""
    rep = copy.deepcopy(REPORT)
    rep["contraction"]["a"]["slab_mass"] = [0.01, 0.3]
    r = FitReport.from_json(rep)
    assert r.slab_mass("a") == (0.01, 0.3) and r.slab_mass("b") is None and r.slab_mass("c") is None
    assert r.bound_pressure("b") == r.posterior_at_bounds[0] and r.bound_pressure("b").side == "upper"
    assert r.bound_pressure("a") is None
    old = FitReport.from_json({k: REPORT[k] for k in ("parameters", "posterior_median")})
    assert old.slab_mass("a") is None and old.bound_pressure("b") is None


@pytest.mark.parametrize("damage, problem", [
    (lambda d: d.pop("posterior_median"), "it lacks 'posterior_median'"),
    (lambda d: d.update(parameters=[{"name": "a"}]), "not a fit report"),
    (lambda d: d.update(per_round=[7]), "not a fit report"),
])
def test_a_report_without_its_required_keys_is_damaged_in_one_line(tmp_path, damage, problem):
    rep = copy.deepcopy(REPORT)
    damage(rep)
    path = tmp_path / "run" / "report.json"
    with pytest.raises(ResultDamaged) as err:
        FitReport.from_json(rep, path)
    assert err.value.path == path and problem in err.value.problem and "\n" not in str(err.value)
    assert f"`softsbi fit ... --out {path.parent}`" in str(err.value)


#: calibration.json as calibrate writes it (three levels, two parameters)
CALIBRATION = {
    "run": "runs/tan", "estimator": "mdnn", "estimator_options": {"ensemble": 2}, "n_test": 50, "n_test_failed": 0,
    "n_no_mass_in_box": 0, "n_train": 120, "n_draws": 300, "rounds": 2, "test_proposal": "prior (60)",
    "coordinates": "unit cube", "parameters": ["a", "b"],
    "coverage": {"levels": [0.0, 0.5, 1.0], "hpd": [0.0, 0.48, 1.0], "band_lo": [0.0, 0.36, 1.0],
                 "band_hi": [0.0, 0.64, 1.0], "band_confidence": 0.95, "at_50": 0.48, "at_90": 0.9,
                 "band_simultaneous_lo": [0.0, 0.3, 1.0], "band_simultaneous_hi": [0.0, 0.7, 1.0],
                 "band_simultaneous_confidence": 0.983, "outside_pointwise": [], "inside_simultaneous": True,
                 "band_50": [0.3, 0.7], "band_90": [0.8, 0.97]},
    "verdict_50": "calibrated", "verdict_90": "calibrated", "verdict": "calibrated", "calibrated": True,
    "alpha": 0.05, "too_narrow": [], "too_wide": ["b"], "biased": [],
    "diagnostics": {"coverage": {"rejects": False, "direction": None, "outside": [], "confidence": 0.983},
                    "tarp": {"rejects": False, "level": 0.0167}, "sbc": {"level": 0.008, "parameters": []}},
    "sbc": {"n_bins": 2, "histograms": [[24, 26], [20, 30]], "band": [15.0, 35.0], "band_level": 0.008,
            "shapes": [[], ["too-wide"]], "rejects": [False, True], "ks_pvalue": [0.5, 0.01],
            "chi2_pvalue": [0.8, 0.2]},
    "tarp": {"levels": [0.0, 0.5, 1.0], "coverage": [0.0, 0.5, 1.0], "atc": 0.0, "ks_pvalue": 0.7},
    "train_seconds": 1.5, "simulation_seconds": 2.5, "estimator_fit": {"epochs": 30},
    "refit_max_mean_difference": None,
}


def test_a_calibration_reads_into_typed_fields_and_writes_back_the_same_object():
    c = CalibrationResult.from_json(CALIBRATION)
    assert c.coverage.at_90 == 0.9 and c.coverage.band_90 == (0.8, 0.97) and c.sbc.shapes == ((), ("too-wide",))
    assert c.tarp.ks_pvalue == 0.7 and c.too_wide == ("b",) and c.is_calibrated
    assert c.to_json() == CALIBRATION and list(c.to_json()) == list(CALIBRATION)


def test_an_older_calibration_reads_and_a_broken_one_is_damaged(tmp_path):
    old = copy.deepcopy(CALIBRATION)
    for k in ("band_simultaneous_lo", "band_simultaneous_hi", "band_simultaneous_confidence", "band_50", "band_90",
              "inside_simultaneous", "outside_pointwise"):
        old["coverage"].pop(k)
    for k in ("band_level", "shapes", "rejects"):
        old["sbc"].pop(k)
    old["sbc"]["band_confidence"] = 0.99
    for k in ("calibrated", "verdict_50", "verdict_90", "too_narrow", "too_wide", "biased", "diagnostics"):
        old.pop(k)
    c = CalibrationResult.from_json(old)
    assert c.coverage.band_simultaneous_lo is None and c.sbc.shapes == () and c.sbc.band_confidence == 0.99
    assert c.calibrated is None and c.is_calibrated and c.too_wide == ()
    bad = dict(CALIBRATION, coverage=None)
    with pytest.raises(ResultDamaged, match="not a calibration") as err:
        CalibrationResult.from_json(bad, tmp_path / "calibration.json")
    assert "`softsbi calibrate" in str(err.value)
