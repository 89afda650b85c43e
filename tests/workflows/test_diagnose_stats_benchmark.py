"""A tiny version of benchmarks/diagnose_stats.py: deterministic cases, resumable results, summary."""
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
_path = Path(__file__).resolve().parents[2] / "benchmarks" / "diagnose_stats.py"
_spec = importlib.util.spec_from_file_location("diagnose_stats", _path)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def test_cases_are_deterministic_and_cover_controls_and_every_effect():
    a = [bench.make_case("mujoco", 0, i) for i in range(10)]
    b = [bench.make_case("mujoco", 0, i) for i in range(10)]
    assert a == b
    assert [c["truth_label"] for c in a[:5]] == ["control", "wind", "air-drag", "extra-damping", "grip-compliance"]
    assert a[0]["magnitude"] is None and all(0.1 <= c["magnitude"] <= 1.0 for c in a[1:5])
    assert bench.make_case("mujoco", 1, 1)["truth"] != a[1]["truth"]
    # the hidden effect's parameter moved from its nominal value by the magnitude's fraction of the range
    wind = a[1]
    u = [abs(wind["truth"][k]) / 2.0 for k in ("wind_x", "wind_y")]
    assert u == pytest.approx([wind["magnitude"]] * 2)
    drag = a[2]
    assert drag["truth"]["air_density"] == pytest.approx(6.0 * drag["magnitude"])
    # cross-engine cases: data from pybullet-massspring at its own random truths, no named hidden effect
    x = bench.make_case("cross-engine", 0, 0)
    assert x["truth_label"] == "other-engine" and x["magnitude"] is None
    assert bench.CORRECT_VERDICT["other-engine"] == "misspecified-unexplained"


def test_tiny_benchmark_runs_resumes_and_summarises(tmp_path):
    results = tmp_path / "r.jsonl"
    rows = bench.run_cases("toy", range(0, 2), results, tmp_path / "runs", seed=3, rounds=2, sims=120, n_null=30,
                           max_null=100, workers=1)
    assert [r["truth_label"] for r in rows] == ["control", "toy-wind"]
    assert all("error" not in r for r in rows), rows
    assert len(results.read_text().splitlines()) == 2
    assert bench.run_cases("toy", range(0, 2), results, tmp_path / "runs", seed=3, workers=1) == []  # resumed
    s = bench.summarise([json.loads(x) for x in results.read_text().splitlines()])
    assert s["controls"] == 1 and s["cases"] == 2
    fa = int(rows[0]["verdict"] != "nothing-missing")
    assert s["false_alarms"] == fa and s["false_alarm_rate"] == fa
    assert s["false_alarm_ci95"][0] <= s["false_alarm_rate"] <= s["false_alarm_ci95"][1]
    assert sum(sum(v.values()) for v in s["confusion"].values()) == 2
    assert s["confusion"]["toy-wind"] == {rows[1]["called"]: 1}
    assert sum(b["n"] for b in s["power"]["toy-wind"]) == 1
    md = bench.markdown(s, rows)
    assert "False alarms: " in md and "| control |" in md and rows[1]["misspecification_p_text"] in md
    for r in rows:
        assert r["verdict"] in ("nothing-missing", "missing-effect", "misspecified-unexplained")
        # check's joint test (omnibus and directional): never below its resolution 2 / (n + 1)
        assert r["test"] == "joint" and r["id"].endswith("-joint-s14") and r["n_summaries"] == 14
        assert r["misspecification_p"] >= 2 / (r["n_null"] + 1)
        assert r["misspecification_p"] == pytest.approx(min(1.0, 2 * min(r["omnibus_p"], r["directional_p"])))
    # the hidden effect's size in the data: the nominal model at the truth scores worse without the effect
    assert bench.add_effect_sizes(results, [tmp_path / "elsewhere", tmp_path / "runs"]) == 1
    assert bench.add_effect_sizes(results, [tmp_path / "runs"]) == 0  # stored: not measured again
    stored = [json.loads(x) for x in results.read_text().splitlines()]
    es = stored[1]["effect_size"]
    assert "effect_size" not in stored[0]  # a control has no hidden effect
    assert es["size_m"] == pytest.approx(es["without_m"] - es["with_m"]) and es["without_m"] > es["with_m"] > 0
    ps = bench.summarise(stored)["power_size"]["toy-wind"]
    assert sum(b["n"] for b in ps) == 1


def test_detection_threshold_over_the_effects_size_in_the_data():
    """Named correctly from 1 cm up: the curve over log10(size) reaches 90% between 0.3 and 3 cm, and every
    case above it was named; rows without a size are left out."""
    sizes = [0.05, 0.1, 0.2, 0.4, 0.7, 0.9, 1.2, 2.0, 4.0, 8.0]
    rows = [{"correct": s >= 1.0, "magnitude": 0.5, "effect_size": {"size_m": s / 100}} for s in sizes]
    t = bench.detection_threshold(rows + [{"correct": False, "magnitude": 0.5}], by="size")
    assert t["n"] == 10 and t["named_correctly"] == 4 and t["by"] == "size"
    assert 0.3 < t["m_level"] < 3.0 and t["above"] == t["above_named"] >= 3
    # never named: no threshold
    assert bench.detection_threshold([dict(r, correct=False) for r in rows], by="size")["m_level"] is None


def test_the_criterion_above_the_detection_threshold_counts_naming_where_the_misfit_is_detected():
    """Detected from magnitude 0.5 up but named in only half of those cases: the detection curve's threshold
    lies between 0.4 and 0.7 and the criterion above it reads about half named, where the naming curve never
    reaches 90%. A curve above the level over the whole range puts every case above it."""
    mags = np.linspace(0.1, 1.0, 10)
    rows = [{"magnitude": float(m), "verdict": "missing-effect" if m >= 0.5 else "nothing-missing",
             "correct": bool(m >= 0.5 and k % 2 == 0)} for k, m in enumerate(mags)]
    d = bench.detection_threshold(rows, outcome="detected")
    assert d["outcome"] == "detected" and d["detected"] == 6 and d["named_correctly"] == 3
    assert 0.4 < d["m_level"] < 0.7 and d["above"] == d["above_detected"] >= 5  # every case above it detected
    assert d["above_named"] <= d["above"] - 2  # ... but half of them named: the criterion fails
    assert bench.detection_threshold(rows)["m_level"] is None  # named in half: the naming curve stays below 90%
    # a hidden effect listed as indistinguishable from the (wrong) named one is counted apart, not as named
    rows[7].update(truth_label="grip-compliance", alternatives=["grip-compliance"])
    rows[9].update(truth_label="grip-compliance", alternatives=["wind"])
    d = bench.detection_threshold(rows, outcome="detected")
    assert d["above_alternative"] == 1 and d["above_named"] <= d["above"] - 2
    every = [{"magnitude": float(m), "verdict": "missing-effect", "correct": True} for m in np.linspace(0.1, 1, 20)]
    every.append({"magnitude": 0.55, "verdict": "nothing-missing", "correct": False})  # 20 of 21 detected
    e = bench.detection_threshold(every, outcome="detected")
    assert e["m_level"] == 0.0 and e["above"] == 21 and e["above_detected"] == 20 and e["above_named"] == 20
    with pytest.raises(ValueError, match="outcome"):
        bench.detection_threshold(rows, outcome="power")


def test_only_and_refit_rows_keep_case_definitions(tmp_path):
    """``--only`` skips other labels without renumbering; refit rows are stored and summarised apart."""
    results = tmp_path / "r.jsonl"
    assert bench.run_cases("toy", range(0, 4), results, tmp_path / "runs", only={"no-such-label"}) == []
    assert not results.exists() or results.read_text() == ""
    base = {"suite": "mujoco", "truth_label": "control", "scenario": "lift", "magnitude": None, "named": None,
            "called": "nothing-missing", "verdict": "nothing-missing", "correct": True}
    rows = [dict(base, id="a", budget={"rounds": 2}),
            dict(base, id="b-refit2", budget={"rounds": 2, "confirm": 2}, truth_label="wind", named="wind",
                 called="wind", verdict="missing-effect", magnitude=0.5,
                 refits=[["wind", 0.5, 0.3, False, None, None, None, 0.7], ["air-drag", 0.1, 0.3, False]]),
            dict(base, id="c-refit2", budget={"confirm": 2}, truth_label="other-engine", called="misspecified-unexplained",
                 verdict="misspecified-unexplained", screening_verdict="missing-effect",
                 refits=[["wind", 0.2, 0.004, True]])]
    assert [r["id"] for r in bench.select_rows(rows)] == ["a"]
    # rows stored before the joint test count as the omnibus test's
    assert [r["id"] for r in bench.select_rows(rows + [dict(base, id="d", test="joint")], test="joint")] == ["d"]
    assert [r["id"] for r in bench.select_rows(rows, test="omnibus")] == ["a"]
    # rows stored before the proposal field were fitted with corrected proposals; truncated ones are kept apart
    trunc = dict(base, id="e", proposal="truncated", budget={"rounds": 3})
    assert [r["id"] for r in bench.select_rows(rows + [trunc])] == ["a"]
    assert [r["id"] for r in bench.select_rows(rows + [trunc], proposal="truncated")] == ["e"]
    assert [r["id"] for r in bench.select_rows(rows + [trunc], proposal=None)] == ["a", "e"]
    refit = bench.select_rows(rows, 2)
    s = bench.summarise(refit)
    assert s["refit_drop"] == {"n": 1, "median": 0.5}
    # the posterior-mean rollout's drop (refits[i][7]) of the named effect's refit, with the same cases' Chamfer drop
    assert s["refit_drop_pm"] == {"n": 1, "median": 0.7, "median_chamfer_same_cases": 0.5}
    assert s["other_engine"] == {"n": 1, "misspecified-unexplained": 1, "screening": {"missing-effect": 1}}
    md = bench.markdown(s, [dict(r, misspecification_p_text="p", wall_s=1.0) for r in refit])
    assert "misspecified-unexplained (screening: missing-effect)" in md and "wind Chamfer -20%, check p 0.004" in md
    assert "posterior-mean rollout's Chamfer, correctly named cases that stored it: 70% (n = 1;" in md
    # rows stored before the local thickness had 13 summaries per frame; new ones say how many
    thick = dict(base, id="f", n_summaries=14)
    assert [r["id"] for r in bench.select_rows(rows + [thick], n_summaries=14)] == ["f"]
    assert [r["id"] for r in bench.select_rows(rows + [thick], n_summaries=13)] == ["a"]


def test_the_reducible_error_uses_the_oracle_score_stored_with_the_effect_size():
    """The drop of the reducible error takes the truth's own score from ``floor_m`` or, the same computation, from
    ``effect_size.with_m``; rows whose truth scores no better than the nominal fit (sensor spread) are counted
    apart, not as drops."""
    base = {"truth_label": "wind", "named": "wind", "called": "wind", "verdict": "missing-effect", "correct": True,
            "magnitude": 0.5, "budget": {"confirm": 2}}
    rows = [dict(base, id="a", refits=[["wind", 0.3]], floor_m=0.01, chamfer_nominal_m=0.04),
            dict(base, id="b", refits=[["wind", 0.5]], effect_size={"size_m": 0.01, "with_m": 0.02, "nominal_m": 0.04}),
            dict(base, id="c", refits=[["wind", -0.1]], effect_size={"size_m": -0.01, "with_m": 0.05, "nominal_m": 0.04}),
            dict(base, id="d", refits=[["wind", 0.2]])]
    rd = bench.summarise(rows)["refit_drop_of_reducible"]
    # a: 0.3 * 0.04 / 0.03 = 0.4; b: 0.5 * 0.04 / 0.02 = 1.0
    assert rd["n"] == 2 and rd["median"] == pytest.approx(0.7)
    assert rd["floor_at_or_above_nominal"] == 1 and rd["without_floor"] == 1


def test_refit_drops_are_reported_per_effect_with_the_summary_bias_fall():
    """The pooled median drop is read with its mix of effects: per hidden effect the Chamfer drop, the reducible
    error's drop and the summary bias's fall (refits[i][4]); a point-noise refit that raises the Chamfer can still
    remove the summary bias, and refits stored without the bias fall are counted, not taken as zero."""
    base = {"verdict": "missing-effect", "correct": True, "magnitude": 0.5, "budget": {"confirm": 2}}
    rows = [dict(base, id="a", truth_label="wind", named="wind", called="wind",
                 refits=[["wind", 0.6, 0.5, False, 0.9], ["air-drag", 0.4, 0.5, False, 0.5]],
                 floor_m=0.01, chamfer_nominal_m=0.04),
            dict(base, id="b", truth_label="wind", named="wind", called="wind", refits=[["wind", 0.2]]),
            dict(base, id="c", truth_label="point-noise", named="point-noise", called="point-noise",
                 refits=[["point-noise", -0.1, 0.5, False, 0.6]],
                 effect_size={"size_m": -0.002, "with_m": 0.05, "nominal_m": 0.04}),
            dict(base, id="d", truth_label="wind", named=None, called="nothing-missing", correct=False,
                 verdict="nothing-missing", refits=[["wind", 0.9, 0.5, False, 0.99]])]
    s = bench.summarise(rows)
    # only the named effect's refit of correctly named cases: a's wind, b's wind, c's point noise
    assert s["refit_bias_fall"] == {"n": 2, "median": pytest.approx(0.75), "without": 1}
    by = s["refit_drop_by_effect"]
    assert set(by) == {"wind", "point-noise"}
    assert by["wind"]["chamfer"] == {"n": 2, "median": pytest.approx(0.4)}
    # a: 0.6 * 0.04 / 0.03 = 0.8; b has no truth's score
    assert by["wind"]["reducible"] == {"n": 1, "median": pytest.approx(0.8)}
    assert by["wind"]["bias"] == {"n": 1, "median": pytest.approx(0.9)}
    # the truth scores worse than the nominal fit: no reducible error, but the bias fall is counted
    assert by["point-noise"]["reducible"] == {"n": 0, "median": None}
    assert by["point-noise"]["chamfer"]["median"] == pytest.approx(-0.1) and by["point-noise"]["bias"]["n"] == 1
    md = bench.markdown(s, [])
    assert "| point-noise | -10% (n = 1) | - | 60% (n = 1) |" in md
    assert "correctly named cases: 75% (n = 2; 1 refits stored before it was kept)" in md


def test_all_candidates_screens_what_diagnose_screens_and_is_stored_apart(tmp_path, monkeypatch):
    """``--all-candidates`` screens the ten named candidates where a suite screens fewer (mujoco: the four built-in
    physics effects), as ``softsbi diagnose`` screens every installed effect; such rows carry ``-c10`` and are
    selected apart; rows stored before the field count their suite's candidates."""
    seen = []
    monkeypatch.setattr(bench, "run_case", lambda case, *a: seen.append((case["id"], a[-1])) or {**case, "verdict": "x"})
    bench.run_cases("mujoco", [1, 2], tmp_path / "r.jsonl", tmp_path / "runs", all_candidates=True)
    bench.run_cases("mujoco", [3], tmp_path / "r.jsonl", tmp_path / "runs")
    bench.run_cases("mujoco-more", [1], tmp_path / "r.jsonl", tmp_path / "runs", all_candidates=True)
    assert [i.endswith("-c10") for i, _ in seen] == [True, True, False, False]
    assert seen[0][1] == bench.NAMED_CANDIDATES and seen[2][1] == ["wind", "air-drag", "extra-damping", "grip-compliance"]
    assert seen[3][1] == bench.NAMED_CANDIDATES
    base = {"truth_label": "control", "verdict": "nothing-missing", "correct": True, "budget": {}}
    rows = [dict(base, id="mujoco-s0-5", suite="mujoco", index=5),
            dict(base, id="mujoco-s0-10-c10", suite="mujoco", index=10, candidates=bench.NAMED_CANDIDATES),
            dict(base, id="mujoco-more-s0-7", suite="mujoco-more", index=7)]
    assert [r["id"] for r in bench.select_rows(rows, proposal=None, n_candidates=4)] == ["mujoco-s0-5"]
    assert [r["id"] for r in bench.select_rows(rows, proposal=None, n_candidates=10)] == ["mujoco-s0-10-c10",
                                                                                           "mujoco-more-s0-7"]


def test_min_magnitude_runs_only_hidden_effect_cases_at_or_above_it(tmp_path, monkeypatch):
    """``--min-magnitude`` chooses cases on the power curve's covariate: controls and smaller effects are skipped,
    the indices keep their definitions."""
    ran = []
    monkeypatch.setattr(bench, "run_case", lambda case, *a, **k: ran.append(case) or {**case, "verdict": "x"})
    bench.run_cases("toy", range(0, 12), tmp_path / "r.jsonl", tmp_path / "runs", min_magnitude=0.7)
    cases = [bench.make_case("toy", 0, i) for i in range(12)]
    want = [c["index"] for c in cases if c["magnitude"] is not None and c["magnitude"] >= 0.7]
    assert want and [c["index"] for c in ran] == want
    # some hidden effects were smaller, and the controls (no magnitude) were skipped too
    assert any(c["magnitude"] is not None and c["magnitude"] < 0.7 for c in cases)
    assert any(c["magnitude"] is None for c in cases)


def test_a_single_hidden_effect_is_named_correctly_only_when_named_alone():
    """A hidden wind named "wind + extra damping" (a pair refit explained the misfit) is not named correctly, and the
    row says what was called; the pair's own cases need both."""
    case = bench.make_case("mujoco", 0, 1)
    assert case["truth_label"] == "wind"
    d = {"verdict": "missing-effect", "selected": "wind", "significant": ["wind", "extra-damping"],
         "misspecification": {"p_value": 0.01, "p_text": "p", "omnibus": {"p_value": 0.01}}, "n_null": 200,
         "ranking": [], "confirmed": []}
    alone = bench.row_fields(case, {**d, "named_effects": ["wind"]})
    assert alone["correct"] and alone["called"] == "wind"
    pair = bench.row_fields(case, {**d, "named_effects": ["wind", "extra-damping"]})
    assert not pair["correct"] and pair["called"] == "extra-damping+wind"
    both = bench.row_fields({**case, "truth_label": "wind+extra-damping"}, {**d, "named_effects": ["wind", "extra-damping"]})
    assert both["correct"] and both["called"] == "extra-damping+wind"


def test_merge_replaces_a_case_run_again_keeps_its_data_fields_and_appends_new_ones(tmp_path):
    results, new = tmp_path / "r.jsonl", tmp_path / "n.jsonl"
    old = [{"id": "a", "verdict": "misspecified-unexplained", "called": "misspecified-unexplained", "correct": False,
            "effect_size": {"size_m": 0.02}, "floor_m": 0.01, "chamfer_nominal_m": 0.03}, {"id": "b", "verdict": "nothing-missing", "correct": True}]
    bench.save_rows(results, old)
    bench.save_rows(new, [{"id": "a", "verdict": "missing-effect", "called": "wind", "correct": True},
                          {"id": "c", "verdict": "nothing-missing", "correct": True},
                          {"id": "d", "error": "RuntimeError: x"}])
    assert bench.merge_rows(results, [new], note="why") == {"replaced": 1, "appended": 1, "skipped": 1}
    rows = bench.load_rows(results)
    assert [r["id"] for r in rows] == ["a", "b", "c"]
    assert rows[0]["called"] == "wind" and rows[0]["effect_size"] == {"size_m": 0.02} and rows[0]["rerun"] == "why"
    assert rows[0]["rerun_was"] == {"called": "misspecified-unexplained", "correct": False}
    assert "floor_m" not in rows[0]  # stored with the old nominal fit's Chamfer: `floor` adds both again
    assert "rerun" not in rows[2]
    # the same measurement under another protocol's id: appended, pointing at the row it follows; counted once
    case = {"suite": "mujoco-more", "index": 495, "truth_label": "time-offset", "verdict": "nothing-missing",
            "called": "nothing-missing", "correct": False}
    bench.save_rows(results, [dict(case, id="mujoco-more-s0-495-refit2-joint-truncated")])
    bench.save_rows(new, [dict(case, id="mujoco-more-s0-495-refit2-3x100-joint-truncated", verdict="missing-effect",
                               called="time-offset", correct=True)])
    assert bench.merge_rows(results, [new], note="protocol") == {"replaced": 0, "appended": 1, "skipped": 0}
    rows = bench.load_rows(results)
    assert rows[1]["rerun_was"] == {"called": "nothing-missing", "correct": False,
                                    "id": "mujoco-more-s0-495-refit2-joint-truncated"}
    assert [r["id"] for r in bench.one_row_per_case(rows)] == ["mujoco-more-s0-495-refit2-3x100-joint-truncated"]


def test_refit_rows_keep_the_posterior_mean_rollout_drop_and_the_backfill_recomputes_it(tmp_path):
    """A refitted case stores its named refit's posterior-mean rollout drop (diagnose computes it); ``pm-rollout``
    (:func:`add_pm_drops`) recomputes the same number from the runs on disk for rows stored without it, and
    ``truth-energy`` (:func:`add_truth_energies`) adds the three energy scores."""
    results = tmp_path / "r.jsonl"
    rows = bench.run_cases("toy", [1], results, tmp_path / "runs", seed=3, rounds=2, sims=120, n_null=30,
                           max_null=100, confirm=1, workers=1)
    assert rows[0]["truth_label"] == "toy-wind" and rows[0]["correct"], rows
    refit = next(x for x in rows[0]["refits"] if x[0] == rows[0]["named"])
    # a wind refit is not judged in the local thickness: its thickness-bias fields (refits[i][8:10]) are empty
    assert len(refit) == 10 and refit[7] > 0.2 and refit[8:] == [None, None]
    stored = bench.load_rows(results)
    for x in stored[0]["refits"]:
        del x[7:]
    bench.save_rows(results, stored)
    assert bench.add_pm_drops(results, [tmp_path / "elsewhere", tmp_path / "runs"]) == 1
    again = next(x for x in bench.load_rows(results)[0]["refits"] if x[0] == rows[0]["named"])
    assert again[7] == pytest.approx(refit[7], abs=1e-9)  # the same seeds and runs
    assert bench.add_pm_drops(results, [tmp_path / "runs"]) == 0  # stored: not measured again
    # `truth-energy`: the nominal fit's, the named refit's and the truth's own energy scores (a proper score: the
    # distribution the measurement came from scores lowest), and the summary's share the refit removes
    assert bench.add_truth_energies(results, [tmp_path / "elsewhere", tmp_path / "runs"]) == 1
    assert bench.add_truth_energies(results, [tmp_path / "runs"]) == 0  # stored: not measured again
    e = bench.load_rows(results)[0]["energy_m"]
    assert 0 < e["truth"] < e["refit"] < e["nominal"] and e["truth_se"] > 0
    et = bench.summarise(bench.load_rows(results))["energy_truth"]
    assert et["n"] == 1 and et["median_drop_of_reducible"] == pytest.approx(
        (e["nominal"] - e["refit"]) / (e["nominal"] - e["truth"]))


def test_a_stored_row_is_rediagnosed_at_a_new_level_only_when_one_of_its_decisions_lay_between_the_levels():
    def row(p, ranking=(), remaining=None, n_null=200, alpha=None):
        budget = {"n_null": 30, "max_null": 200, "confirm": 2}
        if alpha is not None:
            budget["alpha"] = alpha
        return {"verdict": "x", "misspecification_p": p, "n_null": n_null, "budget": budget,
                "ranking": [["wind", 0.5, q] for q in ranking], "remaining": remaining and {"p_value": remaining}}

    assert bench.row_alpha(row(0.3)) == 0.01 and bench.row_alpha(row(0.3, alpha=0.05)) == 0.05
    assert bench.can_change_at(row(0.03), 0.05)                      # not rejected at 0.01, rejected at 0.05
    assert not bench.can_change_at(row(0.3), 0.05)                   # accepted at both
    assert not bench.can_change_at(row(0.06, ranking=[0.03]), 0.05)  # accepted at both: the candidates do not matter
    assert bench.can_change_at(row(0.005, ranking=[0.005, 0.03]), 0.05)  # a second candidate now passes
    assert not bench.can_change_at(row(0.005, ranking=[0.005, 0.2]), 0.05)
    assert bench.can_change_at(row(0.005, ranking=[0.005], remaining=0.02), 0.05)  # a second effect now passes
    assert bench.can_change_at(row(0.13, n_null=30), 0.05)          # a null the eager extension would now grow
    assert bench.can_change_at(row(0.03, alpha=0.05), 0.01)          # and back
    assert not bench.can_change_at({"id": "e", "error": "boom"}, 0.05)


def test_recheck_finds_the_refit_checks_the_first_stage_left_unresolved_and_keeps_backfilled_drops():
    """``recheck`` takes a refit's check again only when its first stage did not resolve rule 3's decision
    (1-6 exceedances in 30 at 0.1 per test) and it did not grow; a decided-again row keeps the energy and
    posterior-mean drops that backfills stored in the row only."""
    def check(k_omni, k_dir, n=30, extended=False):
        return {"misspecification_after": {"alpha": 0.2, "n_null": n, "max_null": 200, "extended": extended,
                                           "omnibus": {"exceed": k_omni, "n_null": n},
                                           "directional": {"exceed": k_dir, "n_null": n}}}
    d = {"confirmed": [dict(check(0, 9), effect="a"), dict(check(3, 12), effect="b"), dict(check(9, 12), effect="c"),
                       dict(check(3, 12, n=200, extended=True), effect="d"), dict(check(2, 8, n=200), effect="e")]}
    assert [c["effect"] for c in bench.unresolved_refit_checks(d)] == ["b"]
    old = [["a", 0.5, 0.3, False, None, None, 0.4, 0.6], ["b", 0.2, 0.26, False, None, None]]
    new = [["b", 0.2, 0.05, True, None, None, None, None], ["a", 0.5, 0.3, False, None, None, 0.45, None],
           ["a+b", 0.6, 0.5, False, None, None, 0.7, 0.8]]
    kept = bench.keep_backfilled(old, new)
    assert kept[0] == ["b", 0.2, 0.05, True, None, None, None, None]
    assert kept[1] == ["a", 0.5, 0.3, False, None, None, 0.45, 0.6]  # the new energy drop, the backfilled one
    assert kept[2] == new[2]


def test_rewiden_takes_only_rejected_refits_that_press_a_bound_and_were_not_widened():
    """``rewiden`` refits again only what confirm_effect would now widen: check rejected the refit, an added
    effect's parameter presses a prior bound, and it has no ``widened`` entry yet."""
    pressed = [{"param": "wind_x", "side": "lower"}]
    d = {"confirmed": [{"effect": "a", "misspecification_after": {"misspecified": True}, "at_bounds": pressed},
                       {"effect": "b", "misspecification_after": {"misspecified": False}, "at_bounds": pressed},
                       {"effect": "c", "misspecification_after": {"misspecified": True}, "at_bounds": []},
                       {"effect": "d", "misspecification_after": {"misspecified": True}},
                       {"effect": "e", "misspecification_after": {"misspecified": True}, "at_bounds": pressed,
                        "widened": {"bounds": {}}},
                       {"effect": "f", "at_bounds": pressed}]}
    assert [c["effect"] for c in bench.refits_to_widen(d)] == ["a"]
    assert bench.refits_to_widen({}) == []


def test_resecond_takes_the_first_refit_only_where_no_single_refit_explains_and_it_has_no_screening():
    """``resecond`` re-checks only the refit whose screening the pair rule reads (the screening's first effect),
    only where the rule applies (screening said missing-effect, every single refit rejected) and only once."""
    rej, acc = {"misspecified": True}, {"misspecified": False}
    d = {"verdict": "misspecified-unexplained", "screening_verdict": "missing-effect", "significant": ["w", "c"],
         "confirmed": [{"effect": "c", "misspecification_after": rej}, {"effect": "w", "misspecification_after": rej},
                       {"effect": "w+c", "misspecification_after": acc}]}
    assert [c["effect"] for c in bench.refits_without_lead(d)] == ["w"]
    d["confirmed"][1]["ranking_after"] = []  # already has its screening
    assert bench.refits_without_lead(d) == []
    del d["confirmed"][1]["ranking_after"]
    d["confirmed"][0]["misspecification_after"] = acc  # a single refit explains it: no pair is refitted
    assert bench.refits_without_lead(d) == []
    assert bench.refits_without_lead({"verdict": "nothing-missing", "significant": [], "confirmed": []}) == []


def test_rebase_takes_the_refit_with_the_largest_drop_only_where_it_is_not_the_screenings_first_and_a_pair_was_due():
    """``rebase`` selects the refit a pair now builds on (the largest drop among the significant effects' single
    refits) only where it differs from the screening's first and the pair path was taken (third verdict, or a pair)."""
    rej = {"misspecified": True}
    d = {"verdict": "misspecified-unexplained", "screening_verdict": "missing-effect", "significant": ["w", "d"],
         "confirmed": [{"effect": "d", "drop": 0.54, "misspecification_after": rej},
                       {"effect": "w", "drop": 0.21, "misspecification_after": rej},
                       {"effect": "w+c", "drop": -0.06, "misspecification_after": {"misspecified": False}}]}
    assert [c["effect"] for c in bench.refits_with_another_base(d)] == ["d"]
    d["confirmed"][0]["drop"] = 0.1  # the screening's first lowers the error most: nothing to rebase
    assert bench.refits_with_another_base(d) == []
    d["confirmed"][0]["drop"] = 0.54
    assert bench.refits_with_another_base({**d, "verdict": "missing-effect", "confirmed": d["confirmed"][:2]}) == []
    assert bench.refits_with_another_base({**d, "significant": ["w"]}) == []  # d is not significant


def test_relead_takes_the_base_refit_only_where_the_current_rule_2_picks_another_second_effect():
    """``relead`` selects the base refit whose check screening now gives another pair lead: the first ranked
    candidate explains too little, the next passes (the stored lead was None)."""
    rej = {"misspecified": True, "alpha": 0.2, "tests": 2}

    def after(effect, p, frac):
        return {"effect": effect, "generic": False, "adjusted_p_value": p, "adjusted_p_text": f"p = {p}",
                "explained_fraction": frac}
    base = {"effect": "w", "drop": 0.3, "misspecification_after": rej,
            "ranking_after": [after("a", 0.01, 0.02), after("d", 0.01, 0.4)]}
    d = {"verdict": "misspecified-unexplained", "screening_verdict": "missing-effect", "significant": ["w"],
         "confirmed": [base], "pair_lead": None}
    assert [c["effect"] for c in bench.refits_with_another_lead(d)] == ["w"]
    assert bench.refits_with_another_lead({**d, "pair_lead": {"after": "w", "effect": "d"}}) == []
    base["ranking_after"][0]["explained_fraction"] = 0.3  # the first ranked passes: the lead is unchanged
    assert bench.refits_with_another_lead({**d, "pair_lead": {"after": "w", "effect": "a"}}) == []
    assert bench.refits_with_another_lead({**d, "verdict": "missing-effect"}) == []  # a single refit explained it


def test_a_stored_row_decided_again_keeps_its_old_verdict_the_old_diagnosis_and_continues(tmp_path, monkeypatch):
    """The loop shared by recheck, rewiden and resecond: the selected refits are changed, the rules applied again,
    diagnosis.json rewritten with the old one kept, the row's verdict replaced with the old one under the mark, and a
    second call does nothing (the mark is there)."""
    import softsbi.workflows.diagnose as dg
    case = {**bench.make_case("mujoco", 0, 1), "id": "mujoco-s0-1-refit2-joint"}
    old = {"run": "x", "verdict": "misspecified-unexplained", "selected": None, "significant": ["wind"],
           "misspecification": {"p_value": 0.01, "p_text": "p = 0.01", "omnibus": {"p_value": 0.01}}, "n_null": 30,
           "ranking": [], "confirmed": [{"effect": "wind", "drop": 0.5, "misspecification_after":
                                         {"p_value": 0.01, "misspecified": True}}]}
    run_dir = tmp_path / "out" / case["id"]
    run_dir.mkdir(parents=True)
    (run_dir / "diagnosis.json").write_text(json.dumps(old))
    results = tmp_path / "r.jsonl"
    bench.save_rows(results, [{**bench.row_fields(case, old), "budget": {"confirm": 2}}])
    seen = {}

    def fake_redecide(run, d, confirm, workers=None, n=None, budget=None):
        seen.update(confirm=confirm, budget=budget, p=d["confirmed"][0]["misspecification_after"]["p_value"])
        return {**d, "verdict": "missing-effect", "selected": "wind", "named_effects": ["wind"]}
    monkeypatch.setattr(dg, "redecide", fake_redecide)

    def redo(run_dir_, d, todo, workers, budget):
        assert run_dir_ == run_dir
        todo[0]["misspecification_after"] = {"p_value": 0.5, "misspecified": False}

    calls = []
    changed = bench.decide_stored_again(results, [tmp_path / "out"], None, "redone", lambda d: d["confirmed"],
                                        "diagnosis.before.json", redo,
                                        lambda d, todo: calls.append(1) or ({"n": len(todo)}, {"k": 1}))
    assert changed == [case["id"]] and seen == {"confirm": 2, "budget": None, "p": 0.5}
    row = bench.load_rows(results)[0]
    assert row["verdict"] == "missing-effect" and row["named"] == "wind" and row["correct"]
    assert row["redone"] == {"verdict": "misspecified-unexplained", "named": None, "k": 1}
    assert json.loads((run_dir / "diagnosis.before.json").read_text()) == old
    assert json.loads((run_dir / "diagnosis.json").read_text())["verdict"] == "missing-effect"
    assert bench.decide_stored_again(results, [tmp_path / "out"], None, "redone", lambda d: d["confirmed"],
                                     "diagnosis.before.json", redo, lambda d, todo: ({}, {})) == [] and calls == [1]


def test_a_case_diagnosed_under_two_protocols_counts_once():
    """Two refit protocols of one measurement (``mujoco-more-s0-475``: refits at the nominal budget and at 3 x 100)
    are one case in the summary: the row stored last; other cases and rows without an index are kept."""
    base = {"suite": "mujoco-more", "truth_label": "point-noise", "scenario": "wipe", "magnitude": 0.3, "named": None,
            "called": "nothing-missing", "verdict": "nothing-missing", "correct": False, "test": "joint",
            "proposal": "truncated", "budget": {"confirm": 2, "alpha": 0.05}}
    rows = [dict(base, id="mujoco-more-s0-475-refit2-joint-truncated", index=475),
            dict(base, id="mujoco-more-s0-476-refit2-3x100-joint-truncated", index=476),
            dict(base, id="mujoco-more-s1-475-refit2-3x100-joint-truncated", index=475),
            dict(base, id="mujoco-more-s0-475-refit2-3x100-joint-truncated", index=475),
            dict(base, id="hand-made", index=None)]
    kept = [r["id"] for r in bench.select_rows(rows, None, proposal=None, alpha=0.05, test="joint")]
    assert kept == ["mujoco-more-s0-476-refit2-3x100-joint-truncated", "mujoco-more-s1-475-refit2-3x100-joint-truncated",
                    "mujoco-more-s0-475-refit2-3x100-joint-truncated", "hand-made"]
    assert bench.summarise(bench.select_rows(rows, None, proposal=None))["power"]["point-noise"]


def test_the_criterion_per_task_fits_one_detection_curve_per_scenario():
    """A grip detected and named in every lift from magnitude 0.3 up, never detected while the cloth hangs in a wind:
    pooled, the effect's detection curve never reaches 90%; per task the lift has a threshold below 0.4 with every
    case above it named, and the wind none. The summary and its Markdown table say so."""
    mags = np.linspace(0.1, 1.0, 10)
    rows = [{"truth_label": "grip-compliance", "scenario": "lift", "magnitude": float(m),
             "verdict": "missing-effect" if m >= 0.3 else "nothing-missing", "called": "grip-compliance",
             "named": "grip-compliance" if m >= 0.3 else None, "correct": bool(m >= 0.3)} for m in mags]
    rows += [{"truth_label": "grip-compliance", "scenario": "wind", "magnitude": float(m), "verdict": "nothing-missing",
              "called": "nothing-missing", "named": None, "correct": False} for m in mags]
    s = bench.summarise(rows)
    assert s["thresholds_detected"]["grip-compliance"]["m_level"] is None
    per = s["thresholds_detected_by_scenario"]["grip-compliance"]
    assert 0.1 < per["lift"]["m_level"] < 0.4 and per["lift"]["above_named"] == per["lift"]["above"] >= 7
    assert per["wind"]["m_level"] is None
    md = bench.markdown(s, [])  # the tables of the summary only (no per-case rows)
    assert "| grip-compliance | " in md and "- (n = 10)" in md
    assert f"{per['lift']['above']} of {per['lift']['above']} cases above their cell's threshold named correctly" in md
