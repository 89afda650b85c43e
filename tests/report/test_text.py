"""Snapshot tests of every sentence check, diagnose and compare print (softsbi.report.text), rendered from fixed,
hand-built typed results: any change of wording shows here as a diff. And the table's verdict column never says
more than the verdict."""
from __future__ import annotations

from dataclasses import replace

import pytest

from result_helpers import REGIONS, candidate, check_result, energy, joint, refit, score
from softsbi.core.results.comparison import CompareResult, Metric, Row
from softsbi.core.metrics import offset_direction
from softsbi.core.results import Diagnosis, Estimate, JointTest, MCPValue, ResidualShape
from softsbi.report.text import (DIAGNOSIS_COLUMNS, candidate_role, diagnosis_columns, check_summary, compare_summary,
                                 diagnosis_rows, diagnosis_summary, diagnosis_text, estimate_words, joint_test_line,
                                 p_short, p_words, refit_words, residual_words)
from softsbi.workflows.criticism.decide import decide

# ---------------------------------------------------------------------------------------------------------------
# fixed results: a nominal fit the joint test rejects, four candidates, refits

FAMILY = ("wind", "extra-damping", "time-offset", "generic-constant")
RANKING = (candidate("generic-constant", 0.62, generic=True, description="a constant force"),
           candidate("wind", 0.55, description="a steady wind", wind_x=0.1, wind_y=0.8),
           candidate("extra-damping", 0.31, description="extra velocity damping", damping_rate=2.0),
           candidate("time-offset", 0.05, 80, kind="sensor", description="a time offset", time_offset=0.01))
NOMINAL = score(21.0, 0.5)
REJECTS = joint(0, 0)  # beyond all 200 nulls: p <= 2/201
ACCEPTS = joint(40, 60, family=("extra-damping", "time-offset", "generic-constant"), effect="extra-damping")
REJECTS_REFIT = joint(0, 30, family=("extra-damping", "time-offset", "generic-constant"), effect="extra-damping")

#: the wind's refit: adequate, 62% lower, its wind_y pressing the upper prior bound (not a physical limit)
WIND = refit(("wind",), 8, ACCEPTS,
             estimates=(Estimate(name="wind_x", unit="m/s", mean=0.05, q05=-0.2, q95=0.3, width_ratio=0.12),
                        Estimate(name="wind_y", unit="m/s", mean=1.79, q05=1.55, q95=1.98, width_ratio=0.11,
                                 pressed="upper", suggested_bounds=(-2.0, 4.0))))
#: extra damping's refit: adequate, 0.84 cm, within 2 standard errors of the wind's; its parameter not informed
DAMPING = refit(("extra-damping",), 8.4, joint(50, 70, family=("wind", "time-offset", "generic-constant")),
                estimates=(Estimate(name="damping_rate", unit="1/s", mean=3.1, q05=0.4, q95=7.9, width_ratio=0.8),))
#: single refits that lower the score but leave the measurement outside, and the pair that explains it
WIND_PART = refit(("wind",), 15, REJECTS_REFIT,
                  ranking=(candidate("generic-constant", 0.5, generic=True), candidate("extra-damping", 0.4, 1)))
DAMPING_PART = refit(("extra-damping",), 17, joint(0, 5, family=("wind", "time-offset", "generic-constant")))
PAIR = refit(("wind", "extra-damping"), 9,
             joint(60, 45, family=("time-offset", "generic-constant"), effect="time-offset"))
RESIDUAL = ResidualShape(
    frames_flagged=tuple(range(10, 22)) + (24,),
    frame_spans=((10, 21, 0.40, 0.84), (24, 24, 0.96, 0.96)),
    phases=(
        {"phase": "early", "frames": [0, 7], "fraction_flagged": 0.0, "chamfer_m": 0.011},
        {"phase": "middle", "frames": [8, 16], "fraction_flagged": 0.78, "chamfer_m": 0.035},
        {"phase": "late", "frames": [17, 24], "fraction_flagged": 0.75, "chamfer_m": 0.084},
    ),
    centroid_offset_cm=(0.3, 0.7, -0.4),
    direction="+y",
    worst_summary="y_q95",
    region_excess_cm={n: 0.1 * i for i, n in enumerate(REGIONS)},
    worst_regions=(REGIONS[8], REGIONS[7]),
)


def diagnosis(refits=(), test=REJECTS, **fields) -> Diagnosis:
    """A diagnosis of the fixed nominal fit (posterior-predictive Chamfer 2.5 cm over 30 rollouts; the refit budget
    --confirm is the number of single refits) whose decision is decide()'s on ``refits``."""
    fields = {"chamfer_m": 0.025, "chamfer_n": 30, "confirm": sum(len(r.effects) == 1 for r in refits), **fields}
    return Diagnosis(run="run/nominal", candidates=FAMILY, alpha=0.05, k_se=2.0, test=test, ranking=RANKING,
                     nominal=NOMINAL, refits=tuple(refits),
                     decision=decide(test, NOMINAL, refits, 2.0), **fields)


NOTHING = diagnosis(test=joint(90, 100))
NAMED = diagnosis([WIND])
TIE = diagnosis([WIND, DAMPING])
PAIRED = diagnosis([WIND_PART, DAMPING_PART, PAIR])
PARTIAL = diagnosis([WIND_PART, DAMPING_PART, replace(PAIR, test=joint(0, 3, family=PAIR.test.family))],
                    residual=RESIDUAL, generic=RANKING[0])
NO_REFIT = diagnosis(residual=RESIDUAL, generic=RANKING[0])
NONE_LOWER = diagnosis([refit(("wind",), 21.5, REJECTS_REFIT),
                        refit(("extra-damping",), 23, joint(0, 5, family=("wind", "time-offset",
                                                                               "generic-constant")))],
                       residual=RESIDUAL, generic=RANKING[0])
#: the wind's refit as adequate and as low, but both its parameters' posteriors reach the off value (no wind)
WIND_OFF = replace(WIND, estimates=tuple(replace(e, effect="wind", may_be_off=True) for e in WIND.estimates))
OFF = diagnosis([WIND_OFF])
#: a task trained with wind and extra-damping: wind's amortised refit scores far lower, extra-damping's no lower (within
#: 2 standard errors of the nominal's), time-offset untrained; one refit (--confirm 1)
AMORTISED = replace(diagnosis([WIND]), ranking=(RANKING[0], replace(RANKING[1], amortised=score(8.3)),
                                                replace(RANKING[2], amortised=score(20.8)), RANKING[3]))
#: the wind's amortised refit passed and improved but left wind possibly off; refined (2 rounds of 150 after it), on
REFINED = diagnosis([replace(WIND, rounds=3, sims_per_round=150, refined_from=replace(WIND_OFF, amortised=True))])
ALL = {"nothing": NOTHING, "amortised": AMORTISED, "named": NAMED, "tie": TIE, "pair": PAIRED, "partial": PARTIAL, "no refit": NO_REFIT,
       "none lower": NONE_LOWER, "off": OFF, "refined": REFINED}

# recurring phrases of the joint test
P_FLOOR = "p <= 2/201 (two tests, Bonferroni; the omnibus test beyond all 200 null simulations)"
P_WIND = "p = 0.41 (two tests, Bonferroni: 2 x the omnibus test's p = 0.2; 200 null simulations)"
DETECT = f"Detect: check's joint test of the nominal fit, {P_FLOOR} <= 0.05."
DECIDE = ("Decide: a refit explains the misfit when check's test of it gives p > 0.05 and its summary energy score (the energy score of its "
          "posterior predictive of check's summaries, a proper score, in sd: standard deviations of the nominal fit's posterior predictive) falls by more than 2 "
          "standard errors below the model it extends, and the data switch its effect on (a parameter's 90% interval "
          "excludes the effect's off value or, for an off value at a prior bound (which no interval reaches), the "
          "posterior's mass next to that bound is at most 0.1 of the prior's (a Savage-Dickey ratio)).")
WIND_WORDS = (f"With wind: the measurement is inside the refit's posterior predictive distribution ({P_WIND}), "
              "summary energy score 21 -> 8 sd (62% lower, 20.3 standard errors), posterior-predictive Chamfer 1.00 cm (n=30 rollouts). The refit estimates wind_x = 0.05 "
              "m/s (90% interval -0.2 to 0.3 m/s); wind_y = 1.79 m/s (90% interval 1.55 to 1.98 m/s). Its wind_y "
              "presses the upper prior bound: refit with --bounds wind_y=-2:4 if such values are physical.")
PART_WORDS = [f"With wind: the measurement is still outside the refit's posterior predictive distribution ({P_FLOOR}), "
              "summary energy score 21 -> 15 sd (29% lower, 9.4 standard errors), posterior-predictive Chamfer 1.70 cm (n=30 rollouts).",
              "With extra-damping: the measurement is still outside the refit's posterior predictive distribution "
              f"({P_FLOOR}), summary energy score 21 -> 17 sd (19% lower, 6.2 standard errors), posterior-predictive Chamfer 1.90 cm (n=30 rollouts)."]
#: the summaries flag the middle phase most, while the Chamfer (check's phase table) is largest late: each named with
#: its own number, never "mostly the middle phase" beside a table whose worst phase is the late one
RESIDUAL_WORDS = ("The summaries leave the rollouts' 95% range in frames 10-21 (t 0.40-0.84 s), frame 24 (t 0.96 s) "
                  "(78% of the middle phase's frames and 75% of the late phase's); the Chamfer is largest in the late phase (8.40 cm, as in "
                  "check's table); the measured centroid is displaced by (+0.3, +0.7, -0.4) cm, mostly +y; the most "
                  "deviant summary is y_q95; regions with the most error beyond the model's own spread: R9 (farthest "
                  "from the grasp; +0.80 cm), R8 (+0.70 cm).")
GENERIC_WORDS = ("Best generic force term: generic-constant explains 62% of the residual in the linearised screening "
                 "(max-T adjusted p <= 1/201 (beyond all 200 null simulations)).")
SCREENED = [["generic-constant", "physics (generic)", "62%", "p <= 1/201"], ["wind", "physics", "55%", "p <= 1/201"],
            ["extra-damping", "physics", "31%", "p <= 1/201"], ["time-offset", "sensor", "5%", "p = 0.4"]]


def rows(*refit_columns, amortised=None):
    """The expected table: the screening's columns, the amortised refit's score (only when given: a task trained with
    candidates), then per candidate (refit check p, refit summary energy score, verdict)."""
    return [s + ([] if amortised is None else [a]) + list(r)
            for s, a, r in zip(SCREENED, amortised or [None] * 4, refit_columns)]


def not_refitted(why: str) -> tuple[str, str, str]:
    """A candidate's refit columns when it was not refitted, with the reason."""
    return "-", "-", f"not refitted: {why}"


GENERIC, BUDGET = not_refitted("generic term"), not_refitted("beyond --confirm 2")


# ---------------------------------------------------------------------------------------------------------------
# diagnose


def test_nothing_missing():
    assert NOTHING.verdict == "nothing-missing"
    p = "p = 0.91 (two tests, Bonferroni: 2 x the omnibus test's p = 0.45; 200 null simulations)"
    assert diagnosis_text(NOTHING) == [
        f"Nothing missing: the measurement lies inside the nominal model's posterior predictive distribution ({p} > "
        "0.05).",
        f"Detect: check's joint test of the nominal fit, {p} > 0.05."]
    assert diagnosis_rows(NOTHING) == rows(*[not_refitted("nothing missing")] * 4)


def test_missing_effect_with_a_refit_pressing_a_prior_bound():
    assert NAMED.verdict == "missing-effect" and NAMED.decision.named == ("wind",)
    assert diagnosis_text(NAMED) == [
        "Missing physics effect: wind (a steady wind). Its refit puts the measurement inside its posterior predictive "
        f"distribution ({P_WIND}) and lowers the summary energy score from 21 to 8 sd (62% lower, 20.3 standard "
        "errors).",
        f"{DETECT} Propose: the screening ranked 4 candidates; refitted wind (the top named ones by evidence). {DECIDE}",
        WIND_WORDS]
    assert diagnosis_rows(NAMED) == rows(GENERIC, ("p = 0.41", "8", "named"),
                                         not_refitted("beyond --confirm 1"), not_refitted("beyond --confirm 1"))


def test_a_trained_task_scores_each_trained_candidates_amortised_refit_and_says_why_one_was_not_refitted():
    assert diagnosis_text(AMORTISED)[1] == (
        f"{DETECT} Propose: the screening ranked 4 candidates and the amortised posterior of each of the 2 the task "
        "trained scored its refit; refitted wind (the trained ones whose amortised refit scores lower, then the top "
        f"named ones the screening ranks). {DECIDE}")
    assert diagnosis_rows(AMORTISED) == rows(GENERIC, ("p = 0.41", "8", "named"),
                                             not_refitted("its amortised refit scores no lower"),
                                             not_refitted("beyond --confirm 1"), amortised=("-", "8.3", "20.8", "-"))
    assert diagnosis_columns(AMORTISED)[4] == "amortised score [sd]" and diagnosis_columns(AMORTISED) == DIAGNOSIS_COLUMNS
    assert "amortised score [sd]" not in diagnosis_columns(NAMED)  # no task trained: no column of dashes
    assert diagnosis_columns(NAMED)[-2] == "refit summary energy score [sd]"  # every score with its unit


def hint(n: int, why: str) -> str:
    """The last line of a diagnosis that leaves ``n`` candidates undecided (``why``: their counts by reason)."""
    return (f"Undecided: {n} candidates ({why}). `softsbi design run/nominal` ranks the motions the object supports by "
            "how well one more recording of each would inform them (seconds from trained tasks, a few minutes of "
            "simulation otherwise).")


def test_missing_effect_with_an_indistinguishable_alternative():
    assert TIE.decision.named == ("wind",) and TIE.decision.alternatives == (("extra-damping",),)
    assert diagnosis_text(TIE) == [
        "Missing physics effect: wind (a steady wind). Its refit puts the measurement inside its posterior predictive "
        f"distribution ({P_WIND}) and lowers the summary energy score from 21 to 8 sd (62% lower, 20.3 standard "
        "errors). The data cannot tell it from extra-damping: that refit explains the misfit too, with a summary "
        "energy score within 2 standard errors; evidence these recordings lack (an independent measurement of the effect, "
        "or a motion in which the two differ) would decide.",
        f"{DETECT} Propose: the screening ranked 4 candidates; refitted wind, extra-damping (the top named ones by "
        f"evidence). {DECIDE}",
        WIND_WORDS,
        "With extra-damping: the measurement is inside the refit's posterior predictive distribution (p = 0.51 (two "
        "tests, Bonferroni: 2 x the omnibus test's p = 0.25; 200 null simulations)), summary energy score 21 -> 8.4 sd (60% lower, "
        "19.7 standard errors), posterior-predictive Chamfer 1.04 cm (n=30 rollouts). The refit estimates damping_rate = 3.1 1/s (90% "
        "interval 0.4 to 7.9 1/s, not informed by the data).", hint(2, "2 indistinguishable")]
    assert diagnosis_rows(TIE) == rows(GENERIC, ("p = 0.41", "8", "named"),
                                       ("p = 0.51", "8.4", "indistinguishable"), BUDGET)


def test_missing_pair():
    assert PAIRED.decision.named == ("wind", "extra-damping")
    p_pair = "p = 0.46 (two tests, Bonferroni: 2 x the directional test's p = 0.23; 200 null simulations)"
    assert diagnosis_text(PAIRED) == [
        "Missing physics effects: wind + extra-damping. Neither refit alone explains the misfit; with both, the refit "
        f"puts the measurement inside its posterior predictive distribution ({p_pair}) and lowers the summary energy score "
        "from 15 to 9 sd (40% lower, 10.6 standard errors).",
        f"{DETECT} Propose: the screening ranked 4 candidates; refitted wind, extra-damping (the top named ones by "
        f"evidence), then the pair wind+extra-damping. {DECIDE}",
        *PART_WORDS,
        f"With wind + extra-damping: the measurement is inside the refit's posterior predictive distribution "
        f"({p_pair}), summary energy score 15 -> 9 sd (40% lower, 10.6 standard errors), posterior-predictive Chamfer 1.10 cm (n=30 rollouts)."]
    assert diagnosis_rows(PAIRED) == rows(GENERIC, ("p <= 2/201", "15", "named (pair)"),
                                          ("p <= 2/201", "17", "named (pair)"), BUDGET)


def test_misspecified_unexplained_with_a_partial_explanation_the_residual_and_the_generic_term():
    assert PARTIAL.verdict == "misspecified-unexplained" and PARTIAL.decision.partial == ("wind",)
    assert diagnosis_text(PARTIAL) == [
        "Misspecified, unexplained: the measurement lies outside the nominal model's posterior predictive "
        f"distribution ({P_FLOOR} <= 0.05), and no refit of wind, extra-damping, wind+extra-damping explains it. wind "
        "explains a part: of the single refits, it lowers the summary energy score most, from 21 to 15 sd (29% lower, 9.4 standard errors), but the measurement stays "
        f"outside its posterior predictive distribution ({P_FLOOR}).",
        f"{DETECT} Propose: the screening ranked 4 candidates; refitted wind, extra-damping (the top named ones by "
        f"evidence), then the pair wind+extra-damping. {DECIDE}",
        *PART_WORDS,
        "With wind + extra-damping: the measurement is still outside the refit's posterior predictive distribution "
        f"({P_FLOOR}), summary energy score 15 -> 9 sd (40% lower, 10.6 standard errors), posterior-predictive Chamfer 1.10 cm (n=30 rollouts).",
        RESIDUAL_WORDS,
        GENERIC_WORDS, hint(3, "3 unexplained")]
    assert diagnosis_rows(PARTIAL) == rows(GENERIC, ("p <= 2/201", "15", "explains a part"),
                                           ("p <= 2/201", "17", "refit: misfit remains"), BUDGET)


def test_misspecified_unexplained_without_refits_and_when_no_refit_lowers_the_score():
    head = ("Misspecified, unexplained: the measurement lies outside the nominal model's posterior predictive "
            f"distribution ({P_FLOOR} <= 0.05)")
    assert diagnosis_text(NO_REFIT) == [
        head + ", and no candidate was refitted.",
        f"{DETECT} Propose: the screening ranked 4 candidates; refitted none (the top named ones by evidence). "
        f"{DECIDE}",
        RESIDUAL_WORDS, GENERIC_WORDS, hint(3, "3 unexplained")]
    assert NONE_LOWER.decision.partial == ()
    assert diagnosis_summary(NONE_LOWER) == (head + ", and no refit of wind, extra-damping explains it. No refit "
                                             "lowers the summary energy score by more than 2 standard errors.")
    assert diagnosis_text(NONE_LOWER)[2] == (
        "With wind: the measurement is still outside the refit's posterior predictive distribution "
        f"({P_FLOOR}), summary energy score 21 -> 21.5 sd (2% higher, -0.8 standard errors), posterior-predictive Chamfer 2.35 cm (n=30 rollouts).")
    assert diagnosis_rows(NONE_LOWER) == rows(GENERIC, ("p <= 2/201", "21.5", "refit: misfit remains"),
                                              ("p <= 2/201", "23", "refit: misfit remains"), BUDGET)
    # a refit that check accepts but whose score does not fall: explains nothing, and the table says why
    flat = diagnosis([refit(("wind",), 20.5, ACCEPTS)])
    assert flat.verdict == "misspecified-unexplained" and flat.decision.partial == ()
    assert diagnosis_rows(flat)[1][-3:] == ["p = 0.41", "20.5", "refit: no lower score"]
    # an adequate refit far below the nominal's score, but above the named one's: the table says so, from the
    # decision's own gains (not "no lower score")
    both = diagnosis([refit(("wind",), 8, ACCEPTS), refit(("extra-damping",), 14, ACCEPTS)])
    assert both.decision.named == ("wind",) and both.decision.gain_of(("extra-damping",)).z > both.k_se
    assert diagnosis_rows(both)[2][-1] == "refit: a lower score than the nominal's, above wind's"


def test_candidates_the_task_does_not_inform_are_named_once_the_check_rejects_and_a_stored_file_without_them_reads():
    blind = {"heavy-hem": 0.96, "extra-damping": 0.91}
    words = ("Not informed by this task: extra-damping (0.91), heavy-hem (0.96). Over the task's held-out prior "
             "simulations, the median 90% interval of every one of their own parameters spans more than 0.5 of the "
             "prior's width (the narrowest in brackets): the data of this motion seldom switch these effects on, so "
             "a missing effect among them is seldom named here; a motion that excites them, trained as another "
             "task, can tell.")
    assert diagnosis_text(replace(NO_REFIT, uninformed=blind))[-2:] == [words, hint(4, "2 unexplained; 2 not informed by this task")]
    # beside a named effect, too; the uninformed ones are then what is undecided
    assert diagnosis_text(replace(NAMED, uninformed=blind))[-2:] == [words, hint(2, "2 not informed by this task")]
    assert diagnosis_text(replace(NOTHING, uninformed=blind)) == diagnosis_text(NOTHING)  # no misfit to explain
    from softsbi.core.results import from_json, to_json
    data = to_json(replace(NO_REFIT, uninformed=blind))
    assert from_json(Diagnosis, data).uninformed == blind
    assert from_json(Diagnosis, {k: v for k, v in data.items() if k != "uninformed"}).uninformed == {}


def test_a_refit_estimate_pressing_a_physical_limit_suggests_no_wider_prior():
    """A sensor refit whose noise presses the upper bound (widening named) and whose dropout presses 0, a physical
    limit (nothing to widen: no --bounds advice)."""
    r = refit(("point-noise",), 8, ACCEPTS,
              estimates=(Estimate(name="noise_std", unit="m", mean=0.0049, q05=0.0041, q95=0.0058, width_ratio=0.2,
                                  pressed="upper", suggested_bounds=(0.0, 0.015)),
                         Estimate(name="dropout", unit="1", mean=0.0, q05=0.0, q95=0.02, width_ratio=0.1,
                                  pressed="lower", suggested_bounds=None)))
    d = diagnosis([r])
    assert diagnosis_text(d)[2] == (
        f"With point-noise: the measurement is inside the refit's posterior predictive distribution ({P_WIND}), "
        "summary energy score 21 -> 8 sd (62% lower, 20.3 standard errors), posterior-predictive Chamfer 1.00 cm (n=30 rollouts). The refit estimates noise_std = 0.0049 m "
        "(90% interval 0.0041 to 0.0058 m); dropout = 0 (90% interval 0 to 0.02). Its noise_std presses the upper "
        "prior bound: refit with --bounds noise_std=0:0.015 if such values are physical.")


def test_a_refit_estimate_pressing_a_bound_that_is_no_limit_adds_the_wider_prior_and_nothing_otherwise():
    """The toy wind's refit: its wind presses the upper prior bound 0.5 m, the wider prior 0 to 0.75 m is named; the
    same estimate pressing nothing, or pressing a physical limit (no wider prior), adds no sentence."""
    def words(**pressed):
        est = Estimate(name="wind", unit="m", mean=0.49, q05=0.41, q95=0.5, width_ratio=0.2, **pressed)
        return refit_words(refit(("toy-wind",), 0.01, joint(50, 50), estimates=(est,)), score(0.02))

    plain = ("With toy-wind: the measurement is inside the refit's posterior predictive distribution (p = 0.51 (two "
             "tests, Bonferroni: 2 x the omnibus test's p = 0.25; 200 null simulations)), summary energy score 0.02 "
             "-> 0.01 sd (50% lower), posterior-predictive Chamfer 0.20 cm (n=30 rollouts). The refit estimates wind = "
             "0.49 m (90% interval 0.41 to 0.5 m).")
    assert words() == plain and words(pressed="upper", suggested_bounds=None) == plain
    assert words(pressed="upper", suggested_bounds=(0.0, 0.75)) == (
        plain + " Its wind presses the upper prior bound: refit with --bounds wind=0:0.75 if such values are physical.")


def test_an_estimate_at_a_switched_off_value_reads_zero():
    """A switched-off effect's estimate and interval (8.7e-22 and 1.3e-14 are rounding) read as 0; an estimate
    without its interval is the value alone."""
    assert estimate_words(Estimate(name="unseen_height", unit="m", mean=8.74e-22, q05=0.0, q95=1.29e-14)) == (
        "unseen_height = 0 m (90% interval 0 to 0 m)")
    assert estimate_words(Estimate(name="wind_x", unit="m/s", mean=0.0123)) == "wind_x = 0.0123 m/s"
    assert estimate_words(Estimate(name="damping_rate", unit="1/s", mean=3.1, q05=0.4, q95=7.9, width_ratio=0.8)) == (
        "damping_rate = 3.1 1/s (90% interval 0.4 to 7.9 1/s, not informed by the data)")


#: the verdict column of each fixed diagnosis, written out by hand, in the screening's order (generic-constant, wind,
#: extra-damping, time-offset)
ROLES = {"nothing": ["not refitted: nothing missing"] * 4,
         "amortised": ["not refitted: generic term", "named", "not refitted: its amortised refit scores no lower",
                       "not refitted: beyond --confirm 1"],
         "named": ["not refitted: generic term", "named", "not refitted: beyond --confirm 1",
                   "not refitted: beyond --confirm 1"],
         "tie": ["not refitted: generic term", "named", "indistinguishable", "not refitted: beyond --confirm 2"],
         "pair": ["not refitted: generic term", "named (pair)", "named (pair)", "not refitted: beyond --confirm 2"],
         "partial": ["not refitted: generic term", "explains a part", "refit: misfit remains",
                     "not refitted: beyond --confirm 2"],
         "no refit": ["not refitted: generic term", "not refitted: beyond --confirm 0",
                      "not refitted: beyond --confirm 0", "not refitted: beyond --confirm 0"],
         "none lower": ["not refitted: generic term", "refit: misfit remains", "refit: misfit remains",
                        "not refitted: beyond --confirm 2"],
         "off": ["not refitted: generic term", "refit: the data leave it possibly off", "not refitted: beyond --confirm 1",
                 "not refitted: beyond --confirm 1"],
         "refined": ["not refitted: generic term", "named", "not refitted: beyond --confirm 1",
                     "not refitted: beyond --confirm 1"]}


@pytest.mark.parametrize("name", list(ALL))
def test_the_verdict_column_never_names_an_effect_the_verdict_does_not_name(name):
    d = ALL[name]
    table = diagnosis_rows(d)
    assert len(diagnosis_columns(d)) == len(table[0]) and diagnosis_columns(d)[-1] == "verdict"
    assert [row[-1] for row in table] == ROLES[name] == [candidate_role(d, c) for c in d.ranking]
    for c, row in zip(d.ranking, table):
        assert row[0] == c.effect
        assert row[-1].startswith("named") == (c.effect in d.decision.named), (name, row)
        if d.verdict != "missing-effect":
            assert row[-1] not in ("named", "named (pair)", "indistinguishable"), (name, row)
        if c.generic:
            assert row[-1].startswith("not refitted: "), (name, row)  # a generic term is never refitted nor named
    assert {d.verdict for d in ALL.values()} == {"nothing-missing", "missing-effect", "misspecified-unexplained"}


# ---------------------------------------------------------------------------------------------------------------
# check and compare


def test_check_summary():
    assert check_summary(check_result()) == (
        "Posterior rollouts miss the measurement by 5.70 cm on average over 30 rollouts (Chamfer; measured -> simulated 4.56 cm); "
        "worst in the late phase (t 0.68-0.96 s, 11.21 cm) and in region R9 (farthest from the grasp; 8.56 cm); the "
        f"measurement is NOT explained by the model ({P_FLOOR} <= 0.05). Chamfer energy score 5.50 cm.")


def test_check_summary_with_the_height_sensor_model_and_pressed_prior_bounds():
    """The fit saw the clouds through a 1 cm height cut on frames 8-24 (the early phase not fitted, never named
    worst); its posterior presses bend's lower bound (widening suggested) and friction's 0 (a physical limit)."""
    c = check_result(metric_min_z_m=0.01, metric_frames=tuple(range(8, 25)), metric_sensor="height", table_z_m=0.0,
                     phases=tuple(replace(p, in_fit=k > 0) for k, p in enumerate(check_result().phases)),
                     posterior_at_bounds=(
                         {"param": "bend", "side": "lower", "bound": 1e-6, "unit": "N*m", "mass": 0.42,
                          "suggested_bounds": [3.16e-8, 1e-3]},
                         {"param": "friction", "side": "lower", "bound": 0.0, "unit": "1", "mass": 0.3,
                          "suggested_bounds": None}),
                     test=joint(40, 70))
    assert check_summary(c) == (
        "Posterior rollouts miss the measurement by 5.70 cm on average over 30 rollouts (Chamfer under the fit's sensor model: points "
        "within 1.0 cm of the table unseen, frames 8-24; measured -> simulated 4.56 cm); worst in the late phase "
        "(t 0.68-0.96 s, 11.21 cm) and in region R9 (farthest from the grasp; 8.56 cm); no evidence of misspecification "
        f"({P_WIND} > 0.05). Chamfer energy score 5.50 cm. The fit's posterior: bend's posterior presses its lower prior "
        "bound 1e-06 N*m (42% of its mass near it): widen the prior (--bounds bend=3.16e-08:0.001) if such values are "
        "physical, or suspect an effect the model lacks. The fit's posterior: friction's posterior presses its lower "
        "prior bound 0 (30% of its mass near it): the bound is a physical limit, so suspect an effect the model "
        "lacks.")


def test_check_summary_through_the_virtual_depth_sensor_without_an_energy_score():
    c = check_result(metric_sensor="camera", energy=None, chamfer_one_sided_mean_m=None)
    assert check_summary(c) == (
        "Posterior rollouts miss the measurement by 5.70 cm on average over 30 rollouts (Chamfer under the fit's sensor model: "
        "simulated clouds made by the recording's virtual depth sensor); worst in the late phase (t 0.68-0.96 s, "
        "11.21 cm) and in region R9 (farthest from the grasp; 8.56 cm); the measurement is NOT explained by the model "
        f"({P_FLOOR} <= 0.05).")


def test_compare_summary():
    a = check_result(posterior_mean={"chamfer_m": 0.02, "chamfer_se_m": 0.001, "n": 3})
    b = check_result(test=joint(40, 70), chamfer_mean_m=0.012, energy=energy(0.009),
                     posterior_mean={"chamfer_m": 0.009, "chamfer_se_m": 0.001, "n": 3})
    table = (
        Row(
            what="posterior-predictive Chamfer, mean over the fit's frames",
            a=a.chamfer_mean_m,
            b=b.chamfer_mean_m,
            metric=Metric.CHAMFER,
        ),
        Row(
            what="posterior-mean rollout Chamfer (the fitted point estimate)",
            a=0.02,
            b=0.009,
            metric=Metric.POSTERIOR_MEAN,
        ),
        Row(
            what="Chamfer energy score (a proper score: Chamfer less half the mean Chamfer between two rollouts)",
            a=a.energy.energy_m,
            b=b.energy.energy_m,
            metric=Metric.ENERGY_CHAMFER,
        ),
    )
    res = CompareResult(
        run_a="run/nominal",
        run_b="run/refit-wind",
        label_a="mujoco-flex (nominal)",
        label_b="mujoco-flex + wind",
        rows=table,
        same_sensor=True,
        check_a=a,
        check_b=b,
        png="run/refit-wind/compare.png",
    )
    assert compare_summary(res) == (
        "mujoco-flex (nominal) -> mujoco-flex + wind: posterior-predictive Chamfer 5.70 cm (n=30 rollouts) -> 1.20 cm "
        "(n=30 rollouts) (79% lower), "
        "Chamfer energy score 5.50 cm -> 0.90 cm (84% lower), posterior-mean rollout 2.00 cm -> 0.90 cm (55% lower); "
        f"misspecification {P_FLOOR} -> {P_WIND}.")
    assert compare_summary(replace(res, same_sensor=False, rows=table[:1])) == (
        "mujoco-flex (nominal) -> mujoco-flex + wind: posterior-predictive Chamfer 5.70 cm (n=30 rollouts) -> 1.20 cm "
        "(n=30 rollouts) (79% lower); "
        f"misspecification {P_FLOOR} -> {P_WIND}. The two fits use different sensor models (--sensor / --min-height "
        "/ --frames), so their Chamfer values measure different things.")



def test_compare_rows_are_keyed_by_their_metric_and_labelled_as_before():
    """Rows are found by their metric, never by their English label; the labels (compare.json's ``what``) are the
    ones compare always wrote, and an old compare.json (rows without ``metric``) reads back with the same keys."""
    import json

    from softsbi.core.results import from_json, to_json
    from softsbi.workflows.criticism.compare import compare_rows
    a = check_result(posterior_mean={"chamfer_m": 0.02, "chamfer_se_m": 0.001, "n": 3})
    b = check_result(chamfer_mean_m=0.012, energy=energy(0.009), n_rollouts=28,
                     posterior_mean={"chamfer_m": 0.009, "chamfer_se_m": 0.001, "n": 3})
    rows = compare_rows(a, b)
    assert [(r.metric, r.part) for r in rows[:4]] == [(Metric.CHAMFER, ""), (Metric.CHAMFER_ONE_SIDED, ""),
                                                      (Metric.ENERGY_CHAMFER, ""), (Metric.POSTERIOR_MEAN, "")]
    assert [r.what for r in rows[:5]] == [
        "posterior-predictive Chamfer, mean over the fit's frames (n=30 and 28 rollouts)",
        "one-sided Chamfer (measured -> simulated)",
        "Chamfer energy score (a proper score: Chamfer less half the mean Chamfer between two rollouts)",
        "posterior-mean rollout Chamfer (the fitted point estimate)", "early phase (0.00-0.28 s)"]
    assert [(r.metric, r.part) for r in rows[4:7]] == [(Metric.PHASE, p) for p in ("early", "middle", "late")]
    assert [(r.metric, r.part, r.what) for r in rows[7:9]] == [(Metric.REGION, REGIONS[0], f"region {REGIONS[0]}"),
                                                               (Metric.REGION, "R2", "region R2")]
    res = CompareResult(run_a="a", run_b="b", label_a="nominal", label_b="+ wind", rows=rows, same_sensor=True, check_a=a, check_b=b)
    assert res.row(Metric.ENERGY_CHAMFER).b == 0.009 and replace(res, rows=rows[:2]).row(Metric.ENERGY_CHAMFER) is None
    doc = json.loads(json.dumps(to_json(res)))
    assert doc["rows"][2]["metric"] == "energy_chamfer"
    assert from_json(CompareResult, doc) == res
    old = [{"what": w, "a": r.a, "b": r.b} for w, r in zip(
        ["posterior-predictive Chamfer, mean over the fit's frames (n=30 and 28 rollouts)",
         "one-sided Chamfer (measured -> simulated)",
         "energy score (a proper score: Chamfer less half the mean Chamfer between two rollouts)",
         "posterior-mean rollout Chamfer (the fitted point estimate)", "early phase (0.00-0.28 s)",
         "middle phase (0.32-0.60 s)", "late phase (0.64-0.96 s)"] + [f"region {n}" for n in REGIONS], rows)]
    back = from_json(CompareResult, {**doc, "rows": old})
    assert [(r.metric, r.part) for r in back.rows] == [(r.metric, r.part) for r in rows]
    with pytest.raises(ValueError, match="a compare row of unknown kind: 'mystery'"):
        from_json(CompareResult, {**doc, "rows": [{"what": "mystery", "a": 1.0, "b": 1.0}]})


def test_p_values_in_words_and_in_table_cells_say_their_resolution():
    """The words of a Monte-Carlo p-value and of check's joint test (formerly MCPValue.text / JointTest.text, with the
    tests of softsbi.workflows.criticism.stats and decide): never below the resolution of the null that gave them."""
    assert p_words(MCPValue(exceed=3, n=30)) == "p = 0.13 (3 of 30 null simulations as extreme)"
    assert p_words(MCPValue(exceed=0, n=30)) == "p <= 1/31 (beyond all 30 null simulations)"
    assert (p_short(MCPValue(exceed=3, n=30)), p_short(MCPValue(exceed=0, n=30))) == ("p = 0.13", "p <= 1/31")
    assert p_words(joint(0, 30)) == ("p <= 2/201 (two tests, Bonferroni; the omnibus test beyond all 200 null "
                                     "simulations)")
    assert p_words(joint(12, 3)) == ("p = 0.04 (two tests, Bonferroni: 2 x the directional test's p = 0.02; 200 null "
                                     "simulations)")
    assert p_words(joint(60, None)) == "p = 0.3 (60 of 200 null simulations as extreme)"
    assert (p_short(joint(0, 3)), p_short(joint(67, 70)), p_short(joint(0, None, n=30))) == \
        ("p <= 2/201", "p = 0.68", "p <= 1/31")
    assert joint_test_line(joint(12, 3)) == (
        "misspecification test: omnibus p = 0.065 (12 of 200 null simulations as extreme); directional (max-T over 2 "
        "candidate effects, strongest wind) p = 0.02 (3 of 200 null simulations as extreme)")
    assert joint_test_line(joint(12, None)) == "misspecification test: omnibus p = 0.065 (12 of 200 null simulations as extreme)"


def test_a_calibrated_omnibus_p_value_counts_replicate_recordings_and_its_own_null_sets_the_floor():
    """A trained task's calibrated omnibus test (softsbi.workflows.criticism.check_null) against 100 replicates, beside a
    directional test on 30 rollouts: each p-value names what it counts, and the joint floor is the larger null's."""
    cal = JointTest(omnibus=MCPValue(exceed=0, n=100), directional=MCPValue(exceed=5, n=30), directional_effect="wind",
                    family=("wind",), alpha=0.05, max_null=200, statistic=3.2, calibrated=True)
    assert cal.n_null == 100 and cal.deciding == "omnibus" and cal.p_value == pytest.approx(2 / 101)
    assert p_words(cal) == ("p <= 2/101 (two tests, Bonferroni; the omnibus test beyond all 100 replicate recordings "
                            "of the task, refitted and checked the same way)")
    assert joint_test_line(cal) == (
        "misspecification test: omnibus (calibrated) p <= 1/101 (beyond all 100 replicate recordings of the task, "
        "refitted and checked the same way); directional (max-T over 1 candidate effects, strongest wind) p = 0.19 "
        "(5 of 30 null simulations as extreme)")
    weak = JointTest(
        omnibus=MCPValue(exceed=40, n=100),
        directional=MCPValue(exceed=1, n=30),
        directional_effect="wind",
        family=("wind",),
        alpha=0.05,
        max_null=200,
        statistic=3.2,
        calibrated=True,
    )
    assert p_words(weak) == ("p = 0.13 (two tests, Bonferroni: 2 x the directional test's p = 0.065; 30 null "
                             "simulations)")

# ---------------------------------------------------------------------------------------------------------------
# words that agree with the tables beside them


def test_the_residual_names_the_phase_check_s_table_gives_as_worst():
    """The summaries flag the middle phase most, the table's Chamfer is worst late: the words name the late phase as
    the one with the largest Chamfer, with the table's number, and the middle one only with its share of flagged
    frames (never "mostly the middle phase")."""
    words = diagnosis_text(NO_REFIT)[2]
    worst = max(RESIDUAL.phases, key=lambda p: p["chamfer_m"])
    assert worst["phase"] == "late" and "the Chamfer is largest in the late phase (8.40 cm" in words
    assert "mostly the middle phase" not in words and "78% of the middle phase's frames" in words


def test_an_adequate_refit_with_a_higher_chamfer_than_the_nominal_is_not_described_as_a_win():
    """A pair refit check accepts, its posterior-predictive Chamfer 4.19 cm against the nominal fit's 3.63 cm: the
    Chamfer is said as a fact, never as the reason the decision gives (it names the pair)."""
    pair = replace(PAIR, chamfer_m=0.0419, chamfer_n=30)
    d = diagnosis([WIND_PART, DAMPING_PART, pair], chamfer_m=0.0363, chamfer_n=30)
    words = diagnosis_text(d)[4]
    assert d.decision.named == ("wind", "extra-damping")
    assert words == ("With wind + extra-damping: check does not reject the refit (p = 0.46 (two tests, Bonferroni: 2 x "
                     "the directional test's p = 0.23; 200 null simulations)), summary energy score 15 -> 9 sd (40% "
                     "lower, 10.6 standard errors); its posterior-predictive Chamfer 4.19 cm (n=30 rollouts) is higher "
                     "than the nominal fit's 3.63 cm (n=30 rollouts).")
    assert "inside the refit's posterior predictive" not in words and "Set aside" not in words
    # lower than the nominal's: the usual words
    assert "is inside the refit's posterior predictive distribution" in diagnosis_text(PAIRED)[4]


def test_the_table_and_the_prose_give_one_reason_for_setting_a_refit_aside():
    """The user's conveyor: an adequate refit (p = 1) whose effect the data leave possibly off, with twice the nominal
    fit's Chamfer. The table says "possibly off"; the paragraph gives that reason too, never the Chamfer."""
    off = replace(WIND_OFF, test=joint(200, 200, family=ACCEPTS.family), chamfer_m=0.05)
    d = diagnosis([off], chamfer_m=0.025)
    assert d.verdict == "misspecified-unexplained"
    assert diagnosis_rows(d)[1][-1] == "refit: the data leave it possibly off"
    words = diagnosis_text(d)[2]
    assert words.startswith("With wind: check does not reject the refit (p = 1 ")
    assert ("its posterior-predictive Chamfer 5.00 cm (n=30 rollouts) is higher than the nominal fit's 2.50 cm (n=30 "
            "rollouts). Set aside: the data leave it possibly off (its effect is switched on when a parameter's 90% "
            "interval excludes the effect's off value or, for an off value at a prior bound (which no interval "
            "reaches), the posterior's mass next to that bound is at most 0.1 of the prior's (a Savage-Dickey ratio), "
            "and no parameter of it does so): the refit explains the misfit by widening its "
            "predictions, not by identifying a cause. The refit estimates") in words
    assert "error is higher" not in words
    # an adequate refit scoring lower than the nominal's but above the named one's, and one scoring no lower: the
    # paragraph says what the table says
    both = diagnosis([refit(("wind",), 8, ACCEPTS), refit(("extra-damping",), 14, ACCEPTS)])
    assert diagnosis_rows(both)[2][-1] == "refit: a lower score than the nominal's, above wind's"
    assert diagnosis_text(both)[3].endswith(
        "Set aside: a lower score than the nominal's, above wind's (by more than 2 standard errors).")
    assert "Set aside" not in diagnosis_text(both)[2]  # the named one
    flat = diagnosis([refit(("wind",), 20.5, ACCEPTS)])
    assert diagnosis_rows(flat)[1][-1] == "refit: no lower score"
    assert diagnosis_text(flat)[2].endswith(
        "Set aside: no lower score (its summary energy score is not 2 standard errors below the model it extends).")
    # a refit that check rejects: its first sentence says so ("still outside"), as the table ("misfit remains")
    assert all("Set aside" not in w for w in PART_WORDS) and "Set aside" not in diagnosis_text(PARTIAL)[3]


def test_a_named_effect_s_wide_interval_that_excludes_its_off_value_says_the_data_switch_it_on():
    """The conveyor's belt speed: the interval is wide (not narrowed to half the prior's), but it excludes 0, the off
    value, which is why the effect was named: the words say what the data do inform."""
    belt = Estimate(name="belt_speed", unit="m/s", mean=0.316, q05=0.162, q95=0.467, width_ratio=0.8, effect="conveyor",
                    may_be_off=False)
    assert estimate_words(belt) == ("belt_speed = 0.316 m/s (90% interval 0.162 to 0.467 m/s: the data show the effect "
                                    "is on, its size known to within ±0.153 m/s)")
    assert estimate_words(replace(belt, may_be_off=True)) == (
        "belt_speed = 0.316 m/s (90% interval 0.162 to 0.467 m/s, not informed by the data)")
    assert estimate_words(replace(belt, width_ratio=0.2)) == "belt_speed = 0.316 m/s (90% interval 0.162 to 0.467 m/s)"


def test_the_residual_names_tied_axes_and_the_share_of_every_phase_the_flagged_frames_fall_in():
    """(+1.9, +2.0, +0.0) cm is not "mostly +y"; frames 0-24, every frame of the fit, are not "100% of the move 1
    phase's frames" (three of them)."""
    every = replace(RESIDUAL, frames_flagged=tuple(range(25)), frame_spans=((0, 24, 0.0, 0.96),),
                    phases=({"phase": "move 1", "frames": [0, 2], "fraction_flagged": 1.0, "chamfer_m": 0.01},
                            {"phase": "lift", "frames": [3, 24], "fraction_flagged": 1.0, "chamfer_m": 0.02}),
                    centroid_offset_cm=(1.9, 2.0, 0.0), direction="+x and +y")
    words = residual_words(every)
    assert words.startswith("The summaries leave the rollouts' 95% range in frames 0-24 (t 0.00-0.96 s) (every "
                            "fitted frame);")
    assert "displaced by (+1.9, +2.0, +0.0) cm, +x and +y alike;" in words and "mostly" not in words
    part = replace(every, phases=(every.phases[0], {**every.phases[1], "fraction_flagged": 0.5}),
                   centroid_offset_cm=(0.0, -0.3, -1.2))
    words = residual_words(part)
    assert "(100% of the move 1 phase's frames and 50% of the lift phase's)" in words
    assert "displaced by (+0.0, -0.3, -1.2) cm, mostly -z (down);" in words
    assert "displaced by (+0.0, +0.0, +0.0) cm; the most" in residual_words(replace(part, centroid_offset_cm=(0.01, 0, 0)))
    assert offset_direction((1.9, 2.0, 0.0)) == "+x and +y" and offset_direction((0.3, 0.7, -0.4)) == "+y"


def test_with_several_handles_the_check_says_whose_grasp_the_regions_are_numbered_from():
    c = check_result(grasp_handle="left")
    assert ("in region R9 (farthest from the grasp; 8.56 cm) (regions numbered from the grasp of handle 'left');"
            in check_summary(c))
    assert "numbered from" not in check_summary(check_result())


def test_every_posterior_predictive_chamfer_says_its_number_of_rollouts():
    c = check_result(n_rollouts=12)
    assert "5.70 cm on average over 12 rollouts" in check_summary(c)
    for paragraph in diagnosis_text(PAIRED)[2:]:
        assert "posterior-predictive Chamfer" in paragraph and "(n=30 rollouts)" in paragraph


def test_a_diagnosis_gain_is_dimensionless_and_an_older_file_still_reads():
    from softsbi.core.results import SCHEMA, Gain, from_json, to_json
    data = to_json(NAMED)
    assert data["schema"] == SCHEMA >= 3 and set(data["decision"]["gain"]) == {"difference", "se", "z"}
    old = {**data, "schema": 2, "decision": {**data["decision"], "gain": {"difference_m": 13.0, "se_m": 0.64,
                                                                            "z": 20.3}}}
    assert from_json(Diagnosis, old).decision.gain == Gain(difference=13.0, se=0.64, z=20.3)


def test_the_fit_report_hints_at_check_when_the_90_intervals_miss_more_hidden_values_than_chance():
    from softsbi.report.text import TRUTH_MISS_LEVEL, truth_miss_hint
    three = {"a": False, "b": False, "c": False, "d": True, "e": True}
    hint = truth_miss_hint(three, "runs/shake")
    assert hint == ("Note: the 90% intervals miss 3 of 5 hidden values, more than chance allows (p = 0.0086 <= 0.05): "
                    "the model may lack an effect; `softsbi check runs/shake` shows where and when it misses the "
                    "measurement.")
    # two misses of five happen by chance 8% of the time; one is expected; a parameter without hidden value is
    # not counted
    assert truth_miss_hint({**three, "c": True}, "r") is None and TRUTH_MISS_LEVEL == 0.05
    assert truth_miss_hint({"a": False, "b": True, "c": None}, "r") is None
    assert truth_miss_hint({**three, "c": True}, "r", level=0.1) is not None


def test_an_unexplained_verdict_gives_the_reason_each_refit_was_set_aside_not_a_score_it_contradicts():
    """A refit 3.4 standard errors better was set aside as possibly off; the summary said "No refit lowers the summary
    energy score by more than 2 standard errors" two lines above its own "(... 3.4 standard errors)"."""
    snag = Estimate(name="snag_k", unit="N/m", mean=3.5, q05=0.51, q95=7.5, width_ratio=0.7, effect="snag",
                    may_be_off=True, off_ratio=1.2)
    d = diagnosis([refit(("snag",), 8, ACCEPTS, estimates=(snag,)), refit(("wind",), 20.5, ACCEPTS)])
    assert d.verdict == "misspecified-unexplained"
    summary = diagnosis_text(d)[0]
    assert "No refit lowers" not in summary
    assert summary.endswith("Set aside: snag: the data leave it possibly off; wind: no lower score.")
    # every refit no lower: the sentence that is then true
    assert diagnosis_text(diagnosis([refit(("wind",), 20.5, ACCEPTS)]))[0].endswith(
        "No refit lowers the summary energy score by more than 2 standard errors.")
    # at a prior bound the printed criterion is the one applied: the ratio, beside an interval that excludes 0
    words = diagnosis_text(d)[2]
    assert ("snag_k = 3.5 N/m (90% interval 0.51 to 7.5 N/m; its posterior next to the off value is 1.2 times the "
            "prior's (possibly off: on at most 0.1), not informed by the data)") in words
    assert "Savage-Dickey" in diagnosis_text(d)[1]  # the rule as applied names the bound's criterion


def test_a_check_whose_directional_test_did_not_run_says_so_and_what_its_p_value_is():
    """A rope's default family held a cloth-only candidate whose refusal stopped the whole screening: check.json had
    "directional": null and the verdict rested on the omnibus test alone, without a word."""
    from softsbi.report.text import rule_words, test_verdict
    alone = replace(joint(3, None), directional_skipped="the screening failed: a sensitivity simulation failed")
    assert test_verdict(alone) == (
        "the measurement is NOT explained by the model (p = 0.02 (3 of 200 null simulations as extreme) <= 0.05); "
        "the directional test did not run (the screening failed: a sensitivity simulation failed): the p-value is "
        "the omnibus test's alone")
    assert "did not run" not in test_verdict(joint(3, 5))
    assert "the directional test did not run (no candidate effects)" in rule_words(
        diagnosis([], test=replace(joint(0, None), directional_skipped="no candidate effects")))


def test_a_min_p_combined_test_says_how_it_was_combined_and_counts_its_own_null():
    """A joint test combined by its null's own minima says so, with the deciding test's own p-value; a calibrated one
    counts replicate recordings. Results written before the combination keep their Bonferroni words (above)."""
    t = replace(joint(2, 0), combined=MCPValue(exceed=0, n=200))
    assert p_words(t) == ("p <= 1/201 (two tests, min-p combined; beyond all 200 null simulations; the directional "
                          "test's own p <= 1/201)")
    assert p_short(t) == "p <= 1/201" and t.resolution == 1 / 201
    cal = replace(joint(9, 4), combined=MCPValue(exceed=3, n=40), calibrated=True)
    assert p_words(cal).startswith("p = 0.098 (two tests, min-p combined: 3 of 40 replicate recordings of the task")
    assert p_short(cal) == "p = 0.098" and not cal.misspecified


def test_a_refined_refit_says_why_it_was_refined_and_that_its_numbers_are_the_refinement_s():
    """diagnose refines an amortised refit that passed and improved but left its effect possibly off: the rule's
    Propose sentence names it, and its paragraph says why and how, before its own (the refinement's) estimates."""
    text = diagnosis_text(REFINED)
    assert REFINED.decision.named == ("wind",)
    assert ("; refined wind (an amortised refit that passed and improved but left its effect possibly off, fitted again "
            "in sequential rounds after its amortised posterior).") in text[-2] + text[-1] + "".join(text)
    para = next(t for t in text if t.startswith("With wind:"))
    assert (f"Refined: its amortised refit passed check ({P_WIND}) and lowered the summary energy score to 8 but left "
            "wind possibly off (no parameter's posterior excluded its off value), so it was fitted again in 2 "
            "sequential rounds of 150 simulations after that posterior; the numbers here are the refinement's.") in para
    assert para.index("Refined:") < para.index("The refit estimates")
    assert "Refined" not in "".join(diagnosis_text(NAMED))
