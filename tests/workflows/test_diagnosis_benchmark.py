"""The diagnosis suite (benchmarks/diagnosis.py): the split's cases, the scoring rule and the summary (no
simulation)."""
from __future__ import annotations

import sys

from toy_helpers import REPO

sys.path.insert(0, str(REPO))
from benchmarks import diagnosis as bench  # noqa: E402


def test_cases_are_fixed_by_split_and_index_and_cycle_through_every_label():
    a, b = bench.make_case("test", 7), bench.make_case("test", 7)
    assert a == b and a["id"] == "test-7" and a != bench.make_case("dev", 7)
    labels = [bench.make_case("test", i)["label"] for i in range(len(bench.CYCLE))]
    assert labels.count("control") == 6 and labels.count("other-engine") == 1
    assert sorted(set(labels) - {"control", "other-engine"}) == sorted(bench.EFFECTS)
    for i in range(len(bench.CYCLE)):
        c = bench.make_case("test", i)
        if c["magnitude"] is not None:  # from the effect's detection threshold to 1
            assert bench.THRESHOLDS.get(c["label"], bench.DEFAULT_THRESHOLD) <= c["magnitude"] <= 1


def test_the_scoring_rule():
    assert bench.right("control", "nothing-missing", [], [])
    assert not bench.right("control", "missing-effect", ["wind"], [])
    assert bench.right("other-engine", "misspecified-unexplained", [], [])
    assert bench.right("wind", "missing-effect", ["wind"], [])
    assert bench.right("wind", "missing-effect", ["air-drag"], [["wind"]])  # listed as indistinguishable
    assert not bench.right("wind", "missing-effect", ["wind", "air-drag"], [])  # one effect too many
    assert not bench.right("wind", "misspecified-unexplained", [], [])


def test_the_summary_counts_false_alarms_and_compares_the_old_rule_on_the_same_cases():
    rows = [{"label": "control", "verdict": "nothing-missing", "named": [], "right": True, "magnitude": None,
             "seconds": 10, "old": {"verdict": "nothing-missing", "right": True}} for _ in range(19)]
    rows.append({"label": "control", "verdict": "missing-effect", "named": ["wind"], "right": False, "magnitude": None,
                 "seconds": 10, "old": {"verdict": "nothing-missing", "right": True}})
    rows.append({"label": "wind", "verdict": "missing-effect", "named": ["wind"], "right": True, "magnitude": 0.8,
                 "score_nominal": 20.0, "score_named": 10.0, "seconds": 10,
                 "old": {"verdict": "misspecified-unexplained", "right": False}})
    rows.append({"id": "x", "label": "wind", "error": "boom"})
    s = bench.summary(rows)
    assert s["cases"] == 22 and s["failed"] == 1
    assert s["false_alarms"] == 1 and 0 < s["false_alarm_ci95"][0] < 0.05 < s["false_alarm_ci95"][1] < 0.3
    assert s["by_label"]["wind"]["right"] == 1 and s["by_label"]["wind"]["old_right"] == 0
    assert s["score_drop_median"] == 0.5 and s["detection_by_magnitude"]["0.75-1.00"] == [1, 1]
    assert s["confusion"]["control"] == {"nothing-missing": 19, "wind": 1}
    rep = bench.report(s, "test")
    assert "1 of 20 controls" in rep["notes"][0]
    assert ["wind", 1, 1, 1] == rep["tables"][0]["rows"][1][:4]
