"""A task's diagnosis across its recordings, decided on hand-built per-recording results
(softsbi.workflows.criticism.joint_decide): no simulation."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest
from scipy.stats import binom, chi2

from result_helpers import joint, recording, wind_refit
from softsbi.core.errors import SoftsbiError
from softsbi.core.results.joint import CombinedTest, JointDiagnosis, SwitchedOn, binomial_tail, chi2_sf_even
from softsbi.core.results import Gain, MCPValue, from_json, to_json
from softsbi.workflows.criticism.joint_decide import (MIN_RECORDINGS, check_recordings, decide_joint,
                                                      informed_by_recording, rig_candidate,
                                                      joint_candidate, nominal_test, ranked, set_candidates)

ALPHA, K_SE = 0.05, 2.0
REJECTS = joint(0, 0)  # beyond all 200 nulls: p = 2/201
ACCEPTS = joint(120, 150)  # p = 1
LOW = joint(20, 40)  # p = 2 * 21/201 = 0.21: no rejection alone


def on_the_set(recs, refits_by_effect):
    """The candidates' rows and the set's decision, as diagnose_runs makes them."""
    cands = ranked([joint_candidate(e, recs, rs, ALPHA) for e, rs in refits_by_effect.items()])
    return decide_joint(nominal_test(recs, ALPHA), cands, K_SE), cands


def test_the_paired_standard_error_comes_from_the_spread_across_recordings():
    # one recording's gain among four null ones is one standard error, however large it is
    for big in (5.0, 50.0, 5000.0):
        g = Gain.paired([big, 0, 0, 0, 0])
        assert g.difference == big and g.z == pytest.approx(1.0)
    # consistent gains: the sum over sd * sqrt(R)
    d = [6.0, 6.5, 5.7, 6.3, 7.0]
    g = Gain.paired(d)
    sd = math.sqrt(sum((x - sum(d) / 5) ** 2 for x in d) / 4)
    assert g.difference == pytest.approx(31.5) and g.se == pytest.approx(sd * math.sqrt(5)) and g.z > 20
    # never below the Monte-Carlo standard error of the sum (equal gains have no spread), and none from one number
    assert Gain.paired([1.0, 1.0, 1.0], mc_se=0.6).se == 0.6 and Gain.paired([1.0]) is None


def test_fishers_method_and_the_binomial_tail_are_the_textbook_distributions():
    for x, df in ((0.5, 2), (9.2, 10), (46.1, 10), (30.0, 20)):
        assert chi2_sf_even(x, df) == pytest.approx(chi2.sf(x, df), rel=1e-9)
    for k, n, q in ((1, 5, 0.1), (3, 5, 0.1), (5, 5, 0.1), (0, 4, 0.2)):
        assert binomial_tail(k, n, q) == pytest.approx(binom.sf(k - 1, n, q), rel=1e-9)
    t = CombinedTest(p_values=(2 / 201, 0.5, 0.5), resolutions=(2 / 201,) * 3, alpha=ALPHA)
    assert t.df == 6 and t.p_value == pytest.approx(chi2.sf(-2 * math.log(2 / 201 * 0.25), 6))
    # the Monte-Carlo p-values enter at their floor 1/(n+1), never below: the combined p is no lower than the
    # resolution, which all recordings at their floor reach
    at_floor = [MCPValue(exceed=0, n=200).value] * 3
    floor = CombinedTest(p_values=tuple(at_floor), resolutions=tuple(at_floor), alpha=ALPHA)
    assert floor.p_value == floor.resolution == pytest.approx(chi2.sf(-6 * math.log(1 / 201), 6)) and floor.rejects
    assert t.p_value >= t.resolution
    # switched on: 3 of 5 beyond the 10% chance rate rejects at 5%, 2 of 5 does not (8.1%)
    assert SwitchedOn(on=(True,) * 3 + (False,) * 2, chance=0.1, alpha=ALPHA).switched_on
    two = SwitchedOn(on=(True,) * 2 + (False,) * 3, chance=0.1, alpha=ALPHA)
    assert not two.switched_on and two.p_value == pytest.approx(0.0815, abs=1e-4)


def test_named_for_the_set_when_all_five_recordings_gain_consistently():
    nominal, refit = [10, 11, 9.5, 10.5, 12], [4, 4.5, 3.8, 4.2, 5]
    recs = [recording(f"r{i}", n, REJECTS, (wind_refit(v, wind_y=0.6 + 0.1 * i),)) for i, (n, v) in
            enumerate(zip(nominal, refit))]
    dec, (wind,) = on_the_set(recs, {"wind": [d.refits[0] for d in recs]})
    assert dec.verdict == "missing-effect" and dec.named == ("wind",) and dec.gain == wind.gain
    assert wind.gain.difference == pytest.approx(sum(nominal) - sum(refit)) and wind.gain.z > K_SE
    assert wind.adequate and wind.adequate_on == (0, 1, 2, 3, 4) and wind.on.count == 5 and wind.on.switched_on
    # each recording keeps its own estimate: their median and range
    assert wind.estimates("wind_y") == pytest.approx((0.6, 0.7, 0.8, 0.9, 1.0))
    assert wind.spread("wind_y") == pytest.approx((0.8, 0.6, 1.0)) and wind.parameters == ("wind_y",)


def test_not_named_for_the_set_when_only_one_of_five_gains_though_its_own_diagnosis_names_it():
    hidden = recording("r0", 10.0, REJECTS, (wind_refit(4.0),))
    assert hidden.verdict == "missing-effect" and hidden.decision.named == ("wind",)  # its own verdict
    controls = [recording(f"r{i}", 4.0 + 0.1 * i, LOW) for i in range(1, 5)]
    assert all(d.verdict == "nothing-missing" for d in controls)
    recs = [hidden] + controls
    assert set_candidates(recs, confirm=2) == ("wind",)  # the hidden recording's own refit proposes it
    # refitted on the controls, the wind gains nothing there; even switched on everywhere (as the toy wind's bound
    # pressure leaves it), its summed gain is about one paired standard error
    extra = [wind_refit(4.1 + 0.15 * i) for i in range(1, 5)]
    test = nominal_test(recs, ALPHA)
    assert test.rejects  # the set is misfit (Fisher: 2/201 and four 0.21s)
    dec, (wind,) = on_the_set(recs, {"wind": [hidden.refits[0]] + extra})
    assert wind.on.switched_on and wind.adequate and wind.gain.difference > 5
    assert wind.gain.z < 1.5 and wind.fails(K_SE) == ("improves",)
    assert dec.verdict == "misspecified-unexplained" and dec.named == () and dec.partial == ()
    # however large the one recording's gain: still not named
    huge = recording("r0", 1000.0, REJECTS, (wind_refit(4.0),))
    dec, _ = on_the_set([huge] + controls, {"wind": [huge.refits[0]] + extra})
    assert dec.named == ()


def test_nothing_for_controls():
    recs = [recording(f"c{i}", 4.0 + 0.1 * i, ACCEPTS) for i in range(5)]
    assert all(d.refits == () for d in recs) and set_candidates(recs, 2) == ()
    dec, cands = on_the_set(recs, {})
    assert dec.verdict == "nothing-missing" and cands == ()
    # a candidate refitted anyway is not named when the set's checks do not reject
    dec, _ = on_the_set(recs, {"wind": [wind_refit(3.0) for _ in recs]})
    assert dec.verdict == "nothing-missing" and dec.named == ()


def test_fewer_than_three_recordings_cannot_be_judged():
    recs = [recording(f"r{i}", 10.0, REJECTS, (wind_refit(4.0),)) for i in range(2)]
    with pytest.raises(SoftsbiError, match=f"needs {MIN_RECORDINGS} recordings or more \\(got 2\\)"):
        on_the_set(recs, {"wind": [d.refits[0] for d in recs]})
    with pytest.raises(SoftsbiError, match="got 1"):
        check_recordings(1)
    check_recordings(3)


def test_a_candidate_inadequate_on_the_set_explains_a_part():
    recs = [recording(f"r{i}", 10.0 + i, REJECTS, (wind_refit(4.0 + 0.3 * i, test=joint(2, 3)),)) for i in range(5)]
    assert all(not d.refits[0].adequate for d in recs)
    dec, (wind,) = on_the_set(recs, {"wind": [d.refits[0] for d in recs]})
    assert not wind.adequate and wind.adequacy.rejects and wind.fails(K_SE) == ("adequate",)
    assert dec.verdict == "misspecified-unexplained" and dec.partial == ("wind",) and dec.gain == wind.gain


def test_an_effect_switched_on_in_fewer_recordings_than_chance_allows_is_not_named():
    def run(n_on):
        recs = [recording(f"r{i}", 10.0 + i, REJECTS, (wind_refit(4.0 + 0.3 * i, on=i < n_on),)) for i in range(5)]
        return on_the_set(recs, {"wind": [d.refits[0] for d in recs]})
    dec, (wind,) = run(2)
    assert wind.on.count == 2 and wind.fails(K_SE) == ("switched on",) and dec.named == () and dec.partial == ()
    dec, (wind,) = run(3)
    assert wind.on.count == 3 and dec.named == ("wind",)


def test_two_candidates_within_k_se_paired_are_indistinguishable_and_the_lower_one_is_named():
    recs = [recording(f"r{i}", 10.0 + i, REJECTS, (wind_refit(4.0 + 0.3 * i),)) for i in range(5)]
    wind = [d.refits[0] for d in recs]
    close = [wind_refit(r.score.value + d, effect="drag") for r, d in zip(wind, (0.3, -0.2, 0.1, 0.4, -0.1))]
    far = [wind_refit(r.score.value + 2.0 + 0.1 * i, effect="mass") for i, r in enumerate(wind)]
    dec, cands = on_the_set(recs, {"drag": close, "wind": wind, "mass": far})
    assert [c.effect for c in cands] == ["wind", "drag", "mass"]  # by summed score
    assert dec.named == ("wind",) and dec.alternatives == (("drag",),)
    # the difference to the best, paired over recordings
    assert cands[0].to_best is None and cands[2].to_best.difference == pytest.approx(11.0) and cands[2].to_best.z > 2


def test_the_sets_candidates_are_the_most_often_refitted_then_by_summed_share():
    a = recording("a", 10, REJECTS, (wind_refit(4.0),))
    drag = wind_refit(5.0, effect="extra-damping")
    b = recording("b", 10, REJECTS, (drag, wind_refit(4.0)))
    c = recording("c", 10, REJECTS, (drag,))
    d = recording("d", 10, REJECTS, (drag,))
    assert set_candidates([a, b, c, d], 2) == ("extra-damping", "wind")
    assert set_candidates([a, b, c, d], 1) == ("extra-damping",) and set_candidates([a, b], 0) == ()
    assert set_candidates([a, b], 2) == ("wind", "extra-damping")  # 2 recordings each; the wind's share is larger


def test_a_joint_diagnosis_round_trips_through_json():
    recs = [recording(f"r{i}", 10.0 + i, REJECTS, (wind_refit(4.0 + 0.3 * i),)) for i in range(3)]
    dec, cands = on_the_set(recs, {"wind": [d.refits[0] for d in recs]})
    j = JointDiagnosis(runs=tuple(d.run for d in recs), recordings=tuple(recs), candidates=cands,
                       test=nominal_test(recs, ALPHA), decision=dec, alpha=ALPHA, k_se=K_SE, confirm=2,
                       key={"runs": ["a"]})
    back = from_json(JointDiagnosis, to_json(j))
    assert back == j and back.verdict == "missing-effect" and to_json(j)["type"] == "JointDiagnosis"
    assert back.nominal == pytest.approx(33.0) and back.named_by("wind") == (0, 1, 2)


def uninformed(refit):
    """``refit`` as a motion that does not inform its effect leaves it: the effect's 90% interval about the prior's."""
    return replace(refit, estimates=tuple(replace(e, width_ratio=0.9, may_be_off=True) for e in refit.estimates))


def rig(lift_refit, wipe_refit, lift_nominal=4.0, wipe_nominal=10.0):
    """A rig's two motions: a lift that fits (its nominal check does not reject) and a wipe that misfits, with the
    wind refitted on both; the candidate by the rig's rule and the rig's decision."""
    lift = recording("lift", lift_nominal, LOW)
    wipe = recording("wipe", wipe_nominal, REJECTS, (wipe_refit,))
    cand = rig_candidate("wind", [lift, wipe], [lift_refit, wipe_refit], ALPHA, K_SE)
    return decide_joint(nominal_test([lift, wipe], ALPHA), ranked([cand]), K_SE, rig=True), ranked([cand])[0]


def test_a_rig_names_an_effect_that_only_its_second_motion_informs():
    """Across motions the paired standard error would be about the gain itself (one motion's gain among null ones:
    z about 1); the rig's rule sums the gains of the motions that inform the effect with their own standard errors."""
    dec, wind = rig(uninformed(wind_refit(4.05)), wind_refit(4.0))
    assert wind.rig and wind.informs == (False, True) and wind.informed_by == (1,)
    assert wind.gain.difference == pytest.approx(6.0) and wind.gain.se == pytest.approx(math.hypot(0.2, 0.2))
    assert wind.on.on == (True,) and wind.on.p_value == pytest.approx(0.1) and wind.on.switched_on
    assert wind.worse_on == () and wind.fails(K_SE) == () and dec.verdict == "missing-effect"
    assert dec.named == ("wind",)
    # the paired rule on the same two gains: one standard error, and two recordings are too few for it
    assert Gain.paired([6.0, -0.05]).z < 1.1
    with pytest.raises(SoftsbiError, match="needs 3 recordings or more"):
        decide_joint(nominal_test([recording("a", 4.0, LOW), recording("b", 10.0, REJECTS)], ALPHA), [], K_SE)


def test_a_rig_does_not_name_an_effect_a_motion_contradicts_or_that_informing_motions_leave_off():
    # the wind makes the lift clearly worse (3.5 of its own standard errors): contradicted there
    dec, wind = rig(uninformed(wind_refit(5.0)), wind_refit(4.0))
    assert wind.worse_on == (0,) and wind.fails(K_SE) == ("not contradicted",) and dec.named == ()
    # both motions inform it, one switches it on: 1 of 2 is within chance (P = 0.19 > 0.10)
    dec, wind = rig(wind_refit(3.5, on=False), wind_refit(4.0))
    assert wind.informs == (True, True) and wind.on.count == 1
    assert wind.on.p_value == pytest.approx(0.19) and wind.fails(K_SE) == ("switched on",) and dec.named == ()
    # on a trained task the task's report decides what the motion informs, not the recording's refit
    lift = replace(recording("lift", 4.0, LOW), uninformed={"wind": 0.9})
    assert not informed_by_recording("wind", lift, replace(wind_refit(4.0), amortised=True))
    assert informed_by_recording("wind", recording("lift", 4.0, LOW), replace(uninformed(wind_refit(4.0)),
                                                                                   amortised=True))
    with pytest.raises(SoftsbiError, match="rig's diagnosis across its motions needs 2 recordings"):
        check_recordings(1, rig=True)
    check_recordings(2, rig=True)
