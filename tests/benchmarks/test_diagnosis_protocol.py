"""The diagnosis suite's protocol (benchmarks/diagnosis.py, benchmarks/diagnosis_protocol.py) on hand-built rows: the
split's cases, strict scoring, settings recorded and pooled only when equal, error rows rerun and counted, the
threshold table, the acceptance figures, the split's minimums and the old rule on the same nominal fit (no fit and
no simulation: the fit, the diagnosis and the old checkout's process are stand-ins)."""
from __future__ import annotations

import itertools
import json
import re
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from toy_helpers import REPO

sys.path.insert(0, str(REPO))
from benchmarks import diagnosis as bench
from benchmarks import diagnosis_protocol as proto

#: settings of one protocol, as a row stores them (the real ones are tested in test_rows_record_commit_and_settings)
SETTINGS = {"fit": {"rounds": 3, "sims_per_round": 100, "proposal": "truncated"},
            "estimator_options": {"ensemble": 5, "recalibrate": True},
            "diagnose": {"alpha": 0.05, "k_se": 2.0, "confirm": 2, "n_null": 30, "max_null": 200},
            "cases": {"thresholds": dict(proto.THRESHOLDS), "placeholder": proto.DEFAULT_THRESHOLD}}


_IDS = itertools.count()


def row(label, verdict="nothing-missing", named=(), alternatives=(), p_value=0.5, **kw):
    """A stored row of a case with ``label`` and the diagnosis's ``verdict`` (a fresh case id)."""
    return {"id": kw.pop("id", f"test-{next(_IDS)}"), "label": label, "status": "ok", "verdict": verdict,
            "named": list(named), "alternatives": [list(a) for a in alternatives], "p_value": p_value,
            "magnitude": 0.8 if label in proto.EFFECTS else None, "seconds": 1.0, "commit": "abc", "settings": SETTINGS,
            **kw}


def test_cases_are_fixed_by_split_and_index_and_start_at_the_threshold_table():
    a, b = bench.make_case("test", 7), bench.make_case("test", 7)
    assert a == b and a["id"] == "test-7" and a != bench.make_case("dev", 7)
    labels = [bench.make_case("test", i)["label"] for i in range(len(proto.CYCLE))]
    assert labels.count("control") == 6 and labels.count("other-engine") == 1
    assert sorted(set(labels) - {"control", "other-engine"}) == sorted(proto.EFFECTS)
    i = proto.CYCLE.index("air-drag")  # no measured threshold: from the placeholder
    assert proto.THRESHOLDS["air-drag"] is None and bench.make_case("test", i)["magnitude"] >= proto.DEFAULT_THRESHOLD
    table = {**proto.THRESHOLDS, "air-drag": 0.95}
    assert bench.make_case("test", i, table)["magnitude"] >= 0.95


def test_scoring_is_strict_and_counts_indistinguishable_apart():
    assert proto.outcome("control", "nothing-missing", []) == "right"
    assert proto.outcome("control", "missing-effect", ["wind"]) == "wrong"
    assert proto.outcome("other-engine", "misspecified-unexplained", []) == "right"
    assert proto.outcome("wind", "missing-effect", ["wind"]) == "right"
    assert proto.outcome("wind", "missing-effect", "wind") == "right"  # a name alone, as older rows hold it
    assert proto.outcome("wind", "missing-effect", ["air-drag"], [["wind"]]) == "indistinguishable"
    assert proto.outcome("wind", "missing-effect", ["wind", "air-drag"]) == "wrong"
    assert proto.outcome("wind", "misspecified-unexplained", []) == "wrong"
    # a row stored under the lenient rule (right: True for a listed alternative) is scored again, strictly
    rows = [row("wind", "missing-effect", ["air-drag"], [["wind"]], right=True),
            row("wind", "missing-effect", ["wind"]), row("air-drag", "missing-effect", ["wind"], right=False)]
    s = proto.summary(rows, "test")
    assert s["by_label"]["wind"]["right"] == 1 and s["by_label"]["wind"]["indistinguishable"] == 1
    assert s["named_right"]["k"] == 1 and s["named_right"]["n"] == 3 and s["named_right"]["indistinguishable"] == 1
    table = proto.report(s, "test")["tables"][0]
    wind = table["rows"][[r[0] for r in table["rows"]].index("wind")]
    assert wind[table["columns"].index("right (this rule)")] == 1
    assert wind[table["columns"].index("listed indistinguishable")] == 1


def test_rows_record_commit_and_settings_and_errors_are_rerun(tmp_path, monkeypatch):
    calls, reason = [], "a simulation failed"

    def run_case(case, out, workers, old):
        calls.append(case["id"])
        if len(calls) == 1:
            raise RuntimeError(reason)
        return {**case, "status": "ok", "verdict": "nothing-missing", "named": [], "alternatives": [],
                "p_value": 0.3}

    monkeypatch.setattr(bench, "run_case", run_case)
    path = tmp_path / "rows.jsonl"
    bench.run("test", [0, 1], tmp_path, None, None, "cmd", path)
    rows = proto.read_rows(path)
    assert [r["status"] for r in rows] == ["error", "ok"] and reason in rows[0]["error"]
    for r in rows:  # every row: its commit and every setting that decides it
        assert r["commit"] and r["command"] == "cmd"
        st = r["settings"]
        assert st["estimator_options"]["recalibrate"] is True and st["estimator_options"]["ensemble"] == 5
        assert (st["fit"]["rounds"], st["fit"]["sims_per_round"], st["fit"]["proposal"]) == (3, 100, "truncated")
        assert {"alpha", "k_se", "confirm", "n_null", "max_null"} <= set(st["diagnose"])
        assert st["cases"]["thresholds"] == proto.THRESHOLDS
    s = proto.summary(rows, "test")
    assert s["errors"] == 1 and s["false_alarms"]["k"] == 1 and s["false_alarms"]["n"] == 2  # counted as wrong
    bench.run("test", [0, 1], tmp_path, None, None, "cmd", path)  # the error is run again, the done case is not
    assert calls == ["test-0", "test-1", "test-0"]
    s = proto.summary(proto.read_rows(path), "test")
    assert s["cases"] == 2 and s["errors"] == 0 and s["reruns"] == 1 and s["false_alarms"]["k"] == 0
    bench.run("test", [0, 1], tmp_path, None, None, "cmd", path)
    assert len(calls) == 3


def test_a_run_refuses_a_rows_file_of_other_settings_before_any_case(tmp_path, monkeypatch):
    monkeypatch.setattr(bench, "run_case", lambda *a: pytest.fail("a case ran"))
    path = tmp_path / "rows.jsonl"
    current = bench.settings()
    recal_off = {**current, "estimator_options": {**current["estimator_options"], "recalibrate": False}}
    path.write_text(json.dumps(row("control", id="test-0", settings=recal_off)) + "\n")
    with pytest.raises(SystemExit, match=r"--results .*differ in estimator_options\.recalibrate"):
        bench.run("test", [0, 1], tmp_path, None, None, "cmd", path)
    legacy = {k: v for k, v in row("control", id="test-0").items() if k not in ("settings", "status")}
    path.write_text(json.dumps(legacy) + "\n")
    with pytest.raises(SystemExit, match="1 rows record none"):
        bench.run("test", [1], tmp_path, None, None, "cmd", path)
    bench.run("test", [0], tmp_path, None, None, "cmd", path)  # nothing to run: no refusal
    path.write_text(json.dumps(row("control", id="test-0", settings=current)) + "\n")
    with pytest.raises(SystemExit, match=r"differ in cases\.thresholds\.air-drag"):  # another table, another setting
        bench.run("test", [1], tmp_path, None, None, "cmd", path, {**proto.THRESHOLDS, "air-drag": 0.7})


def test_errors_count_as_wrong_and_the_summary_says_how_many():
    rows = [row("control"), row("wind", "missing-effect", ["wind"]),
            {"id": "test-x", "label": "wind", "status": "error", "error": "boom", "commit": "abc",
             "settings": SETTINGS}]
    s = proto.summary(rows, "test")
    assert s["errors"] == 1 and s["by_label"]["wind"] | {"right_ci95": None} == {
        "n": 2, "errors": 1, "right": 1, "right_ci95": None, "indistinguishable": 0, "detected": 1}
    assert s["named_right"]["n"] == 2 and s["named_right"]["rate"] == 0.5
    assert s["confusion"]["wind"] == {"wind": 1, "error": 1}


def test_rows_of_differing_settings_are_not_pooled():
    changed = {**SETTINGS, "estimator_options": {"ensemble": 5, "recalibrate": False}}
    rows = [row("control"), row("control", settings=changed)]
    s = proto.summary(rows, "test")
    assert "estimator_options.recalibrate" in s["refused"] and "by_label" not in s
    rep = proto.report(s, "test")
    assert rep == {"tables": [], "notes": [s["refused"]]} and "\n" not in s["refused"]
    legacy = {**{k: v for k, v in row("control").items() if k not in ("settings", "status")}, "commit": "f00d"}
    # a row that stored no settings is refused, naming its commit
    assert legacy["commit"] in proto.summary([row("control"), legacy], "test")["refused"]
    assert proto.summary([row("control"), row("control", commit="def")], "test").get("refused") is None


def test_rows_stored_before_the_protocol_summarise_with_their_settings_unknown():
    legacy = [{"id": f"test-{i}", "label": lab, "verdict": v, "named": n, "alternatives": [], "partial": [],
               "p_value": p, "right": True, "magnitude": m, "seconds": 30.0, "commit": "738c2b9c42"}
              for i, (lab, v, n, p, m) in enumerate([("control", "nothing-missing", [], 1.0, None),
                                                     ("wind", "missing-effect", ["wind"], 0.0, 0.7)])]
    s = proto.summary(legacy, "test")
    assert s["settings"] == "unknown" and set(s["thresholds"].values()) == {"unknown"} and s["errors"] == 0
    assert proto.report(s, "test")["notes"]
    other_commit = {**legacy[1], "id": "test-9", "commit": "0000000000"}
    assert "refused" in proto.summary([*legacy, other_commit], "test")


def test_threshold_table_from_a_file(tmp_path):
    f = tmp_path / "t.json"
    f.write_text(json.dumps({**proto.THRESHOLDS, "air-drag": 0.6}))
    assert proto.load_thresholds(f)["air-drag"] == 0.6 and proto.load_thresholds(f)["sticky-patch"] is None
    for bad, what in [({k: v for k, v in proto.THRESHOLDS.items() if k != "wind"}, "missing ['wind']"),
                      ({**proto.THRESHOLDS, "magnet": 0.3}, "unknown ['magnet']"),
                      ({**proto.THRESHOLDS, "wind": 1.5}, "[0, 1)"), ([0.3], "JSON object")]:
        f.write_text(json.dumps(bad))
        with pytest.raises(SystemExit, match=r"--thresholds .*" + re.escape(what)):
            proto.load_thresholds(f)
    s = proto.summary([row("air-drag", "missing-effect", ["air-drag"]), row("wind", "missing-effect", ["wind"])],
                      "test")
    assert s["thresholds"]["air-drag"] == "unmeasured" and s["thresholds"]["wind"] == 0.36
    table = proto.report(s, "test")["tables"][0]
    cells = {r[0]: r[table["columns"].index("threshold")] for r in table["rows"]}
    assert cells == {"air-drag": f"unmeasured ({proto.DEFAULT_THRESHOLD:g} placeholder)", "wind": "0.36"}


def test_acceptance_figures_against_the_targets():
    p = (np.arange(60) + 0.5) / 60  # uniform control p-values
    ctl = [row("control", p_value=float(x)) for x in p[:-2]]
    ctl += [row("control", "missing-effect", ["wind"], p_value=0.001) for _ in range(2)]
    eff = [row(e, "missing-effect", [e]) for e in proto.EFFECTS for _ in range(9)]
    eff += [row(e, "nothing-missing") for e in proto.EFFECTS]
    oe = [row("other-engine", "misspecified-unexplained") for _ in range(10)]
    s = proto.summary(ctl + eff + oe, "test")
    ci = stats.binomtest(2, 60).proportion_ci(method="exact")
    assert s["false_alarms"]["k"] == 2 and s["false_alarms"]["ci95"] == pytest.approx([ci.low, ci.high])
    acc = s["acceptance"]
    assert acc["false_alarms"]["pass"] is False  # 3.3% but its upper bound is 11.5%
    assert s["ks"]["n"] == 60 and acc["control_p_uniform"]["pass"] is True
    assert s["named_right"]["rate"] == 0.9 and acc["named_right"]["pass"] is True
    assert s["other_engine"]["rate"] == 1.0 and acc["other_engine"]["pass"] is True
    assert s["minimums"]["met"] is True
    ctl2 = [row("control", p_value=1.0) for _ in range(100)]  # no false alarm, but p-values not uniform
    acc2 = proto.summary(ctl2, "test")["acceptance"]
    assert acc2["false_alarms"]["pass"] is True and acc2["control_p_uniform"]["pass"] is False
    assert acc2["named_right"]["pass"] is None and acc2["other_engine"]["pass"] is None


def test_the_split_size_reaches_the_minimums():
    assert proto.cases_for_minimums() == 180 and bench.FULL == {"cases": "0:180"}
    labels = [proto.CYCLE[i % len(proto.CYCLE)] for i in range(180)]
    assert labels.count("control") >= 60 and labels.count("other-engine") >= 10
    assert min(labels.count(e) for e in proto.EFFECTS) >= 10
    s = proto.summary([row("control") for _ in range(59)] + [row("other-engine") for _ in range(10)], "test")
    assert s["minimums"]["short"]["control"] == [59, 60] and s["minimums"]["short"]["wind"] == [0, 10]
    assert s["minimums"]["met"] is False and "other-engine" not in s["minimums"]["short"]


def _diagnosis(verdict, named, alternatives=()):
    return types.SimpleNamespace(
        verdict=verdict, decision=types.SimpleNamespace(named=named if isinstance(named, str) else tuple(named),
                                                        alternatives=tuple(alternatives),
                                                        partial=()),
        test=types.SimpleNamespace(p_value=0.01, n_null=30), refits=(), nominal=None, refit=lambda e: None)


def test_the_old_rule_diagnoses_a_copy_of_the_same_nominal_fit(tmp_path, monkeypatch):
    seen = {}

    def run_fit(run_dir, rec, cfg):
        (run_dir / "run.zarr").mkdir(parents=True)
        (run_dir / "report.json").write_text('{"fit": 1}')
        (run_dir / "check.json").write_text("{}")  # left by an earlier diagnosis of this fit: not copied

    def diagnose_run(run_dir, **kw):
        seen["new"], seen["kw"] = Path(run_dir), kw
        (Path(run_dir) / "diagnosis.json").write_text("{}")
        return _diagnosis("missing-effect", ["wind"])

    def fake_run(cmd, **kw):
        if cmd[0] == "git":
            return subprocess.CompletedProcess(cmd, 0, "0ldc0ffee0\n", "")
        run = Path(cmd[3])
        seen["old"], seen["env"], seen["files"] = run, kw["env"]["PYTHONPATH"], sorted(p.name for p in run.iterdir())
        out = {"verdict": "missing-effect", "named": ["air-drag"], "alternatives": [["wind"]], "p_value": 0.02}
        return subprocess.CompletedProcess(cmd, 0, "ROW " + json.dumps(out) + "\n", "")

    monkeypatch.setattr(bench, "run_fit", run_fit)
    monkeypatch.setattr(bench, "diagnose_run", diagnose_run)
    monkeypatch.setattr(bench, "measurement", lambda case: None)
    monkeypatch.setattr(bench.subprocess, "run", fake_run)
    case = {"id": "test-6", "index": 6, "label": "wind", "magnitude": 0.8}
    r = bench.run_case(case, tmp_path / "runs", None, tmp_path / "old-checkout")
    assert seen["new"] == tmp_path / "runs" / "test-6" / "nominal"
    assert seen["old"] == (tmp_path / "runs" / "test-6" / "old-rule").resolve() and seen["old"] != seen["new"]
    assert seen["files"] == ["report.json", "run.zarr"] and seen["env"] == str((tmp_path / "old-checkout").resolve())
    assert seen["kw"]["effects"] == proto.EFFECTS and seen["kw"]["settings"].k_se == bench.DIAGNOSE["k_se"]
    assert (r["outcome"], r["named"]) == ("right", ["wind"])
    assert (r["old"]["verdict"], r["old"]["named"], r["old"]["commit"]) == ("missing-effect", ["air-drag"],
                                                                          "0ldc0ffee0")
    rows = [{**row("wind"), **{k: r[k] for k in ("verdict", "named", "alternatives", "old")}},
            row("control", old={"verdict": "nothing-missing", "named": [], "commit": "0ldc0ffee0"}),
            row("control", old={"error": "ImportError", "commit": "0ldc0ffee0"})]
    s = proto.summary(rows, "test")
    o = s["old"]
    assert (o["n"], o["agree"], o["new_right"]["k"], o["old_right"]["k"], o["not_shared"]) == (2, 1, 2, 1, 1)
    assert s["by_label"]["wind"]["old_right"] == 0 and s["by_label"]["control"]["old_n"] == 1
    rows.append(row("control", old={"verdict": "nothing-missing", "named": [], "commit": "another"}))
    assert "refused" in proto.summary(rows, "test")["old"]


def test_the_old_rule_driver_reads_the_old_checkouts_diagnosis(monkeypatch, capsys):
    calls = {}

    def diagnose_run(run, effects, workers):
        calls.update(run=run, effects=effects, workers=workers)
        return _diagnosis("missing-effect", "wind", ["air-drag"])  # an older decision's shapes: a name, names

    monkeypatch.setitem(sys.modules, "softsbi.workflows.criticism.diagnose", types.SimpleNamespace(diagnose_run=diagnose_run))
    monkeypatch.setattr(sys, "argv", ["-c", "runs/x/old-rule", json.dumps(proto.EFFECTS), "2"])
    exec(bench.OLD_DRIVER, {})
    out = json.loads(capsys.readouterr().out.split("ROW ", 1)[1])
    assert calls == {"run": "runs/x/old-rule", "effects": proto.EFFECTS, "workers": 2}
    assert out == {"verdict": "missing-effect", "named": ["wind"], "alternatives": [["air-drag"]], "p_value": 0.01}
