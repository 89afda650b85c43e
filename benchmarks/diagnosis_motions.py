"""The motions split: the workflow a user follows, diagnosed under frozen rules on cases it never saw.

*Cases* are drawn as the diagnosis suite's (:func:`benchmarks.diagnosis.case_at`): a cloth at a prior draw and
one shipped effect hidden at a magnitude in the upper two thirds of its on range, a control, or the other engine;
their own seed stream (:data:`SPLIT_SEED`) and counts (:data:`COUNTS`: 40 controls, 4 cases per shipped effect, 8
other-engine recordings), so no case is one of the first split's or a development case.

*Each case* is the loop a user follows. Its lift is simulated, fitted (the trained lift task), checked and diagnosed
(step 1, *Part 1*). While the last diagnosis leaves candidates undecided
(:func:`~softsbi.core.results.design.undecided_candidates`) and fewer than :data:`MAX_MOTIONS` motions are recorded,
``softsbi design`` of it advises the next motion (:attr:`~softsbi.core.results.design.Design.best`, a motion not yet
recorded that informs an undecided candidate none recorded does); the same hidden truth (cloth and effect) is
simulated on that motion, fitted on its trained task, checked, and the recordings so far are diagnosed as one rig
(``softsbi diagnose RUN RUN ... --out DIR``), a further step (*Part 2*). A case stops when nothing is undecided,
when no motion weighed informs what is left, or at :data:`MAX_MOTIONS`. Controls go through the same loop, so the
rig's false alarms are measured too.

*The tasks* (lift, wipe, fling on mujoco-flex, each with every shipped candidate and its replicate recordings) are
trained once into ``--out/bank`` by ``--train`` (``softsbi task train``'s defaults; stored models are read).

Rows go to ``benchmarks/results/diagnosis-motions.jsonl`` as each case finishes, with the commit, machine, command
and settings; a run resumes (a case whose latest row is ``ok`` is skipped). Usage::

    python -m benchmarks run diagnosis-motions --train --full --out OUTSIDE/motions [--workers 2]
    python -m benchmarks run diagnosis-motions --cases none       # the page from the stored rows only
"""
from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from benchmarks import runner
from benchmarks.diagnosis_protocol import (EFFECTS, LABELS, _rate, latest, outcome, read_rows)

RESULTS = runner.RESULTS / "diagnosis-motions.jsonl"
#: the split's seed stream (the diagnosis suite's splits are 0 and 1)
SPLIT_SEED = 2
#: cases per truth: controls, each shipped effect, the other engine
COUNTS = {"control": 40, "effect": 4, "other-engine": 8}
N_CASES = COUNTS["control"] + COUNTS["effect"] * len(EFFECTS) + COUNTS["other-engine"]
#: the motions a case may record, and at most how many
MOTIONS = ("lift", "wipe", "fling")
MAX_MOTIONS = 3
#: each motion's recording seed offset (the case's index is added)
MOTION_SEED = {"lift": 1000, "wipe": 3000, "fling": 5000}
#: the goals of the issue, for the page
GOALS = {"lift_false_alarms": "<= 1 of 40", "lift_informed_right": ">= 0.95", "lift_unexplained": "<= 0.10",
         "lift_wrong_effect": "<= 0.03", "last_named_right": ">= 0.75", "last_false_alarms": "<= 1 of 40",
         "last_other_engine": ">= 7 of 8", "design_decides": ">= 0.60"}


def make_case(i: int) -> dict[str, Any]:
    """Case ``i`` of the split (:func:`benchmarks.diagnosis.case_at` at :data:`SPLIT_SEED` and :data:`COUNTS`)."""
    from benchmarks.diagnosis import case_at
    return case_at("motions", SPLIT_SEED, i, COUNTS)


def scenario(motion: str):
    """A motion's scenario: the demo's lift (the lift task's), else the built-in scenario of that name."""
    if motion == "lift":
        from softsbi.scenarios.builtin import lift_scenario
        return lift_scenario(None)
    from softsbi.scenarios.catalog import load_scenario
    return load_scenario(motion)


def _score(s: Any) -> list[float] | None:
    return None if s is None else [float(s.difference), float(s.se), float(s.z)]


def step_of(motion: str, d: Any, seconds: float) -> dict[str, Any]:
    """A step's row from its diagnosis ``d`` (a single recording's, or the rig's so far): ``motion``, ``verdict``,
    ``named``, ``alternatives``, ``p_value`` (the check's, or Fisher's over the rig's recordings), ``gain`` (the
    named effect's gain over the nominal model: difference, standard error, z; summed over the rig), ``undecided``
    (the candidates it leaves undecided, with why) and ``seconds`` (fit + check + diagnose of this step)."""
    from softsbi.core.results.design import undecided_candidates
    return {"motion": motion, "verdict": d.verdict, "named": list(d.decision.named),
            "alternatives": [list(a) for a in d.decision.alternatives], "p_value": float(d.test.p_value),
            "gain": _score(d.decision.gain), "undecided": undecided_candidates(d, d.family), "seconds": seconds}


def record_motion(case: Mapping[str, Any], motion: str, run_dir: Path, bank: Path, workers: int | None) -> float:
    """Simulate the case's truth on ``motion``, fit it (its trained task, the fit's defaults) and check it into
    ``run_dir``; the seconds."""
    from benchmarks.diagnosis import DIAGNOSE, ENGINE, OTHER_ENGINE, fit_config
    from softsbi.core.defaults import DiagnoseSettings
    from softsbi.workflows.criticism.check import check_run
    from softsbi.workflows.fit.run import run_fit
    from softsbi.workflows.measurement import simulate_recording
    hidden = [] if case["label"] in ("control", "other-engine") else [case["label"]]
    engine = OTHER_ENGINE if case["label"] == "other-engine" else ENGINE
    t0 = time.perf_counter()
    rec = simulate_recording(engine, scenario(motion), case["truth"], effects=hidden,
                             seed=MOTION_SEED[motion] + case["index"])
    run_fit(run_dir, rec, fit_config(bank, workers), make_plots=False)
    check_run(run_dir, plot=False, settings=DiagnoseSettings(**DIAGNOSE, workers=workers).check())
    return time.perf_counter() - t0


def run_case(case: Mapping[str, Any], out: Path, workers: int | None) -> dict[str, Any]:
    """The case's loop (module docstring) under ``out/<id>``: the row's ``steps`` (:func:`step_of`, each but the
    last with ``design``: the motion it advised and the motions ranked) and ``stop`` (why the loop ended)."""
    from benchmarks.diagnosis import DIAGNOSE
    from softsbi.core.defaults import DiagnoseSettings
    from softsbi.workflows.criticism.design import design_run
    from softsbi.workflows.criticism.diagnose import diagnose_run
    from softsbi.workflows.criticism.joint import diagnose_runs
    settings = DiagnoseSettings(**DIAGNOSE, workers=workers)
    home, bank = out / case["id"], out / "bank"
    runs = [home / "lift"]
    seconds = record_motion(case, "lift", runs[0], bank, workers)
    t0 = time.perf_counter()
    d = diagnose_run(runs[0], settings=settings, plots=False)
    steps = [step_of("lift", d, seconds + time.perf_counter() - t0)]
    where, stop = runs[0], "nothing undecided"
    while steps[-1]["undecided"]:
        if len(runs) == MAX_MOTIONS:
            stop = f"{MAX_MOTIONS} motions recorded"
            break
        t0 = time.perf_counter()
        des = design_run(where, workers=workers)
        steps[-1]["design"] = {"best": des.best, "motions": list(des.motions), "seconds": time.perf_counter() - t0}
        if des.best is None:
            stop = "no motion weighed informs what is left"
            break
        runs.append(home / des.best)
        seconds = record_motion(case, des.best, runs[-1], bank, workers)
        where = home / f"rig-{len(runs)}"
        t0 = time.perf_counter()
        j = diagnose_runs(runs, settings=settings, out_dir=where, plots=False)
        steps.append(step_of(des.best, j, seconds + time.perf_counter() - t0))
    return {"steps": steps, "stop": stop}


def train(out: Path, workers: int | None, say=print) -> None:
    """Train every motion's task into ``out/bank`` (``softsbi task train``'s defaults; stored models are read)."""
    from benchmarks.diagnosis import fit_config
    from benchmarks.bench_motions import task_recording
    from softsbi.workflows.tasks.training import train_task
    for m in MOTIONS:
        train_task(task_recording(m), fit_config(out / "bank", workers), message=say)


def settings() -> dict[str, Any]:
    """The diagnosis suite's settings, with this split's cases and loop."""
    from benchmarks.diagnosis import settings as base
    s = base()
    s["cases"] = {**s["cases"], "counts": COUNTS, "split_seed": SPLIT_SEED, "motions": list(MOTIONS),
                  "max_motions": MAX_MOTIONS, "motion_seeds": MOTION_SEED}
    return s


def run(indices: Sequence[int], out: Path, workers: int | None, command: str, path: Path = RESULTS) -> None:
    """Run the cases of ``indices`` whose latest row in ``path`` is not ``ok``; append each row as it finishes
    (:func:`benchmarks.diagnosis.append_rows`: a failed case is a row with its error, counted wrong).

    Raises:
        SystemExit: before any case runs, when ``path`` holds rows of other settings."""
    from benchmarks.diagnosis import append_rows

    def run_one(case: dict[str, Any]) -> dict[str, Any]:
        t0 = time.perf_counter()
        return {**case, **run_case(case, out, workers), "status": "ok", "wall_s": time.perf_counter() - t0}
    append_rows(path, [make_case(i) for i in indices], run_one, command, settings(),
                lambda row: {"id": row["id"], "label": row["label"], "wall_s": row.get("wall_s"),
                             "error": row.get("error"),
                             "steps": [(s["motion"], s["verdict"], s["named"]) for s in row.get("steps", [])]})


# ------------------------------------------------------------------ the page, from stored rows


def step_outcome(row: Mapping[str, Any], step: Mapping[str, Any] | None) -> str:
    """A step's score (:func:`~benchmarks.diagnosis_protocol.outcome`); ``error`` for a failed case."""
    if row.get("status") != "ok" or step is None:
        return "error"
    return outcome(row["label"], step["verdict"], step["named"], step["alternatives"])


def kind(row: Mapping[str, Any], step: Mapping[str, Any] | None) -> str:
    """How a step ended, for the confusion table: ``error``, the named effects (joined by +), or the verdict."""
    if row.get("status") != "ok" or step is None:
        return "error"
    return "+".join(step["named"]) or step["verdict"]


def summary(rows: Sequence[Mapping[str, Any]], informed: Sequence[str] = ()) -> dict[str, Any]:
    """The figures of the stored rows (a case's latest row counts): per stage (``lift``: step 1; ``last``: the last
    step) the confusion (truth by call), false alarms, named right among effect cases (and among the effects
    ``informed``: those the trained lift informs), detected but unexplained, named as a wrong effect, the other
    engine left unexplained; ``design``: of the cases that took a second motion, how often the step it advised
    decided (nothing undecided after it); ``steps``: cases by number of motions; ``seconds``: the median seconds per
    step by its motion."""
    rows = latest(rows)
    out: dict[str, Any] = {"cases": len(rows), "errors": sum(r.get("status") != "ok" for r in rows)}
    for stage, pick in (("lift", 0), ("last", -1)):
        scored = []
        for r in rows:
            steps = r.get("steps") or []
            st = steps[pick] if steps else None
            scored.append((r, st, step_outcome(r, st)))
        ctl = [(r, o) for r, _, o in scored if r["label"] == "control"]
        eff = [(r, s, o) for r, s, o in scored if r["label"] in EFFECTS]
        oe = [o for r, _, o in scored if r["label"] == "other-engine"]
        inf = [o for r, _, o in eff if r["label"] in informed]
        out[stage] = {
            "confusion": {label: dict(Counter(kind(r, s) for r, s, _ in scored if r["label"] == label))
                          for label in LABELS if any(r["label"] == label for r, _, _ in scored)},
            "false_alarms": _rate(sum(o != "right" for _, o in ctl), len(ctl)),
            "named_right": _rate(sum(o == "right" for _, _, o in eff), len(eff)),
            "informed_right": _rate(inf.count("right"), len(inf)),
            "unexplained": _rate(sum(s is not None and s["verdict"] == "misspecified-unexplained" for _, s, _ in eff),
                                 len(eff)),
            "wrong_effect": _rate(sum(s is not None and s["verdict"] == "missing-effect" and o == "wrong"
                                      for _, s, o in eff), len(eff)),
            "other_engine": _rate(oe.count("right"), len(oe)),
            "by_effect": {e: [sum(o == "right" for r, _, o in eff if r["label"] == e),
                              sum(r["label"] == e for r, _, _ in eff)] for e in EFFECTS}}
    asked = [r for r in rows if r.get("status") == "ok" and len(r.get("steps") or []) > 1]
    decided = [r for r in asked if not r["steps"][1]["undecided"]]
    out["design"] = {**_rate(len(decided), len(asked)), "advised": dict(Counter(r["steps"][1]["motion"] for r in asked))}
    out["steps"] = dict(Counter(len(r.get("steps") or []) for r in rows if r.get("status") == "ok"))
    by_motion: dict[str, list[float]] = {}
    for r in rows:
        for s in r.get("steps") or []:
            by_motion.setdefault(s["motion"], []).append(float(s["seconds"]))
    out["seconds"] = {m: float(np.median(v)) for m, v in by_motion.items()}
    return out


def report(s: Mapping[str, Any]) -> dict[str, Any]:
    """The page's tables and notes from :func:`summary`."""
    def frac(x: Mapping[str, Any]) -> str:
        return "-" if not x["n"] else (f"{x['k']} of {x['n']} ({x['rate']:.2f}; 95% {x['ci95'][0]:.2f}-"
                                       f"{x['ci95'][1]:.2f})")
    tables = [runner.table(
        "The loop, scored strictly after the lift and after the last motion (95% Clopper-Pearson intervals)",
        ["measure", "after the lift", "after the last motion", "goal (lift; last)"],
        [["false alarms (controls)", frac(s["lift"]["false_alarms"]), frac(s["last"]["false_alarms"]),
          f"{GOALS['lift_false_alarms']}; {GOALS['last_false_alarms']}"],
         ["effects named right", frac(s["lift"]["named_right"]), frac(s["last"]["named_right"]),
          f"-; {GOALS['last_named_right']}"],
         ["effects the lift informs named right", frac(s["lift"]["informed_right"]),
          frac(s["last"]["informed_right"]), f"{GOALS['lift_informed_right']}; -"],
         ["detected, unexplained (effect cases)", frac(s["lift"]["unexplained"]), frac(s["last"]["unexplained"]),
          f"{GOALS['lift_unexplained']}; -"],
         ["named as a wrong effect", frac(s["lift"]["wrong_effect"]), frac(s["last"]["wrong_effect"]),
          f"{GOALS['lift_wrong_effect']}; -"],
         ["other engine left unexplained", frac(s["lift"]["other_engine"]), frac(s["last"]["other_engine"]),
          f"-; {GOALS['last_other_engine']}"],
         ["design's first motion decided", "-", frac(s["design"]), GOALS["design_decides"]]])]
    tables.append(runner.table("Named right per effect, after the lift and after the last motion",
                               ["effect", "after the lift", "after the last motion"],
                               [[e, f"{a[0]} of {a[1]}", f"{b[0]} of {b[1]}"] for e, a, b in
                                zip(EFFECTS, s["lift"]["by_effect"].values(), s["last"]["by_effect"].values())
                                if a[1]]))
    for stage, title in (("lift", "after the lift"), ("last", "after the last motion")):
        calls = sorted({c for row in s[stage]["confusion"].values() for c in row})
        tables.append(runner.table(f"Confusion {title}: truth by call", ["truth", *calls],
                                   [[t, *[row.get(c, 0) for c in calls]] for t, row in s[stage]["confusion"].items()]))
    notes = [f"{s['cases']} cases ({s['errors']} failed, counted wrong); motions recorded per case: "
             + ", ".join(f"{k} in {v}" for k, v in sorted(s["steps"].items())) + "; second motions advised: "
             + (", ".join(f"{m} {n}" for m, n in s["design"]["advised"].items()) or "none") + ".",
             "Median seconds per step (fit + check + diagnose; a rig's step diagnoses every recording so far): "
             + ", ".join(f"{m} {v:.0f}" for m, v in s["seconds"].items()) + "."]
    return {"tables": tables, "notes": notes}


FULL = {"cases": f"0:{N_CASES}"}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--cases", default="0:4", help=f"start:stop or i,j,k: the cases to run where not yet stored "
                                                  f"(none: only the page; --full: {FULL['cases']})")
    ap.add_argument("--out", type=Path, default=runner.REPO / "runs" / "diagnosis-motions",
                    help="folder of the cases' runs and of the tasks' bank (out/bank)")
    ap.add_argument("--train", action="store_true", help="train the lift, wipe and fling tasks first (resumes)")
    ap.add_argument("--workers", type=int, default=None)


def suite(a: argparse.Namespace) -> dict[str, Any]:
    """Train when asked, run the cases not yet stored, then the page from every stored row.

    Raises:
        SystemExit: one line for bad ``--cases``, before any work."""
    from benchmarks.diagnosis import _indices
    idx = [] if a.cases == "none" else _indices(a.cases, "--cases")
    if bad := [i for i in idx if not 0 <= i < N_CASES]:
        raise SystemExit(f"--cases {a.cases}: the split has cases 0 to {N_CASES - 1} (not {bad[0]})")
    if a.train:
        train(a.out, a.workers)
    if idx:
        run(idx, a.out, a.workers, a.command)
    rows = read_rows(RESULTS)
    if not rows:
        return {"notes": [f"No case is stored yet: `python -m benchmarks run diagnosis-motions --train --full --out "
                          f"OUTSIDE` runs the split ({N_CASES} cases; it resumes)."]}
    return {**report(s := summary(rows, informed_by_lift())), "data": s}


def informed_by_lift() -> list[str]:
    """The shipped effects the trained lift informs, from the diagnosis suite's stored training reports."""
    from benchmarks.diagnosis import TASK_RESULTS
    from softsbi.core.defaults import INFORMED_MAX_RATIO
    from softsbi.plugins import registry
    if not TASK_RESULTS.is_file():
        return []
    models = json.loads(TASK_RESULTS.read_text())["models"]
    out = []
    for e in EFFECTS:
        m = models.get(f"nominal+{e}")
        if m is None:
            continue
        own = {p.name for p in registry().effect(e)().param_space()}
        if any(w is not None and w <= INFORMED_MAX_RATIO for n, w in m["width_ratio"].items() if n in own):
            out.append(e)
    return out


__all__ = ["COUNTS", "MAX_MOTIONS", "make_case", "report", "run", "run_case", "summary"]
