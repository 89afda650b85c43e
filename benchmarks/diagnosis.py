"""The diagnosis suite: how often ``diagnose`` is right, under a frozen rule, on cases it was not chosen on.

Cases are measurements simulated by mujoco-flex (grid 7) in a built-in scenario (lift, wipe, fling, winding) at random
parameters (the middle 60% of each prior): *controls* (the nominal model is true; right: ``nothing-missing``), one
shipped effect hidden (right: the verdict names that effect alone; listed as indistinguishable from the named one is
counted apart, not as right) or data from *the other engine* (pybullet-massspring; right:
``misspecified-unexplained``, since no installed effect turns one engine into the other). Case ``i`` of a split is
fixed by the split's seed, ``i`` and the threshold table: a cycle of 18 holds 6 controls, one case of each of the 11
shipped effects and one of the other engine. A hidden effect's magnitude (the fraction of the way from its
switched-off value to an edge of its prior) is uniform from its detection threshold (``--thresholds FILE``, default
:data:`~benchmarks.diagnosis_protocol.THRESHOLDS`; an effect without a measured one starts at an unmeasured
placeholder, which the summary names) to 1.

Splits: ``dev`` (seed 0, the seed of the cases the rule and its knobs were chosen on) and ``test`` (seed 1: fresh
cases, run once under the frozen rule). ``--full`` runs cases 0:180, ten cycles: the test split's minimums (60
controls, 10 cases per shipped effect, 10 of the other engine). Each case fits the nominal model (3 rounds x 100
simulations, truncated proposals), then diagnoses it with every shipped effect as a candidate (refits at the same
budget). With ``--old CHECKOUT`` a copy of that same nominal fit is diagnosed by CHECKOUT's ``diagnose_run`` (its own
rule and defaults) in a process whose softsbi is CHECKOUT's; the row holds both verdicts.

Usage:
    python -m benchmarks run diagnosis --split test --full [--old ../softsbi-old] [--workers 2]
    python -m benchmarks run diagnosis --split test --cases none    # the summary of the stored rows only
Rows go to ``benchmarks/results/diagnosis-<split>.jsonl`` (one per case run, with its commit, machine, command and
``settings``: the fit's, the estimator's options with its recalibration, the diagnosis's, the cases'). A case whose
latest row is ``ok`` is skipped, one whose latest row is an ``error`` is run again, so a run resumes; a run refuses,
before any case, a rows file whose rows were run under other settings (or record none). The suite's
result is the summary of every stored row of each split (:mod:`benchmarks.diagnosis_protocol`: strict scoring,
errors counted as wrong, rows of differing settings refused, the acceptance figures against their targets).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from softsbi.plugins import registry
from softsbi.workflows.criticism.diagnose import diagnose_run
from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording

from benchmarks import runner
from benchmarks.diagnosis_protocol import (CYCLE, DEFAULT_THRESHOLD, EFFECTS, THRESHOLDS, cases_for_minimums,
                                           done_ids, load_thresholds, outcome, read_rows, report, settings_conflict,
                                           summary, threshold)
from softsbi.core.defaults import DiagnoseSettings

RESULTS = runner.RESULTS
SPLIT_SEEDS = {"dev": 0, "test": 1}
SCENARIOS = ["lift", "wipe", "fling", "winding"]
GRID = {"grid": 7}
N_POINTS, N_DENSE = 64, 300
BUDGET = {"rounds": 3, "sims_per_round": 100}
#: the settings of ``diagnose_run`` that decide a verdict, at its defaults, passed explicitly (so a row records what
#: the diagnosis used)
DIAGNOSE = {k: v for k, v in dataclasses.asdict(DiagnoseSettings()).items() if k != "workers"}
#: files of a run directory that a diagnosis writes: left out of the copy the old rule diagnoses
DIAGNOSIS_FILES = ("check.json*", "diagnosis.json*", "refit-*")


def make_case(split: str, i: int, thresholds: Mapping[str, float | None] = THRESHOLDS) -> dict[str, Any]:
    """Case ``i`` of ``split``: ``id``, ``split``, ``index``, ``label`` (``control``, ``other-engine`` or the hidden
    effect), ``scenario``, ``truth`` (physical units) and ``magnitude`` (None without a hidden effect; from the
    effect's entry of ``thresholds``, or :data:`DEFAULT_THRESHOLD` where it has none, to 1)."""
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
        magnitude = float(rng.uniform(threshold(thresholds, label), 1.0))
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
    """The nominal fit of a case (with ``--old``, the old rule diagnoses a copy of it)."""
    return FitConfig(backend="mujoco-flex", backend_options=GRID, rounds=BUDGET["rounds"],
                     sims_per_round=BUDGET["sims_per_round"], workers=workers, n_points=N_POINTS, n_eval=30,
                     n_dense=N_DENSE, seed=case["index"], proposal="truncated")


def measurement(case: dict[str, Any]):
    """The case's simulated recording."""
    hidden = [] if case["label"] in ("control", "other-engine") else [case["label"]]
    engine = "pybullet-massspring" if case["label"] == "other-engine" else "mujoco-flex"
    return simulate_recording(engine, _scenario(case["scenario"]), case["truth"], backend_options=GRID, effects=hidden,
                              n_points=N_POINTS, n_dense=N_DENSE, seed=1000 + case["index"])


def settings(thresholds: Mapping[str, float | None] = THRESHOLDS) -> dict[str, Any]:
    """What decides a row besides its case index, as stored JSON: ``fit`` (:class:`FitConfig` of the nominal fit but
    its per-case seed and the workers), ``estimator_options`` (the estimator's defaults with the fit's options over
    them: the recalibration among them), ``diagnose`` (the candidates and :data:`DIAGNOSE`) and ``cases`` (engine
    options, points, scenarios, cycle, the threshold table and its placeholder)."""
    fit = asdict(fit_config({"index": 0}, None))
    fit.pop("seed"), fit.pop("workers")
    est = registry().estimator(fit["estimator"])
    options = {**(est.defaults() if hasattr(est, "defaults") else {}), **fit["estimator_options"]}
    cases = {"grid": GRID, "n_points": N_POINTS, "n_dense": N_DENSE, "scenarios": SCENARIOS, "cycle": CYCLE,
             "thresholds": dict(thresholds), "placeholder": DEFAULT_THRESHOLD}
    return json.loads(json.dumps(runner.portable({"fit": fit, "estimator_options": options,
                                                  "diagnose": {"effects": EFFECTS, **DIAGNOSE}, "cases": cases})))


def run_case(case: dict[str, Any], out: Path, workers: int | None, old: Path | None) -> dict[str, Any]:
    """Fit and diagnose one case (in ``out/<id>/nominal``); with ``old``, CHECKOUT's rule diagnoses a copy of the
    same nominal fit (``out/<id>/old-rule``, made before this rule's diagnosis writes anything). The row's fields."""
    t0 = time.perf_counter()
    run_dir = out / case["id"] / "nominal"
    row: dict[str, Any] = dict(case)
    run_fit(run_dir, measurement(case), fit_config(case, workers))
    if old is not None:
        copy = out / case["id"] / "old-rule"
        if not copy.exists():  # through a temporary name: a copy cut short is made again
            tmp = copy.with_name(copy.name + ".tmp")
            shutil.rmtree(tmp, ignore_errors=True)
            shutil.copytree(run_dir, tmp, ignore=shutil.ignore_patterns(*DIAGNOSIS_FILES))
            tmp.rename(copy)
    t1 = time.perf_counter()
    d = diagnose_run(run_dir, effects=EFFECTS, settings=DiagnoseSettings(**DIAGNOSE, workers=workers))
    named = d.refit(d.decision.named) if d.decision.named else None
    row.update(status="ok", verdict=d.verdict, named=list(d.decision.named),
               alternatives=[list(a) for a in d.decision.alternatives], partial=list(d.decision.partial),
               p_value=d.test.p_value, n_null=d.test.n_null,
               refits=[{"effects": list(r.effects), "adequate": r.adequate, "p_value": r.test.p_value,
                        "score": r.score.value if r.score else None, "chamfer_m": r.chamfer_m} for r in d.refits],
               score_nominal=d.nominal.value if d.nominal else None,
               score_named=named.score.value if named and named.score else None,
               outcome=outcome(case["label"], d.verdict, d.decision.named, d.decision.alternatives),
               seconds=time.perf_counter() - t1)
    if old is not None:
        row["old"] = run_old(out / case["id"] / "old-rule", workers, old)
    row["wall_s"] = time.perf_counter() - t0
    return row


#: the old rule's diagnosis of a run, in a process of its own whose softsbi is CHECKOUT's (its own defaults)
OLD_DRIVER = """
import json, sys
from softsbi.workflows.criticism.diagnose import diagnose_run
d = diagnose_run(sys.argv[1], effects=json.loads(sys.argv[2]), workers=json.loads(sys.argv[3]))
named = d.decision.named
print("ROW " + json.dumps({"verdict": d.verdict, "named": [named] if isinstance(named, str) else list(named or []),
                           "alternatives": [[a] if isinstance(a, str) else list(a) for a in d.decision.alternatives],
                           "p_value": d.test.p_value}))
"""


def run_old(run_dir: Path, workers: int | None, checkout: Path) -> dict[str, Any]:
    """CHECKOUT's verdict on the run in ``run_dir`` (a copy of this rule's nominal fit): ``verdict``, ``named``,
    ``alternatives``, ``p_value``, ``commit`` (CHECKOUT's), ``wall_s``; ``error`` (the tail of its output) instead
    of the verdict where it failed."""
    checkout = checkout.resolve()
    env = dict(os.environ, PYTHONPATH=str(checkout))  # and its folder as the working one: `-c` puts that first
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", OLD_DRIVER, str(run_dir.resolve()), json.dumps(EFFECTS),
                          json.dumps(workers)], env=env, cwd=checkout, capture_output=True, text=True)
    head = subprocess.run(["git", "rev-parse", "--short=10", "HEAD"], cwd=checkout, capture_output=True, text=True)
    info = {"commit": head.stdout.strip() if head.returncode == 0 else "unknown", "wall_s": time.perf_counter() - t0}
    line = next((x for x in res.stdout.splitlines() if x.startswith("ROW ")), None)
    if line is None:
        return {**info, "error": (res.stderr or res.stdout)[-800:]}
    return {**info, **json.loads(line[4:])}


def run(split: str, indices: Sequence[int], out: Path, workers: int | None, old: Path | None,
        command: str, path: Path | None = None, thresholds: Mapping[str, float | None] = THRESHOLDS) -> None:
    """Run the cases of ``indices`` whose latest row in ``path`` (default ``results/diagnosis-<split>.jsonl``) is
    not ``ok`` (none, or an error: run again); append each row as it finishes, ``status`` ``ok`` or ``error``, with
    the commit, machine, command and :func:`settings`.

    Raises:
        SystemExit: before any case runs, when ``path`` holds rows of other (or unknown) settings
            (:func:`~benchmarks.diagnosis_protocol.settings_conflict`).
    """
    path = path or RESULTS / f"diagnosis-{split}.jsonl"
    stored = read_rows(path)
    done = done_ids(stored)
    prov = {**runner.commit(), "machine": runner.machine(), "command": command, "settings": settings(thresholds)}
    todo = [i for i in indices if f"{split}-{i}" not in done]
    if todo and (problem := settings_conflict(stored, prov["settings"], runner.portable(path))):
        raise SystemExit(problem)
    for i in todo:
        case = make_case(split, i, thresholds)
        try:
            row = run_case(case, out, workers, old)
        except Exception as e:  # noqa: BLE001  a case that fails is a row with its error, and the run goes on
            row = {**case, "status": "error", "error": f"{type(e).__name__}: {e}"}
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("a") as f:
            f.write(json.dumps({**row, **prov}) + "\n")
        print(json.dumps({k: row.get(k) for k in ("id", "label", "verdict", "named", "outcome", "wall_s", "error")}),
              file=sys.stderr, flush=True)


#: ``--full``: ten cycles, the test split's minimums (:data:`~benchmarks.diagnosis_protocol.MINIMUMS`)
FULL = {"cases": f"0:{cases_for_minimums()}"}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--split", choices=sorted(SPLIT_SEEDS), default="test")
    ap.add_argument("--cases", default="0:18", help="start:stop or i,j,k: the cases to run where not yet stored "
                                                   f"(none: only summarise the stored rows; --full: {FULL['cases']}, "
                                                   "the test split's minimums)")
    ap.add_argument("--out", type=Path, default=runner.REPO / "runs" / "diagnosis", help="folder of the cases' runs")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--old", type=Path, default=None, help="a checkout whose rule diagnoses a copy of each case's "
                                                           "nominal fit")
    ap.add_argument("--results", type=Path, default=None, help="rows file (default results/diagnosis-SPLIT.jsonl)")
    ap.add_argument("--thresholds", type=Path, default=None,
                    help="JSON {effect: detection threshold or null (not measured)} naming every shipped effect "
                         "(default: the table in benchmarks/diagnosis_protocol.py)")


def suite(a: argparse.Namespace) -> dict[str, Any]:
    """Run ``--split``'s cases not yet stored, then summarise every split with stored rows (dev, then test).

    Raises:
        SystemExit: one line for a bad ``--thresholds`` file, ``--old`` folder or ``--cases``, before any case runs.
    """
    thresholds = load_thresholds(a.thresholds) if a.thresholds else THRESHOLDS
    if a.old is not None and not (a.old / "softsbi").is_dir():
        raise SystemExit(f"--old {a.old}: not a softsbi checkout (no softsbi/ folder in it)")
    path = a.results or RESULTS / f"diagnosis-{a.split}.jsonl"
    if a.cases != "none":
        lo, _, hi = a.cases.partition(":")
        try:
            idx = range(int(lo), int(hi)) if hi else [int(x) for x in a.cases.split(",")]
        except ValueError:
            raise SystemExit(f"--cases {a.cases}: give start:stop, i,j,k or none") from None
        run(a.split, idx, a.out, a.workers, a.old, a.command, path, thresholds)
    out: dict[str, Any] = {"tables": [], "notes": [], "data": {}}
    for split in SPLIT_SEEDS:
        rows = read_rows(path if split == a.split else RESULTS / f"diagnosis-{split}.jsonl")
        if not rows:
            continue
        s = summary(rows, split)
        rep = report(s, split)
        out["tables"] += rep["tables"]
        out["notes"] += [f"{split.capitalize()} split: {n}" for n in rep["notes"]]
        out["data"][split] = s
    return out
