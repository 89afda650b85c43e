"""A posterior that presses against a prior bound (softsbi.inference.contraction.bound_pressure): the fit's
report, its printed table, check's summary and a diagnosis refit's sentence say so, with the fix."""
import json

import numpy as np
import pytest

import softsbi
from softsbi.core.types import Param, ParamSpace
from softsbi.inference.contraction import BOUND_MASS_MIN, BOUND_SLAB, bound_pressure, bound_sentence, widened_bounds
from softsbi.core.defaults import CheckSettings

pytestmark = pytest.mark.integration

pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
from toy_helpers import toy_measurement  # noqa: E402

SPACE = ParamSpace([Param("stretch", 1.0, 1000.0, "N/m", log=True), Param("friction", 0.0, 1.5)])


def test_a_flat_or_interior_posterior_presses_no_bound():
    rng = np.random.default_rng(0)
    flat = SPACE.from_unit(rng.random((4000, 2)))  # the prior itself: BOUND_SLAB of the mass in each slab
    assert bound_pressure(SPACE, flat) == []
    interior = SPACE.from_unit(np.clip(rng.normal(0.5, 0.1, (4000, 2)), 0, 1))
    assert bound_pressure(SPACE, interior) == []


def test_a_pile_up_at_a_bound_is_named_in_the_parameters_own_scale():
    rng = np.random.default_rng(1)
    u = np.column_stack([1 - np.abs(rng.normal(0, 0.04, 4000)),  # stretch piled at its upper bound (log scale)
                         rng.uniform(0.3, 0.7, 4000)])
    u[:, 0] = np.clip(u[:, 0], 0, 1)
    (e,) = bound_pressure(SPACE, SPACE.from_unit(u))
    assert e["param"] == "stretch" and e["side"] == "upper" and e["bound"] == 1000.0 and e["unit"] == "N/m"
    assert e["mass"] > 0.7
    # the slab is measured in the log scale: 5% of the log range below 1000 N/m is above 708 N/m, not above 950
    theta = np.column_stack([np.full(100, 800.0), np.full(100, 0.75)])
    assert bound_pressure(SPACE, theta)[0]["mass"] == 1.0
    # the fix, with numbers: the upper bound moved half the (log) range outward, 10^3 -> 10^4.5 N/m (the sentence
    # that names it: tests/report/test_fit_text.py)
    assert e["suggested_bounds"] == [1.0, pytest.approx(10 ** 4.5)]
    # the lower bound, and the threshold
    lo = SPACE.from_unit(
        np.column_stack([rng.uniform(0.3, 0.7, 1000), np.r_[np.zeros(300), rng.uniform(0.3, 0.7, 700)]])
    )
    (e,) = bound_pressure(SPACE, lo)
    assert (e["param"], e["side"], e["bound"]) == ("friction", "lower", 0.0) and e["mass"] == pytest.approx(0.3)
    # friction 0 is a physical limit: no wider prior is suggested (the sentence says to suspect a missing effect)
    assert e["suggested_bounds"] is None
    assert bound_pressure(SPACE, lo, min_mass=0.31) == []
    assert BOUND_MASS_MIN > BOUND_SLAB


def test_bad_input_raises():
    with pytest.raises(ValueError, match=r"shape \(S, 2\)"):
        bound_pressure(SPACE, np.ones((10, 3)))
    with pytest.raises(ValueError, match="slab and min_mass"):
        bound_pressure(SPACE, np.ones((10, 2)), slab=0.0)


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bounds") / "run"
    res = softsbi.fit(toy_measurement(), out, backend="toy-gauss", estimator="mdnn", rounds=2, sims_per_round=60,
                      n_points=8, n_eval=5, n_dense=32, workers=1, seed=3, plots=False,
                      bounds={"a": (-1.0, 0.05)}, estimator_options={"max_epochs": 30, "hidden": [16]})
    return out, res


def test_the_fit_report_holds_the_bound_pressure_of_its_own_posterior(toy_run):
    """report.json's entry is bound_pressure of the fit's posterior (the same 4000 draws as its summaries)."""
    from softsbi.workflows.fit.runs import open_run
    out, res = toy_run
    rep = json.loads((out / "report.json").read_text())
    post = open_run(out).posterior
    draws = post.space.from_unit(post.unit.sample(4000, np.random.default_rng([3, 99])))
    np.testing.assert_allclose(draws.mean(0), [rep["posterior_mean"][n] for n in post.names])  # the report's draws
    assert rep["posterior_at_bounds"] == bound_pressure(post.space, draws)
    # and with the threshold lowered to what this wide posterior puts next to a's upper bound 0.05, it is named
    mass = float((post.space.to_unit(draws)[:, 0] >= 1 - BOUND_SLAB).mean())
    assert mass > 0
    (e,) = [b for b in bound_pressure(post.space, draws, min_mass=mass) if b["param"] == "a" and b["side"] == "upper"]
    assert e["bound"] == pytest.approx(0.05) and e["mass"] == pytest.approx(mass)


def test_the_printed_report_and_a_refit_sentence_say_so(toy_run, capsys):
    """The fit prints one line per pressed bound of its report, the bound's sentence (bound_sentence); a diagnosis
    refit whose added parameter presses a bound that is not a physical limit adds one sentence (the wider prior).
    Their wording: tests/report/test_fit_text.py and tests/report/test_text.py."""
    from dataclasses import replace

    from result_helpers import joint, refit, score
    from toy_helpers import printed_fit_report
    from softsbi.core.results import Estimate
    from softsbi.report.text import refit_words
    out, res = toy_run
    pressed = {"param": "a", "side": "upper", "bound": 0.05, "unit": "1", "mass": 0.42}
    _, lines = printed_fit_report(dict(res.report.to_json(), posterior_at_bounds=[pressed]), out, capsys)
    _, plain = printed_fit_report(dict(res.report.to_json(), posterior_at_bounds=[]), out, capsys)
    noted = [line for line in lines if line not in plain]
    assert len(lines) == len(plain) + 1 and len(noted) == 1 and bound_sentence(pressed) in noted[0]
    # a diagnosis refit whose added parameter presses its prior bound names the wider prior to try
    est = Estimate(name="wind", unit="m", mean=0.49, q05=0.41, q95=0.5, width_ratio=0.2, pressed="upper",
                   suggested_bounds=(0.0, 0.75))

    def words(e):
        return refit_words(refit(("toy-wind",), 0.01, joint(50, 50), estimates=(e,)), score(0.02))
    unpressed = words(replace(est, pressed=None, suggested_bounds=None))
    assert words(est).startswith(unpressed) and len(words(est)) > len(unpressed)
    assert words(replace(est, suggested_bounds=None)) == unpressed  # a physical limit: nothing to widen


def test_check_repeats_the_fits_pressed_bounds(toy_run, tmp_path):
    import shutil

    from softsbi.workflows.criticism.check import check_run
    out, res = toy_run
    run = tmp_path / "run"
    shutil.copytree(out, run)
    # a level the 10-rollout null resolves (2/11 <= 0.5): the test is not what this checks
    plain = check_run(run, plot=False, settings=CheckSettings(n_eval=10, workers=1, alpha=0.5, max_null=10))
    rep = json.loads((run / "report.json").read_text())
    assert list(plain.posterior_at_bounds) == rep["posterior_at_bounds"]
    rep["posterior_at_bounds"] = [{"param": "b", "side": "lower", "bound": -1.0, "unit": "1", "mass": 0.35}]
    (run / "report.json").write_text(json.dumps(rep))
    pressed = check_run(run, plot=False, settings=CheckSettings(n_eval=10, workers=1, alpha=0.5, max_null=10))
    # read through the typed report: a key the file lacks (no wider prior suggested) reads as None
    assert list(pressed.posterior_at_bounds) == [{**rep["posterior_at_bounds"][0], "suggested_bounds": None}]
    assert pressed.test == plain.test  # the test is unchanged


def test_widened_bounds_move_a_pressed_bound_half_the_range_outward_but_never_past_an_edge():
    """widened_bounds: half the range in the parameter's own scale (a decade and a half for bend's three decades),
    clipped to the physical limits; an effect's switched-off value (keep) and a physical limit stay put."""
    space = ParamSpace([Param("bend", 1e-6, 1e-3, "N*m", log=True), Param("wind_x", -2.0, 2.0, "m/s"),
                        Param("noise_std", 0.0, 0.01, "m"), Param("friction", 0.2, 1.0, limits=(0.0, 1.1))])
    pressed = [{"param": "bend", "side": "lower"}, {"param": "wind_x", "side": "lower"},
               {"param": "wind_x", "side": "upper"}, {"param": "noise_std", "side": "lower"},
               {"param": "noise_std", "side": "upper"}, {"param": "friction", "side": "upper"},
               {"param": "not-inferred", "side": "upper"}]
    new = widened_bounds(space, pressed, keep={"noise_std": 0.0, "wind_x": 0.0})
    assert new["bend"] == (pytest.approx(10 ** -7.5), 1e-3)
    assert new["wind_x"] == (-4.0, 4.0)  # both sides pressed (a bimodal posterior): both move
    assert new["noise_std"] == (0.0, 0.015)  # the switched-off side (no noise) stays
    assert new["friction"] == (0.2, 1.1)  # clipped to the explicit physical limit
    assert widened_bounds(space, [{"param": "noise_std", "side": "lower"}], keep={"noise_std": 0.0}) == {}
    assert widened_bounds(space, []) == {}
    assert widened_bounds(space, [{"param": "friction", "side": "lower"}], fraction=1.0)["friction"] == (0.0, 1.0)
    with pytest.raises(ValueError, match="fraction"):
        widened_bounds(space, pressed, fraction=0.0)
