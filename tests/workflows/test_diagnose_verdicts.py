"""diagnose's verdicts on MuJoCo lift measurements (slow: each fits the nominal model)."""
import pytest

from softsbi.effects.builtin import ExtraDamping, Wind
from softsbi.scenarios.builtin import lift_scenario
from softsbi.workflows.check import check_run
from softsbi.workflows.diagnose import diagnose_run
from softsbi.workflows.fit import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording
from softsbi.plugins import registry

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
    """A hidden wind; wind and extra damping marked as generic force terms (as the generic
    library's constant / drag effects will be): no named effect is left, so the verdict is
    misspecified-unexplained, with the residual's shape and the best generic term; check agrees."""
    run = _hidden_wind_fit(tmp_path)
    monkeypatch.setattr(Wind, "generic", True, raising=False)
    monkeypatch.setattr(ExtraDamping, "generic", True, raising=False)
    d = diagnose_run(run, effects=["wind", "extra-damping"], workers=1, confirm=0)
    chk = check_run(run, workers=1, plot=False)["misspecification"]
    assert chk["misspecified"] and d["misspecification"]["p_value"] == chk["p_value"]
    assert d["verdict"] == "misspecified-unexplained" and d["significant"] == []
    assert d["generic"] == "wind" and d["ranking"][0]["effect"] == "wind"
    assert d["ranking"][0]["explained_fraction"] > 0.3
    assert "Best generic force term: wind explains" in d["summary"]
    res = d["residual"]
    assert res["frames_flagged"] and len(res["worst_regions"]) == 2
    # the wind blows along +y: the measured cloth is displaced that way
    assert res["direction"] == "+y" and res["centroid_offset_cm"][1] > 0
    # without the flag the same screening names the wind as a missing physics effect
    monkeypatch.setattr(Wind, "generic", False)
    d2 = diagnose_run(run, effects=["wind", "extra-damping"], workers=1, confirm=0)
    assert d2["verdict"] == "missing-effect" and d2["selected"] == "wind"
    assert d2["summary"].startswith("Missing physics effect: wind")
