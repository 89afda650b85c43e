"""The diagnosis' decision (softsbi.workflows.criticism.decide) on hand-built typed results: no simulation."""
from __future__ import annotations

from dataclasses import replace

from softsbi.core.results import Candidate, Decision, Estimate, JointTest, MCPValue, Refit, RefitGain, Role, Score
from softsbi.core.types import Param
from softsbi.workflows.criticism.decide import K_SE, decide, gain, improves, next_refit, refit_order
from softsbi.workflows.criticism.diagnose import may_be_off, off_ratio

ALPHA = 0.05


def joint(p_exceed: int = 0, n: int = 200) -> JointTest:
    """A joint test whose omnibus and directional p-values both come from ``p_exceed`` of ``n`` nulls."""
    return JointTest(omnibus=MCPValue(exceed=p_exceed, n=n), directional=MCPValue(exceed=p_exceed, n=n),
                     directional_effect="x", family=("a", "b"), alpha=ALPHA, max_null=200)


REJECTS, ACCEPTS = joint(0), joint(150, 200)


def score(e: float, se: float = 0.01) -> Score:
    return Score(value=e, se=se, n=30)


def cand(name: str, generic: bool = False, p: int = 0) -> Candidate:
    return Candidate(effect=name, kind="physics", generic=generic, description=name, explained=0.3,
                     adjusted=MCPValue(exceed=p, n=200), estimate={})


def refit(effects: tuple[str, ...], e: float, adequate: bool = True, ranking: tuple[Candidate, ...] = ()) -> Refit:
    return Refit(effects=effects, run=f"refit-{'+'.join(effects)}", test=ACCEPTS if adequate else REJECTS,
                 score=score(e), chamfer_m=e,
                 ranking=ranking)


NOMINAL = score(1.0)


def test_the_joint_test_is_bonferroni_over_two_monte_carlo_p_values_and_never_below_its_resolution():
    t = JointTest(omnibus=MCPValue(exceed=0, n=200), directional=MCPValue(exceed=3, n=200), directional_effect="wind",
                  family=("wind",), alpha=ALPHA, max_null=200)
    assert t.deciding == "omnibus" and t.p_value == 2 / 201 and t.resolution == 2 / 201 and t.misspecified
    assert (t.tests, t.n_null) == (2, 200) and t.best == MCPValue(exceed=0, n=200) and t.best.at_floor
    one = JointTest(omnibus=MCPValue(exceed=0, n=30), directional=None, directional_effect=None, family=(), alpha=ALPHA,
                    max_null=200)
    assert one.tests == 1 and one.p_value == 1 / 31 and one.misspecified
    # 30 nulls cannot reach 0.05 with two tests: the smallest joint p is 2/31 > 0.05
    assert not JointTest(omnibus=MCPValue(exceed=0, n=30), directional=MCPValue(exceed=0, n=30), directional_effect="x",
                         family=("x",), alpha=ALPHA, max_null=30).misspecified


def test_nothing_missing_iff_the_nominal_test_does_not_reject():
    assert decide(ACCEPTS, NOMINAL, [refit(("a",), 0.2)]).verdict == "nothing-missing"
    assert decide(REJECTS, NOMINAL, []).verdict == "misspecified-unexplained"


def test_the_adequate_refit_with_the_lowest_energy_score_is_named():
    d = decide(REJECTS, NOMINAL, [refit(("a",), 0.6), refit(("b",), 0.3)])
    assert d == Decision(verdict="missing-effect", named=("b",), gain=gain(NOMINAL, score(0.3)),
                         gains=(RefitGain(effects=("a",), gain=gain(NOMINAL, score(0.6))),
                                RefitGain(effects=("b",), gain=gain(NOMINAL, score(0.3)))))
    assert d.role(("b",)) is Role.NAMED and d.role(("a",)) is Role.NOT_NAMED
    assert d.gain_of(("a",)) == gain(NOMINAL, score(0.6)) and d.gain_of(("z",)) is None


def test_an_inadequate_refit_is_never_named_however_low_its_score():
    d = decide(REJECTS, NOMINAL, [refit(("a",), 0.6), refit(("b",), 0.1, adequate=False)])
    assert d.named == ("a",)


def test_an_adequate_refit_that_does_not_lower_the_score_by_k_se_explains_nothing():
    # a refit that check accepts only because its posterior predictive is wider: the score does not fall
    flat = refit(("a",), 1.0 - K_SE * 0.01)  # k_se of one score's se, under k_se of the difference's
    assert not improves(NOMINAL, flat.score)
    d = decide(REJECTS, NOMINAL, [flat])
    assert d.verdict == "misspecified-unexplained" and d.partial == ()


def test_refits_within_k_se_of_the_best_are_indistinguishable():
    d = decide(REJECTS, NOMINAL, [refit(("a",), 0.30), refit(("b",), 0.31), refit(("c",), 0.60)])
    assert d.named == ("a",) and d.alternatives == (("b",),)
    assert d.role(("b",)) is Role.INDISTINGUISHABLE


def test_an_improving_refit_that_check_rejects_explains_a_part():
    d = decide(REJECTS, NOMINAL, [refit(("a",), 0.5, adequate=False), refit(("b",), 0.7, adequate=False)])
    assert d.verdict == "misspecified-unexplained" and d.partial == ("a",)
    assert d.role(("a",)) is Role.PARTIAL


def test_a_pair_is_named_only_when_it_is_adequate_and_improves_on_its_first_effects_refit():
    base = refit(("a",), 0.5, adequate=False)
    good_pair = refit(("a", "b"), 0.2)
    d = decide(REJECTS, NOMINAL, [base, good_pair])
    assert d.named == ("a", "b") and d.gain_of(("b", "a")) == gain(score(0.5), score(0.2))  # over its first refit
    # adequate but no better than the single refit it extends: the added effect buys nothing
    no_gain = refit(("a", "b"), 0.49)
    d = decide(REJECTS, NOMINAL, [base, no_gain])
    assert d.verdict == "misspecified-unexplained" and d.partial == ("a",)
    # improves but check still rejects the pair
    assert decide(REJECTS, NOMINAL, [base, refit(("a", "b"), 0.2, adequate=False)]).named == ()


def off_estimates(effect: str, *reaches_off: bool) -> tuple[Estimate, ...]:
    return tuple(Estimate(name=f"{effect}_{i}", unit="1", mean=0.5, q05=0.1, q95=0.9, width_ratio=0.5, effect=effect,
                          may_be_off=r)
                 for i, r in enumerate(reaches_off))


def test_a_refit_whose_added_effect_the_data_leave_possibly_off_is_never_named():
    # adequate and by far the lowest score, but every parameter of its effect reaches the off value
    off = replace(refit(("a",), 0.2), estimates=off_estimates("a", True, True))
    on = replace(refit(("b",), 0.5), estimates=off_estimates("b", True, False))  # one parameter excludes off: on
    assert off.maybe_off == ("a",) and on.maybe_off == ()
    d = decide(REJECTS, NOMINAL, [off, on])
    assert d.named == ("b",) and d.alternatives == ()
    d = decide(REJECTS, NOMINAL, [off])
    assert d.verdict == "misspecified-unexplained" and d.named == () and d.partial == ()  # explains nothing
    # a pair is named only when each of its effects is switched on
    base = refit(("c",), 0.5, adequate=False)
    pair = replace(refit(("c", "a"), 0.2), estimates=off_estimates("c", False) + off_estimates("a", True))
    assert pair.maybe_off == ("a",) and decide(REJECTS, NOMINAL, [base, pair]).named == ()
    # an older file's estimates (no effect, unknown) say nothing: the refit may be named
    assert decide(
        REJECTS, NOMINAL, [replace(refit(("a",), 0.2), estimates=(Estimate(name="a_0", unit="1", mean=0.5),))]
    ).named == ("a",)


def test_an_off_value_inside_the_prior_is_reached_by_the_interval_and_one_at_a_bound_by_the_density_ratio():
    wind, mass = Param("wind_y", -2.0, 2.0), Param("ballast_mass", 0.0, 0.05)
    assert may_be_off(wind, 0.0, -0.08, 1.13, None) and not may_be_off(wind, 0.0, 0.2, 1.1, None)
    # at a bound the interval decides nothing: a posterior the data left flat puts the prior's 5% next to the bound
    # (Savage-Dickey ratio 1) and may be off, although its interval excludes the bound
    assert may_be_off(mass, 0.0, 0.001, 0.048, (0.05, 0.05))
    # the ratio 0.1 (0.005 of the mass in the 5% slab) is the edge: at it the data exclude the off value
    assert not may_be_off(mass, 0.0, 0.02, 0.04, (0.005, 0.0)) and may_be_off(mass, 0.0, 0.02, 0.04, (0.006, 0.0))
    assert not may_be_off(Param("slip", 0.0, 1.0), 1.0, 0.1, 0.5, (0.3, 0.0))  # off at the upper bound: its slab
    assert may_be_off(mass, 0.0, 0.0, 0.01, None) is None  # an older report: no slab mass
    assert off_ratio(mass, 0.0, (0.025, 0.0)) == 0.5 and off_ratio(wind, 0.0, (0.05, 0.05)) is None
    assert may_be_off(wind, None, -1.0, 1.0, None) is None and may_be_off(wind, 0.0, None, None, None) is None


def test_the_refits_proposed_are_the_top_named_candidates_then_one_pair():
    ranking = (cand("g", generic=True), cand("a"), cand("b"), cand("c", p=150))
    assert next_refit(ACCEPTS, ranking, NOMINAL, [], confirm=2) is None
    assert next_refit(REJECTS, ranking, NOMINAL, [], confirm=2) == ("a",)
    done = [refit(("a",), 0.5, adequate=False, ranking=(cand("g", True), cand("b"), cand("c"))),
            refit(("b",), 0.8, adequate=False)]
    assert next_refit(REJECTS, ranking, NOMINAL, done[:1], confirm=2) == ("b",)
    # neither single explains: the improving one with the lowest score and the first named candidate its own
    # screening ranks (not the generic term)
    assert next_refit(REJECTS, ranking, NOMINAL, done, confirm=2) == ("a", "b")
    assert next_refit(REJECTS, ranking, NOMINAL, done + [refit(("b", "a"), 0.4)], confirm=2) is None
    # a single refit that explains the misfit: no pair
    assert next_refit(REJECTS, ranking, NOMINAL, [refit(("a",), 0.3), refit(("b",), 0.8)], confirm=2) is None
    # no refit lowers the score: no pair is built on nothing
    assert next_refit(REJECTS, ranking, NOMINAL, [refit(("a",), 1.0, False), refit(("b",), 1.0, False)], 2) is None
    assert next_refit(REJECTS, ranking, NOMINAL, [], confirm=0) is None
    # refits whose checks screened nothing (a trained task's, checked by the omnibus test alone): the pair is the two
    # improving singles, the lower score first; one improving single builds none
    unscreened = [refit(("b",), 0.8, adequate=False), refit(("a",), 0.5, adequate=False)]
    assert next_refit(REJECTS, ranking, NOMINAL, unscreened, confirm=2) == ("a", "b")
    assert next_refit(REJECTS, ranking, NOMINAL, [refit(("a",), 0.5, False), refit(("b",), 1.0, False)], 2) is None


def test_trained_candidates_are_refitted_first_by_their_amortised_score_and_never_when_it_does_not_improve():
    # the screening ranks a, b, c; the task trained b (its amortised refit far lower) and c (no lower): b first, then
    # the untrained a in the screening's order; c never (its refit's score estimates the same quantity)
    ranking = (cand("g", generic=True), cand("a"), replace(cand("b"), amortised=score(0.5)),
               replace(cand("c"), amortised=score(0.99)), replace(cand("d", p=150), adjusted=None))
    assert refit_order(ranking, NOMINAL) == ["b", "a"]
    assert next_refit(REJECTS, ranking, NOMINAL, [], confirm=1) == ("b",)
    assert next_refit(REJECTS, ranking, NOMINAL, [refit(("b",), 0.5, adequate=False)], confirm=2) == ("a",)
    # two improving trained candidates: the lower score first, whatever the screening says
    ranking = (cand("a"), replace(cand("b"), amortised=score(0.6)), replace(cand("c"), amortised=score(0.3)))
    assert refit_order(ranking, NOMINAL) == ["c", "b", "a"]
    # no task trained: the screening's order alone, as before
    assert refit_order((cand("g", generic=True), cand("a"), cand("b")), NOMINAL) == ["a", "b"]


def test_the_amortised_race_stops_a_candidate_once_its_refit_decision_is_made_either_way():
    from softsbi.workflows.criticism.evidence import decided
    nominal = Score(value=10.0, se=0.3, n=30)
    scores = {"good": Score(value=5.0, se=0.5, n=10), "second": Score(value=8.8, se=0.5, n=10),
              "null": Score(value=9.9, se=0.6, n=10), "worse": Score(value=11.2, se=0.6, n=10)}
    third = 10 / 30
    # futile: at a third of the rollouts, z below k_se (sqrt(1/3) - 1) = -0.85 cannot reach k_se at the cap
    assert gain(nominal, scores["worse"]).z < K_SE * (third ** 0.5 - 1)
    assert decided("worse", scores, nominal, keep=2, k_se=K_SE, fraction=third)
    # undecided: a gain near 0 at a third of the rollouts may still reach k_se; with one refit to spend, the good one
    # improving by k_se and scoring lower by k_se standard errors of the difference outranks it
    assert not decided("null", scores, nominal, keep=2, k_se=K_SE, fraction=third)
    assert decided("null", scores, nominal, keep=1, k_se=K_SE, fraction=third)
    # the ones that will be refitted stay in the race to the cap
    assert not decided("good", scores, nominal, keep=1, k_se=K_SE, fraction=third)
    assert not decided("second", scores, nominal, keep=2, k_se=K_SE, fraction=third)


def test_an_adequate_improving_amortised_refit_whose_effect_may_be_off_is_refined_and_its_refinement_decides():
    """to_refine picks the amortised single refits that are adequate, improve on the nominal fit and leave their
    effect possibly off, lowest score first; never a sequential refit, a refinement, an inadequate or a
    non-improving one, nor anything when the check does not reject. The refinement replaces it in the decision, and
    is adequate only when the refit it refines was too."""
    from softsbi.core.results import OffTest
    from softsbi.workflows.criticism.decide import to_refine
    off = OffTest(statistic=0.4, p_value=MCPValue(exceed=120, n=199), level=0.1)
    on = OffTest(statistic=3.5, p_value=MCPValue(exceed=3, n=199), level=0.1)
    hem = replace(refit(("heavy-hem",), 0.4), amortised=True, off_test=off)
    cam = replace(refit(("camera-offset",), 0.3), amortised=True, off_test=off)
    others = [replace(refit(("wind",), 0.2), amortised=True, off_test=on),          # switched on: named as it is
              replace(refit(("drift",), 0.1), off_test=None),                     # sequential: no estimates, on
              replace(refit(("slope",), 0.5, adequate=False), amortised=True, off_test=off),   # inadequate
              replace(refit(("patch",), 0.995), amortised=True, off_test=off)]    # does not improve by k_se
    assert to_refine(REJECTS, NOMINAL, [hem, cam, *others]) == [("camera-offset",), ("heavy-hem",)]
    assert to_refine(ACCEPTS, NOMINAL, [hem, cam]) == []
    assert decide(REJECTS, NOMINAL, [hem]).verdict == "misspecified-unexplained"
    # refined: the sequential posterior's estimates switch it on (no off test of its own)
    est = Estimate(name="hem_density", unit="kg/m^2", mean=0.03, q05=0.02, q95=0.04, width_ratio=0.4, pressed=None,
                   suggested_bounds=None, effect="heavy-hem", may_be_off=False, off_ratio=0.0)
    refined = replace(refit(("heavy-hem",), 0.35), estimates=(est,), refined_from=hem)
    assert to_refine(REJECTS, NOMINAL, [refined]) == []  # refined once
    d = decide(REJECTS, NOMINAL, [refined])
    assert d.verdict == "missing-effect" and d.named == ("heavy-hem",)
    # its own (uncalibrated) check does not replace the amortised refit's calibrated one
    assert not replace(refined, refined_from=replace(hem, test=REJECTS)).adequate
    assert decide(REJECTS, NOMINAL, [replace(refined, refined_from=replace(hem, test=REJECTS))]).verdict == \
        "misspecified-unexplained"
    # diagnosis.json keeps the refit it refines
    from softsbi.core.results import from_json, to_json
    assert from_json(Refit, to_json(refined)) == refined
