""""Switched on", calibrated (softsbi.workflows.criticism.switched_on): the statistic, its Monte-Carlo test against
a stored null, the decision it takes for a refit, and the words that report it, on fixed numbers."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from softsbi.core.results.fitreport import Contraction
from softsbi.core.results import Estimate, MCPValue, OffTest
from softsbi.core.types import Param, ParamSpace
from softsbi.workflows.criticism.decide import decide
from softsbi.workflows.criticism.statistics import off_distance
from softsbi.workflows.criticism.switched_on import (OFF_NULL_FILE, draws_off_distance, off_test, store_off_null,
                                                     stored_off_null, unit_off_values)
from result_helpers import joint, refit, score


class Breeze:
    """An effect with one parameter off at 0 inside its prior and one off at its lower bound."""
    name = "breeze"

    def param_space(self):
        return ParamSpace([Param("gust", -2.0, 2.0), Param("drag", 0.0, 1.0)])

    def nominal(self):
        return {"gust": 0.0, "drag": 0.0}


SPACE = ParamSpace([Param("bend", 1e-4, 1e-2, log=True), Param("gust", -2.0, 2.0), Param("drag", 0.0, 1.0)])


def test_the_statistic_is_the_largest_distance_from_off_in_posterior_sds_leaving_out_parameters_without_one():
    assert off_distance([0.5, 0.7, 0.2], [0.1, 0.1, 0.05], [np.nan, 0.5, 0.0]) == pytest.approx(4.0)
    assert np.isnan(off_distance([0.5], [0.1], [np.nan]))
    # a posterior that is a point is as far as its mean over a tiny floor, not a division by zero
    assert off_distance([0.6], [0.0], [0.5]) > 1e4
    rng = np.random.default_rng(0)
    draws = np.column_stack([rng.random(4000), 0.5 + 0.1 * rng.standard_normal(4000)])
    assert draws_off_distance(draws, np.array([np.nan, 0.3])) == pytest.approx(2.0, rel=0.05)


def test_off_values_in_unit_coordinates_of_the_fits_space_at_bounds_and_inside():
    off = unit_off_values(Breeze(), SPACE)
    assert np.isnan(off[0]) and off[1] == pytest.approx(0.5) and off[2] == 0.0
    widened = ParamSpace([Param("gust", -1.0, 3.0), Param("drag", 0.0, 1.0)])  # bounds the user changed
    assert unit_off_values(Breeze(), widened)[0] == pytest.approx(0.25)


def contraction(gust=(0.5, 0.2), drag=(0.5, 0.29)):
    return {"bend": Contraction(unit_mean=0.4, unit_std=0.01),
            "gust": Contraction(unit_mean=gust[0], unit_std=gust[1]),
            "drag": Contraction(unit_mean=drag[0], unit_std=drag[1])}


def test_the_test_is_a_monte_carlo_p_value_against_the_null_and_on_at_most_its_level():
    null = np.linspace(0.5, 2.5, 199)  # 199 posteriors of simulations without the effect
    flat = off_test(contraction(), Breeze(), SPACE, null)  # a posterior the data left at the prior: 1.72 sd from 0
    assert flat.statistic == pytest.approx(0.5 / 0.29)
    assert flat.p_value.n == 199 and not flat.on and flat.p_value.value > 0.1
    far = off_test(contraction(drag=(0.7, 0.2)), Breeze(), SPACE, null)  # wide (sd 0.2 of the range) yet 3.5 sd
    assert far.on and far.p_value == MCPValue(exceed=0, n=199) and far.p_value.value == pytest.approx(1 / 200)
    # an older report without the unit moments: no test (the estimates' rule decides)
    assert off_test({"gust": Contraction(), "drag": Contraction()}, Breeze(), SPACE, null) is None


def test_a_stored_null_round_trips_and_a_damaged_one_is_named_and_not_used(tmp_path):
    store_off_null(tmp_path, np.array([1.0, np.nan, 2.0]), n_draws=50)
    assert stored_off_null(tmp_path).tolist() == [1.0, 2.0]  # a posterior without mass in the box left out
    assert stored_off_null(tmp_path / "none") is None
    (tmp_path / OFF_NULL_FILE).write_text("{bad")
    said = []
    assert stored_off_null(tmp_path, said.append) is None
    assert len(said) == 1 and OFF_NULL_FILE in said[0] and "estimates' rule" in said[0]


WIDE = (Estimate(name="drag", unit="N", mean=0.4, q05=0.05, q95=0.8, width_ratio=0.8, effect="breeze",
                 may_be_off=True, off_ratio=0.6),)


def test_the_calibrated_test_overrides_the_estimates_rule_both_ways():
    """A refit whose estimates' rule says "possibly off" (a Savage-Dickey ratio of 0.6 at the bound) is switched on
    when its calibrated test rejects "off", and one whose test does not reject stays set aside."""
    base = refit(("breeze",), 8, joint(60, 70), estimates=WIDE)
    on = replace(base, off_test=OffTest(statistic=3.5, p_value=MCPValue(exceed=3, n=199), level=0.1))
    off = replace(base, off_test=OffTest(statistic=1.7, p_value=MCPValue(exceed=120, n=199), level=0.1))
    assert base.maybe_off == ("breeze",) and on.maybe_off == () and off.maybe_off == ("breeze",)
    rejects = joint(0, 0)
    assert decide(rejects, score(20), [on]).named == ("breeze",)
    assert decide(rejects, score(20), [off]).verdict == "misspecified-unexplained"


def test_the_words_give_the_test_that_decided_and_never_the_ratios_own_verdict():
    from softsbi.report.text import estimate_words, refit_words
    t = OffTest(statistic=3.46, p_value=MCPValue(exceed=3, n=199), level=0.1)
    r = refit(("breeze",), 8, joint(60, 70), estimates=WIDE, off_test=t)
    s = refit_words(r, score(20))
    assert ("Is its effect off? Its posterior lies 3.5 posterior standard deviations from the off value, farther "
            "than on 196 of 199 of its model's posteriors of simulations without the effect (p = 0.02: switched on "
            "at p <= 0.1).") in s
    assert "possibly off" not in s and "the data show the effect is on" in s
    # without a test, the ratio's own verdict
    assert "possibly off: on at most 0.1" in estimate_words(WIDE[0])


def test_the_rule_as_applied_names_the_calibrated_test_only_for_the_refits_it_decided():
    from softsbi.report.text import SWITCHED_ON_RULE, SWITCHED_ON_TEST, switched_on_rules
    t = OffTest(statistic=3.46, p_value=MCPValue(exceed=3, n=199), level=0.1)
    tested = refit(("breeze",), 8, joint(60, 70), estimates=WIDE, off_test=t)
    sequential = refit(("wind",), 9, joint(60, 70))
    assert switched_on_rules([sequential]) == SWITCHED_ON_RULE
    assert switched_on_rules([tested]) == SWITCHED_ON_TEST
    both = switched_on_rules([tested, sequential])
    assert both.startswith(f"for breeze, {SWITCHED_ON_TEST}; for the others, a parameter's 90% interval")
