"""The words and table of a task's diagnosis across its recordings (softsbi.report.joint_text), rendered from fixed,
hand-built results: any change of wording shows here as a diff."""
from __future__ import annotations

from result_helpers import joint, recording, wind_refit
from softsbi.core.results.design import undecided_candidates
from softsbi.core.results.joint import JointDiagnosis
from softsbi.report.joint_text import (JOINT_COLUMNS, RECORDING_COLUMNS, joint_rows, joint_summary, joint_text,
                                       recording_rows)
from softsbi.workflows.criticism.joint_decide import decide_joint, joint_candidate, nominal_test, ranked

REJECTS, ACCEPTS, LOW = joint(0, 0), joint(120, 150), joint(20, 40)


def joint_diagnosis(recs, refits_by_effect) -> JointDiagnosis:
    cands = ranked([joint_candidate(e, recs, rs, 0.05) for e, rs in refits_by_effect.items()])
    test = nominal_test(recs, 0.05)
    return JointDiagnosis(runs=tuple(d.run for d in recs), recordings=tuple(recs), candidates=cands, test=test,
                          decision=decide_joint(test, cands, 2.0), alpha=0.05, k_se=2.0, confirm=2)


#: five lifts that all lack the wind (each names it alone), and the damping refitted on all of them too
NAMED = joint_diagnosis(
    [recording(f"lift{i}", 10.0 + i, REJECTS, (wind_refit(4.0 + 0.5 * i, wind_y=0.6 + 0.1 * i),)) for i in range(5)],
    {"wind": [wind_refit(4.0 + 0.5 * i, wind_y=0.6 + 0.1 * i) for i in range(5)],
     "extra-damping": [wind_refit(9.0 + i * 0.9, test=joint(1, 2) if i < 3 else None, on=i == 0,
                                  effect="extra-damping") for i in range(5)]})
#: one lift with the wind among four that fit: the set is misfit, and the wind's gain is one recording's
ONE = joint_diagnosis(
    [recording("lift0", 10.0, REJECTS, (wind_refit(4.0),))] + [recording(f"lift{i}", 4.0, LOW) for i in range(1, 5)],
    {"wind": [wind_refit(4.0)] + [wind_refit(4.1 + 0.15 * i) for i in range(1, 5)]})
#: controls, one of which rejects alone
CONTROLS = joint_diagnosis([recording("c0", 10.0, REJECTS, (wind_refit(4.0),))]
                           + [recording(f"c{i}", 4.0, ACCEPTS) for i in range(1, 5)], {})


def test_the_table_has_a_row_per_candidate_and_each_recordings_own_verdict_beside_it():
    assert JOINT_COLUMNS[:3] == ["candidate", "summed score [sd]", "gain over nominal [sd]"]
    assert joint_rows(NAMED) == [
        ["wind", "25", "35 ± 1.8 (z 19.8)", "best", "5 of 5", "p = 1", "5 of 5 (p = 1e-05)",
         "wind_y 0.8 (0.6 to 1) m/s", "5 of 5", "named"],
        # its gains 1.0-1.4 barely spread: the Monte-Carlo standard error of the sum (0.63) is the floor
        ["extra-damping", "54", "6 ± 0.63 (z 9.5)", "29 ± 1.4 (z 20.5)", "2 of 5 (#4, #5)", "p = 0.009",
         "1 of 5 (p = 0.41)", "wind_y 0.8 (0.8 to 0.8) m/s", "-", "not named: misfit on the set, not switched on"]]
    assert RECORDING_COLUMNS == ["#", "recording", "check p", "own verdict", "named alone"]
    assert recording_rows(ONE) == [["#1", "lift0", "p <= 2/201", "missing-effect", "wind"]] + [
        [f"#{i + 1}", f"lift{i}", "p = 0.21", "nothing-missing", "-"] for i in range(1, 5)]
    assert joint_rows(ONE)[0][-2:] == ["1 of 5 (#1)", "not named: gain within --k-se"]


def test_the_verdict_names_the_effect_with_the_three_criteria():
    assert joint_summary(NAMED) == (
        "Missing effect for the task: wind. Summed over the 5 recordings, its refits lower the summary energy score "
        "by 35 sd, 19.8 standard errors paired over recordings (more than 2); Fisher's combined test of its refits' "
        "checks gives p = 1 > 0.05 (adequate alone on 5 of 5); the data switch it on on 5 of 5 recordings (binomial "
        "p = 1e-05 <= 0.05 against 10% by chance). Its parameters across the recordings: wind_y 0.8 (0.6 to 1) m/s "
        "(median and range).")
    assert joint_text(NAMED)[1].startswith("Rule: the 5 recordings are diagnosed one by one;")


def test_one_recordings_gain_is_not_the_tasks_and_the_verdict_says_which_criterion_failed():
    assert ONE.verdict == "misspecified-unexplained"
    assert joint_summary(ONE) == (
        "Misspecified, unexplained for the task: Fisher's combined test of the 5 nominal fits' checks gives p = 0.016 "
        "<= 0.05, and no candidate of wind meets the three criteria. wind: its summed gain 4.1 sd is 0.6 standard "
        "errors paired over recordings (not more than 2).")


def test_controls_say_nothing_missing_and_name_the_recording_that_misfits_alone():
    assert CONTROLS.verdict == "nothing-missing" and joint_rows(CONTROLS) == []
    assert joint_summary(CONTROLS) == (
        "Nothing missing for the task: Fisher's combined test of the 5 nominal fits' checks gives p = 0.51 > 0.05. On "
        "its own, c0's diagnosis says missing-effect (wind): a misfit of that recording, which the set does not "
        "share.")


def test_a_candidate_that_gains_on_every_recording_but_stays_misfit_explains_a_part():
    recs = [recording(f"lift{i}", 10.0 + i, REJECTS, (wind_refit(4.0 + 0.5 * i, test=joint(1, 2)),)) for i in range(5)]
    j = joint_diagnosis(recs, {"wind": [d.refits[0] for d in recs]})
    assert j.decision.partial == ("wind",) and joint_rows(j)[0][-1] == "explains a part"
    assert joint_summary(j).endswith(
        "and no candidate of wind meets the three criteria. wind explains a part: it lowers the summed summary energy "
        "score most, by 35 ± 1.8 sd (z 19.8), and the data switch it on, but Fisher's combined test of its refits' "
        "checks rejects (p = 2.4e-05 <= 0.05).")


def test_a_rejecting_set_names_the_candidates_its_task_cannot_identify_and_controls_do_not():
    from dataclasses import replace

    from softsbi.report.text import uninformed_words
    blind = {"heavy-hem": 0.96}

    def with_blind(j):
        return replace(j, recordings=tuple(replace(d, uninformed=blind) for d in j.recordings))
    text = joint_text(ONE, "runs/lifts")
    blind_text = joint_text(with_blind(ONE), "runs/lifts")
    assert blind_text[:3] == text[:2] + [uninformed_words(blind)] and len(blind_text) == len(text) + 1
    assert "(2 unexplained; 1 not informed by these tasks)" in blind_text[-1]
    assert joint_text(with_blind(CONTROLS)) == joint_text(CONTROLS)
    # a misfit set leaves candidates undecided, and its last line says how to choose the motion to record next
    family = [c.effect for c in ONE.recordings[0].ranking if not c.generic]
    assert ONE.verdict == "misspecified-unexplained" and family
    assert text[-1] == (f"Undecided: {len(family)} candidate{'s' if len(family) > 1 else ''} ({len(family)} "
                        f"unexplained). `softsbi design runs/lifts` ranks the motions the object supports by how well "
                        f"one more recording of each would inform them (seconds from trained tasks, a few minutes of "
                        f"simulation otherwise).")
    assert undecided_candidates(with_blind(ONE), [])["heavy-hem"] == "not informed by these tasks"
    assert not undecided_candidates(with_blind(CONTROLS), family)  # the set fits: nothing to decide


def test_a_rig_leaves_uninformed_only_what_no_recordings_task_informs():
    from dataclasses import replace
    recs = (replace(recording("lift", 10.0, REJECTS), uninformed={"heavy-hem": 0.96, "sticky-patch": 0.93}),
            replace(recording("wipe", 10.0, REJECTS), uninformed={"heavy-hem": 0.7}))
    test = nominal_test(list(recs), 0.05)
    j = JointDiagnosis(runs=("runs/lift", "runs/wipe"), recordings=recs, candidates=(), test=test,
                       decision=decide_joint(test, [], 2.0, rig=True), alpha=0.05, k_se=2.0, confirm=2,
                       scenarios=("lift", "wipe"))
    assert j.uninformed == {"heavy-hem": 0.7}  # the wipe informs the sticky patch, neither the hem
    assert undecided_candidates(j, ["sticky-patch"]) == {"sticky-patch": "unexplained",
                                                         "heavy-hem": "not informed by these tasks"}


def test_an_empty_candidates_table_is_one_sentence_saying_why(capsys):
    """The empty joint table printed a header with no row and no sentence."""
    from softsbi.cli.diagnose_cmd import print_joint_diagnosis
    from softsbi.cli.output import Output
    print_joint_diagnosis(Output(), CONTROLS)
    out = capsys.readouterr().out
    assert "Candidate effects refitted on every recording" not in out
    assert ("No candidate was refitted on every recording: the recordings' combined check does not reject (Fisher's "
            "method, p = 0.51 > 0.05), so nothing is missing for the task.") in out
    assert "Each recording's own diagnosis" in out  # the recordings' table stays


def test_a_rigs_verdict_says_which_motions_inform_the_effect_and_gives_the_combined_interval():
    from dataclasses import replace
    from softsbi.core.results import Estimate
    from softsbi.workflows.criticism.joint_decide import rig_candidate
    lift_refit = wind_refit(4.05)
    lift_refit = replace(lift_refit, estimates=tuple(replace(e, width_ratio=0.9, may_be_off=True)
                                                     for e in lift_refit.estimates))
    wipe_refit = wind_refit(4.0)
    recs = [recording("lift", 4.0, LOW), recording("wipe", 10.0, REJECTS, (wipe_refit,))]
    cand = rig_candidate("wind", recs, [lift_refit, wipe_refit], 0.05, 2.0)
    cand = replace(cand, combined=(Estimate(name="wind_y", unit="m/s", mean=0.8, q05=0.55, q95=1.05,
                                            effect="wind"),))
    test = nominal_test(recs, 0.05)
    j = JointDiagnosis(runs=("runs/lift", "runs/wipe"), recordings=tuple(recs), candidates=(cand,), test=test,
                       decision=decide_joint(test, [cand], 2.0, rig=True), alpha=0.05, k_se=2.0, confirm=2,
                       scenarios=("lift", "wipe"))
    assert j.rig and j.verdict == "missing-effect"
    assert joint_summary(j) == (
        "Missing effect for the rig: wind. Summed over the 1 recording whose motion informs it, its refits lower the "
        "summary energy score by 6 sd, 21.2 standard errors of the recordings' own scores (more than 2); no recording scores worse with it; Fisher's combined test of its "
        "refits' checks gives p = 1 > 0.05 (adequate alone on 2 of 2); the data switch it on on 1 of 1 recordings "
        "(binomial p = 0.1 <= 0.1 against 10% by chance). Its parameters across the recordings: wind_y 0.8 (0.8 to "
        "0.8) m/s; combined: wind_y 0.8 (90% 0.55 to 1.05) m/s (median and range; combined: the product of the "
        "informing recordings' marginal posteriors, assuming the recordings independent given one value of the "
        "parameter for the rig).")
    assert joint_text(j)[1].startswith("Rule for a rig's 2 motions (lift, wipe): the 2 recordings are diagnosed")
    assert joint_rows(j)[0][6] == "1 of 1 (p = 0.1)" and joint_rows(j)[0][-1] == "named"
