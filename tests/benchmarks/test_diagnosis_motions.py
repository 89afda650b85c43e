"""The motions split (benchmarks/diagnosis_motions.py) on hand-built rows: its cases are fresh and of its own counts,
each case scored strictly after the lift and after its last motion, design's first motion counted as deciding only
when nothing is left undecided after it, and a failed case counted wrong at every stage (no fit, no simulation)."""
from __future__ import annotations

import itertools
import sys

from toy_helpers import REPO

sys.path.insert(0, str(REPO))
from benchmarks import diagnosis as bench
from benchmarks import diagnosis_motions as motions
from benchmarks import diagnosis_protocol as proto

_IDS = itertools.count()


def step(motion, verdict="nothing-missing", named=(), undecided=(), seconds=60.0):
    return {"motion": motion, "verdict": verdict, "named": list(named), "alternatives": [], "p_value": 0.3,
            "gain": None, "undecided": dict.fromkeys(undecided, "unexplained"), "seconds": seconds}


def row(label, *steps, status="ok"):
    return {"id": f"motions-{next(_IDS)}", "label": label, "status": status, "steps": list(steps)}


def test_the_split_is_fresh_and_has_its_own_counts():
    labels = [motions.make_case(i)["label"] for i in range(motions.N_CASES)]
    assert motions.N_CASES == 40 + 4 * len(proto.EFFECTS) + 8 == 116
    assert labels.count("control") == 40 and labels.count("other-engine") == 8
    assert all(labels.count(e) == 4 for e in proto.EFFECTS)
    # no case's cloth is one of the diagnosis splits' (other seed streams)
    first = {tuple(sorted(bench.make_case(s, i)["truth"].items())) for s in ("dev", "test") for i in range(20)}
    assert not first & {tuple(sorted(motions.make_case(i)["truth"].items())) for i in range(20)}


def test_each_case_is_scored_after_the_lift_and_after_its_last_motion():
    rows = [
        row("control", step("lift")),
        # a false alarm on the lift that the rig clears
        row("control", step("lift", "misspecified-unexplained", undecided=["wind"]), step("fling")),
        # a sticky patch the lift cannot inform: the fling names it, and nothing is left undecided
        row("sticky-patch", step("lift", "misspecified-unexplained", undecided=["sticky-patch", "wind"]),
            step("fling", "missing-effect", ["sticky-patch"])),
        # a wind the lift names right at once
        row("wind", step("lift", "missing-effect", ["wind"])),
        # a hem named as another effect after two motions, still undecided after the first
        row("heavy-hem", step("lift", "misspecified-unexplained", undecided=["heavy-hem"]),
            step("fling", "misspecified-unexplained", undecided=["heavy-hem"]),
            step("wipe", "missing-effect", ["wind"])),
        row("other-engine", step("lift", "misspecified-unexplained", undecided=["wind"]),
            step("fling", "misspecified-unexplained", undecided=["wind"]),
            step("wipe", "misspecified-unexplained", undecided=["wind"])),
        row("air-drag", status="error")]
    s = motions.summary(rows, informed=["wind"])
    assert s["cases"] == 7 and s["errors"] == 1
    lift, last = s["lift"], s["last"]
    assert (lift["false_alarms"]["k"], lift["false_alarms"]["n"]) == (1, 2)
    assert (last["false_alarms"]["k"], last["false_alarms"]["n"]) == (0, 2)
    assert (lift["named_right"]["k"], lift["named_right"]["n"]) == (1, 4)  # the wind; the error counts wrong
    assert (last["named_right"]["k"], last["named_right"]["n"]) == (2, 4)
    assert (lift["informed_right"]["k"], lift["informed_right"]["n"]) == (1, 1)
    assert lift["unexplained"]["k"] == 2 and last["unexplained"]["k"] == 0
    assert last["wrong_effect"]["k"] == 1 and lift["wrong_effect"]["k"] == 0
    assert lift["other_engine"]["k"] == 1 and last["other_engine"]["k"] == 1
    assert last["by_effect"]["sticky-patch"] == [1, 1] and lift["by_effect"]["sticky-patch"] == [0, 1]
    assert last["confusion"]["heavy-hem"] == {"wind": 1} and last["confusion"]["air-drag"] == {"error": 1}
    # design's first advised motion decided when nothing was undecided after it: 2 of the 4 that took one
    assert (s["design"]["k"], s["design"]["n"]) == (2, 4) and s["design"]["advised"] == {"fling": 4}
    assert s["steps"] == {1: 2, 2: 2, 3: 2} and s["seconds"] == {"lift": 60.0, "fling": 60.0, "wipe": 60.0}
    page = motions.report(s)
    first = page["tables"][0]["rows"]
    assert first[0] == ["false alarms (controls)", "1 of 2 (0.50; 95% 0.01-0.99)", "0 of 2 (0.00; 95% 0.00-0.84)",
                        "<= 1 of 40; <= 1 of 40"]
    assert first[-1] == ["design's first motion decided", "-", "2 of 4 (0.50; 95% 0.07-0.93)", ">= 0.60"]
    assert page["notes"][0].startswith("7 cases (1 failed, counted wrong); motions recorded per case: 1 in 2, 2 in 2, "
                                       "3 in 2; second motions advised: fling 4.")
