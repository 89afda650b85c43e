"""The diagnosis suite: how often ``diagnose`` is right, under a frozen rule, on cases it was not chosen on.

Cases are measurements simulated by mujoco-flex (grid 7) in a built-in scenario (lift, wipe, fling, winding) at random
parameters (the middle 60% of each prior): *controls* (the nominal model is true; right: ``nothing-missing``), one
shipped effect hidden (right: the effect named, alone or listed as indistinguishable from the named one) or data from
*the other engine* (pybullet-massspring; right: ``misspecified-unexplained``, since no installed effect turns one engine
into the other). Case ``i`` of a split is fixed by the split's seed and ``i``: a cycle of 18 holds 6 controls, one case
of each of the 11 shipped effects and one of the other engine. A hidden effect's magnitude (the fraction of the way
from its switched-off value to an edge of its prior) is uniform from its detection threshold on the development
split (:data:`THRESHOLDS`; 0.5 for an effect no magnitude within the prior detects reliably) to 1.

Splits: ``dev`` (seed 0, the seed of the cases the rule and its knobs were chosen on) and ``test`` (seed 1: fresh
cases, run once under the frozen rule). Each case fits the nominal model (3 rounds x 100 simulations, truncated
proposals), then diagnoses it with every shipped effect as a candidate (refits at the same budget). With ``--old
CHECKOUT`` the same case is first diagnosed by the code in CHECKOUT (e.g. the rules before this one) and the new rule
reuses that nominal fit, so both decide on the same fit.

Usage:
    python -m benchmarks run diagnosis --split test --cases 0:36 [--old ../softsbi-old] [--workers 2]
    python -m benchmarks run diagnosis --split test --cases none    # the summary of the stored rows only
Rows go to ``benchmarks/results/diagnosis-<split>.jsonl`` (one per case, with commit, machine and command); a case
already there is skipped, so a run resumes. The suite's result is the summary of every stored row of the split.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy import stats

from softsbi.plugins import registry
from softsbi.workflows.diagnose import diagnose_run
from softsbi.workflows.fit import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording

from benchmarks import runner

RESULTS = runner.RESULTS
SPLIT_SEEDS = {"dev": 0, "test": 1}
SCENARIOS = ["lift", "wipe", "fling", "winding"]
EFFECTS = ["wind", "air-drag", "extra-damping", "grip-compliance", "table-slope", "sticky-patch", "heavy-hem",
           "calibration-offset", "time-offset", "point-noise", "table-unseen"]
#: one cycle of case labels
CYCLE = ["control"] * 6 + EFFECTS + ["other-engine"]
#: magnitude at which the earlier benchmark's development cases detected the effect in 90% of cases (a logistic fit
#: of detection on magnitude, 38-89 cases per effect); effects it never detected that reliably within their prior
#: start at :data:`DEFAULT_THRESHOLD`
THRESHOLDS = {"calibration-offset": 0.26, "point-noise": 0.37, "wind": 0.36, "time-offset": 0.54,
              "grip-compliance": 0.82}
DEFAULT_THRESHOLD = 0.5
GRID = {"grid": 7}
N_POINTS, N_DENSE = 64, 300
BUDGET = {"rounds": 3, "sims_per_round": 100}


def make_case(split: str, i: int) -> dict[str, Any]:
    """Case ``i`` of ``split``: ``id``, ``split``, ``index``, ``label`` (``control``, ``other-engine`` or the hidden
    effect), ``scenario``, ``truth`` (physical units) and ``magnitude`` (None without a hidden effect)."""
    rng = np.random.default_rng([SPLIT_SEEDS[split], i, 41])
    label = CYCLE[i % len(CYCLE)]
    scen = SCENARIOS[int(rng.integers(len(SCENARIOS)))]
    reg = registry()
    engine = "pybullet-massspring" if label == "other-engine" else "mujoco-flex"
    sc = _scenario(scen)
    space = reg.simulator(engine)(**GRID).param_space(sc)
    truth = space.as_dict(space.from_unit(rng.uniform(0.2, 0.8, space.dim)))
    magnitude = None
    if label not in ("control", "other-engine"):
        magnitude = float(rng.uniform(THRESHOLDS.get(label, DEFAULT_THRESHOLD), 1.0))
        eff = reg.effect(label)()
        es, nom = eff.param_space(), eff.nominal()
        for p in es:
            ps1 = es.subset([p.name])
            u0 = float(ps1.to_unit(np.array([nom[p.name]]))[0])
            edge = (1.0 if rng.random() < 0.5 else 0.0) if 0.05 < u0 < 0.95 else (1.0 if u0 <= 0.05 else 0.0)
            truth[p.name] = float(ps1.from_unit(np.array([u0 + magnitude * (edge - u0)]))[0])
    return {"id": f"{split}-{i}", "split": split, "index": i, "label": label, "scenario": scen, "truth": truth,
            "magnitude": magnitude}


def _scenario(name: str):
    from softsbi.scenarios.builtin import lift_scenario, make_scenario
    return lift_scenario(None) if name == "lift" else make_scenario(name)


def fit_config(case: dict[str, Any], workers: int | None) -> FitConfig:
    """The nominal fit of a case (the same for the old rule's run)."""
    return FitConfig(backend="mujoco-flex", backend_options=GRID, rounds=BUDGET["rounds"],
                     sims_per_round=BUDGET["sims_per_round"], workers=workers, n_points=N_POINTS, n_eval=30,
                     n_dense=N_DENSE, seed=case["index"], proposal="truncated")


def measurement(case: dict[str, Any]):
    """The case's simulated recording."""
    hidden = [] if case["label"] in ("control", "other-engine") else [case["label"]]
    engine = "pybullet-massspring" if case["label"] == "other-engine" else "mujoco-flex"
    return simulate_recording(engine, _scenario(case["scenario"]), case["truth"], backend_options=GRID, effects=hidden,
                              n_points=N_POINTS, n_dense=N_DENSE, seed=1000 + case["index"])


def right(label: str, verdict: str, named: Sequence[str], alternatives: Sequence[Sequence[str]]) -> bool:
    """The scoring rule: a control is right with ``nothing-missing``, the other engine with
    ``misspecified-unexplained``, a hidden effect when the verdict names it alone or lists it alone as
    indistinguishable from the named effect."""
    if label == "control":
        return verdict == "nothing-missing"
    if label == "other-engine":
        return verdict == "misspecified-unexplained"
    return verdict == "missing-effect" and ([label] == list(named) or [label] in [list(a) for a in alternatives])


def run_case(case: dict[str, Any], out: Path, workers: int | None, old: Path | None) -> dict[str, Any]:
    """Diagnose one case (after the old rule's run of it, with ``old``); the row's fields."""
    t0 = time.perf_counter()
    run_dir = out / case["id"] / "nominal"
    row: dict[str, Any] = dict(case)
    if old is not None:
        row["old"] = run_old(case, out / case["id"] / "old", workers, old)
        if (out / case["id"] / "old" / "run.zarr").exists() and not run_dir.exists():
            run_dir.mkdir(parents=True)  # the same nominal fit for both rules
            shutil.copytree(out / case["id"] / "old" / "run.zarr", run_dir / "run.zarr")
            shutil.copy(out / case["id"] / "old" / "report.json", run_dir / "report.json")
    t1 = time.perf_counter()
    run_fit(run_dir, measurement(case), fit_config(case, workers))
    d = diagnose_run(run_dir, effects=EFFECTS, workers=workers)
    named = d.refit(d.decision.named) if d.decision.named else None
    row.update(verdict=d.verdict, named=list(d.decision.named), alternatives=[list(a) for a in d.decision.alternatives],
               partial=list(d.decision.partial), p_value=d.test.p_value, n_null=d.test.n_null,
               refits=[{"effects": list(r.effects), "adequate": r.adequate, "p_value": r.test.p_value,
                        "score": r.score.value if r.score else None, "chamfer_m": r.chamfer_m} for r in d.refits],
               score_nominal=d.nominal.value if d.nominal else None,
               score_named=named.score.value if named and named.score else None,
               right=right(case["label"], d.verdict, d.decision.named, d.decision.alternatives),
               seconds=time.perf_counter() - t1, wall_s=time.perf_counter() - t0)
    return row


#: the old rule's run of one case, in a process of its own whose softsbi is CHECKOUT's
OLD_DRIVER = """
import json, sys
sys.path.insert(0, sys.argv[1] + "/benchmarks")
import diagnose_stats as ds
case, out, workers = json.loads(sys.argv[2]), sys.argv[3], (None if sys.argv[4] == "None" else int(sys.argv[4]))
from pathlib import Path
suite = {"other-engine": "cross-engine", "table-unseen": "table-unseen"}.get(case["label"], "mujoco-more")
scen = {"winding": "wind"}.get(case["scenario"], case["scenario"])  # its name in older code
truth_label = case["label"]
c = {"id": "old", "suite": suite, "index": case["index"], "truth_label": truth_label, "scenario": scen,
     "truth": case["truth"], "magnitude": case["magnitude"]}
row = ds.run_case(c, Path(out), 3, 100, 30, 200, 2, workers, {"rounds": 3, "sims_per_round": 100}, "truncated",
                  0.05, ds.NAMED_CANDIDATES + ["table-unseen"])
print("ROW " + json.dumps({k: row.get(k) for k in ("verdict", "named", "named_all", "alternatives", "wall_s")}))
"""


def run_old(case: dict[str, Any], out: Path, workers: int | None, checkout: Path) -> dict[str, Any]:
    """The old rule's verdict on ``case``: ``diagnose_stats.run_case`` of ``checkout`` in a subprocess, its run in
    ``out`` (``out/old`` holds the nominal fit)."""
    checkout = checkout.resolve()
    env = dict(os.environ, PYTHONPATH=str(checkout))  # and its folder as the working one: `-c` puts that first
    res = subprocess.run([sys.executable, "-c", OLD_DRIVER, str(checkout), json.dumps(case),
                          str(out.parent.resolve()), str(workers)], env=env, cwd=checkout, capture_output=True,
                         text=True)
    line = next((x for x in res.stdout.splitlines() if x.startswith("ROW ")), None)
    if line is None:
        return {"error": (res.stderr or res.stdout)[-800:]}
    r = json.loads(line[4:])
    named = r.get("named_all") or ([r["named"]] if r.get("named") else [])
    alts = [[a] for a in r.get("alternatives") or []]
    return {**r, "right": right(case["label"], r["verdict"], named if r["verdict"] == "missing-effect" else [], alts)}


def run(split: str, indices: Sequence[int], out: Path, workers: int | None, old: Path | None,
        command: str, path: Path | None = None) -> None:
    """Run the cases of ``indices`` not yet stored in ``path`` (default ``results/diagnosis-<split>.jsonl``);
    append each row as it finishes."""
    path = path or RESULTS / f"diagnosis-{split}.jsonl"
    done = {json.loads(x)["id"] for x in path.read_text().splitlines() if x.strip()} if path.exists() else set()
    prov = {**runner.commit(), "machine": runner.machine(), "command": command}
    for i in indices:
        case = make_case(split, i)
        if case["id"] in done:
            continue
        try:
            row = run_case(case, out, workers, old)
        except Exception as e:  # noqa: BLE001  a case that fails is a row with its error, and the run goes on
            row = {**case, "error": f"{type(e).__name__}: {e}"}
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("a") as f:
            f.write(json.dumps({**row, **prov}) + "\n")
        print(json.dumps({k: row.get(k) for k in ("id", "label", "verdict", "named", "right", "wall_s", "error")}),
              file=sys.stderr, flush=True)


def interval(k: int, n: int) -> list[float]:
    """The 95% Clopper-Pearson interval of ``k`` successes in ``n``."""
    if n == 0:
        return [0.0, 1.0]
    ci = stats.binomtest(k, n).proportion_ci(0.95, method="exact")
    return [float(ci.low), float(ci.high)]


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Rates of a split: per label the cases, detections (any verdict but ``nothing-missing``) and right verdicts
    with their 95% intervals, for the new rule and (where stored) the old one on the same cases; the confusion
    of labels and what was called; detection against magnitude; the score's fall in right named cases."""
    ok = [r for r in rows if "verdict" in r]
    out: dict[str, Any] = {"cases": len(rows), "failed": len(rows) - len(ok), "by_label": {}, "confusion": {}}
    for label in ["control", *EFFECTS, "other-engine"]:
        rs = [r for r in ok if r["label"] == label]
        if not rs:
            continue
        k = sum(r["right"] for r in rs)
        entry = {"n": len(rs), "right": k, "right_ci95": interval(k, len(rs)),
                 "detected": sum(r["verdict"] != "nothing-missing" for r in rs)}
        olds = [r["old"] for r in rs if isinstance(r.get("old"), dict) and "verdict" in r["old"]]
        if olds:
            ko = sum(o["right"] for o in olds)
            entry.update(old_n=len(olds), old_right=ko, old_right_ci95=interval(ko, len(olds)))
        out["by_label"][label] = entry
        out["confusion"][label] = dict(Counter("+".join(r["named"]) if r["named"] else r["verdict"] for r in rs))
    ctl = out["by_label"].get("control")
    if ctl:
        out["false_alarms"] = ctl["n"] - ctl["right"]
        out["false_alarm_ci95"] = interval(out["false_alarms"], ctl["n"])
    drops = [1 - r["score_named"] / r["score_nominal"] for r in ok
             if r["right"] and r.get("score_named") and r.get("score_nominal")]
    out["score_drop_median"] = float(np.median(drops)) if drops else None
    eff = [r for r in ok if r.get("magnitude") is not None]
    bins = [(0.25, 0.5), (0.5, 0.75), (0.75, 1.0001)]
    out["detection_by_magnitude"] = {f"{a:.2f}-{min(b, 1):.2f}": [sum(r["verdict"] != "nothing-missing" for r in eff
                                                                       if a <= r["magnitude"] < b),
                                                                   sum(a <= r["magnitude"] < b for r in eff)]
                                     for a, b in bins}
    out["seconds_median"] = float(np.median([r["seconds"] for r in ok])) if ok else None
    return out


def report(s: dict[str, Any], split: str) -> dict[str, Any]:
    """The summary as the suite's tables and notes."""
    rows = []
    for label, e in s["by_label"].items():
        old = ([f"{e['old_right']} of {e['old_n']}", f"{e['old_right_ci95'][0]:.2f}-{e['old_right_ci95'][1]:.2f}"]
               if "old_n" in e else [None, None])
        rows.append([label, e["n"], e["detected"], e["right"], f"{e['right_ci95'][0]:.2f}-{e['right_ci95'][1]:.2f}",
                     *old])
    if not s["cases"]:
        return {"tables": [], "notes": [f"No case of the {split} split is stored yet."]}
    notes = [f"{s['cases']} cases ({s['failed']} failed to run). False alarms: "
             + (f"{s['false_alarms']} of {s['by_label']['control']['n']} controls (95% interval "
                f"{s['false_alarm_ci95'][0]:.2f}-{s['false_alarm_ci95'][1]:.2f})." if "false_alarms" in s else "-"),
             "What was called, per truth: " + "; ".join(f"{k}: " + ", ".join(f"{c} {n}" for c, n in v.items())
                                                       for k, v in s["confusion"].items()) + ".",
             "Detected against magnitude: " + ", ".join(f"{k}: {d} of {n}" for k, (d, n)
                                                       in s["detection_by_magnitude"].items()) + "."]
    if s.get("score_drop_median") is not None:
        notes.append(f"Median fall of the energy score of the summaries from the nominal fit to the named refit, right "
                     f"cases: {s['score_drop_median'] * 100:.0f}%.")
    return {"tables": [runner.table(f"Diagnosis, {split} split: right verdicts per truth",
                                    ["truth", "cases", "detected", "right (this rule)", "95% interval",
                                     "right (old rules, same cases)", "95% interval"], rows)],
            "notes": notes}


FULL = {"cases": "0:36"}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--split", choices=sorted(SPLIT_SEEDS), default="test")
    ap.add_argument("--cases", default="0:18", help="start:stop or i,j,k: the cases to run where not yet stored "
                                                   "(none: only summarise the stored rows)")
    ap.add_argument("--out", type=Path, default=runner.REPO / "runs" / "diagnosis", help="folder of the cases' runs")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--old", type=Path, default=None, help="a checkout whose rules diagnose the same cases first")
    ap.add_argument("--results", type=Path, default=None, help="rows file (default results/diagnosis-SPLIT.jsonl)")


def suite(a: argparse.Namespace) -> dict[str, Any]:
    """Run ``--split``'s cases not yet stored, then summarise every split with stored rows (dev, then test)."""
    path = a.results or RESULTS / f"diagnosis-{a.split}.jsonl"
    if a.cases != "none":
        lo, _, hi = a.cases.partition(":")
        idx = range(int(lo), int(hi)) if hi else [int(x) for x in a.cases.split(",")]
        run(a.split, idx, a.out, a.workers, a.old, a.command, path)
    out: dict[str, Any] = {"tables": [], "notes": [], "data": {}}
    for split in SPLIT_SEEDS:
        p = path if split == a.split else RESULTS / f"diagnosis-{split}.jsonl"
        rows = [json.loads(x) for x in p.read_text().splitlines() if x.strip()] if p.exists() else []
        if not rows:
            continue
        s = summary(rows)
        rep = report(s, split)
        commits = Counter(r.get("commit", "unknown") for r in rows)
        rep["notes"].append("Rows measured at " + ", ".join(f"commit `{c}` ({n})" for c, n in commits.items()) + ".")
        out["tables"] += rep["tables"]
        out["notes"] += [f"{split.capitalize()} split: {n}" for n in rep["notes"]]
        out["data"][split] = s
    return out
