"""The diagnosis suite: how often ``check`` + ``diagnose`` are right, under a frozen rule, on the demo's lift task
trained once with every shipped candidate, on recordings it never saw.

*The task* is the demo's: the built-in lift on mujoco-flex with the fit's defaults. ``--train`` trains it first into
``--out/bank`` (``softsbi task train``'s workflow with its defaults: the nominal model and every shipped candidate,
each with check's replicates; a model already stored is read, so training resumes). Every case's fit then stops at
the trained task, and its diagnosis scores the trained candidates by their amortised posteriors.

*Cases* are lift recordings at prior draws (uniform over every parameter's prior), case ``i`` of a split fixed by
the split's seed and ``i``. A split holds :data:`~benchmarks.diagnosis_protocol.COUNTS` cases, their labels in an
order shuffled by the split's seed (:func:`~benchmarks.diagnosis_protocol.schedule`), so that any first cases mix
them: *controls* (the nominal model is true; right: ``nothing-missing``), one shipped effect hidden (right: the
verdict names that effect alone) and recordings simulated by *the other engine* (pybullet-massspring, fitted with
the same mujoco-flex task; right: ``misspecified-unexplained``). A hidden effect's *magnitude* is the fraction of the
way from its switched-off value (``nominal()``) to an edge of its prior, for every parameter of the effect (the edge
is drawn when the off value lies inside the prior, else the far one); the effect's *on range* is that way, and a
case's magnitude is drawn uniformly from its upper two thirds (:data:`~benchmarks.diagnosis_protocol.MAGNITUDES`).

*Each case* fits the nominal model (``softsbi fit``'s defaults: the trained task's posterior), checks it and
diagnoses it with the CLI's defaults (every installed effect the engine applies as a candidate: :func:`family`), each
step timed. Cases of
``--sequential`` (default: the split's first 4 controls and first 8 hidden-effect cases) are also run on the path a
user has without a trained task: the same recording fitted in sequential rounds (the fit's defaults) with a bank of
its own, checked and diagnosed with sequential refits; the row holds both.

Usage:
    python -m benchmarks run diagnosis --split test --train --full --out OUTSIDE/diagnosis [--workers 2]
    python -m benchmarks run diagnosis --split test --cases none    # the summary of the stored rows only
    python -m benchmarks run diagnosis --development --out OUTSIDE/diagnosis   # the test split's failures, rerun
Rows go to ``benchmarks/results/diagnosis-<split>.jsonl``, one per case as it finishes, with its commit, machine,
command and ``settings``. A case whose latest row is ``ok`` is skipped, one whose latest row is an ``error`` is run
again, so a run resumes; a run refuses, before any case, a rows file whose rows were run under other settings. The
suite's result is the summary of every stored row of each split (:mod:`benchmarks.diagnosis_protocol`).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from softsbi.core.defaults import DiagnoseSettings
from softsbi.plugins import registry
from softsbi.scenarios.builtin import lift_scenario
from softsbi.workflows.criticism.check import check_run
from softsbi.workflows.criticism.diagnose import diagnose_run
from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording

from benchmarks import runner
from benchmarks.diagnosis_protocol import (COUNTS, EFFECTS, MAGNITUDES, N_CASES, development_cases, development_table,
                                           done_ids, outcome, read_rows, report, schedule, sequential_cases,
                                           settings_conflict, summary)

RESULTS = runner.RESULTS
#: what the trained task learned, per model (its training reports), kept beside the rows: the bank lies outside the
#: repository, and the page is written from stored results
TASK_RESULTS = RESULTS / "diagnosis-task.json"
#: the development cases' rows (``--development``): the test split's failure cases rerun under a later rule
DEVELOPMENT = RESULTS / "diagnosis-development.jsonl"
SPLIT_SEEDS = {"dev": 0, "test": 1}
ENGINE, OTHER_ENGINE = "mujoco-flex", "pybullet-massspring"
#: the settings of ``diagnose_run`` that decide a verdict, at its defaults, passed explicitly (so a row records what
#: the diagnosis used)
DIAGNOSE = {k: v for k, v in dataclasses.asdict(DiagnoseSettings()).items() if k != "workers"}


def make_case(split: str, i: int) -> dict[str, Any]:
    """Case ``i`` of ``split``: ``id``, ``split``, ``index``, ``label`` (``control``, ``other-engine`` or the hidden
    effect), ``seed`` (of its draws; the recording's is ``1000 + i``), ``truth`` (physical units: the engine's
    parameters at a prior draw and the hidden effect's) and ``magnitude`` (None without a hidden effect)."""
    return case_at(split, SPLIT_SEEDS[split], i, COUNTS)


def case_at(split: str, split_seed: int, i: int, counts: dict[str, int]) -> dict[str, Any]:
    """Case ``i`` of a split of seed ``split_seed`` and ``counts`` (:func:`make_case`; the motions split's too)."""
    seed = [split_seed, i, 41]
    rng = np.random.default_rng(seed)
    label = schedule(split_seed, counts)[i]
    reg = registry()
    engine = OTHER_ENGINE if label == "other-engine" else ENGINE
    space = reg.simulator(engine)().param_space(lift_scenario(None))
    truth = space.as_dict(space.from_unit(rng.uniform(0.0, 1.0, space.dim)))
    magnitude = None
    if label not in ("control", "other-engine"):
        magnitude = float(rng.uniform(*MAGNITUDES))
        eff = reg.effect(label)()
        es, nom = eff.param_space(), eff.nominal()
        for p in es:
            ps1 = es.subset([p.name])
            u0 = float(ps1.to_unit(np.array([nom[p.name]]))[0])
            edge = (1.0 if rng.random() < 0.5 else 0.0) if 0.05 < u0 < 0.95 else (1.0 if u0 <= 0.05 else 0.0)
            truth[p.name] = float(ps1.from_unit(np.array([u0 + magnitude * (edge - u0)]))[0])
    return {"id": f"{split}-{i}", "split": split, "index": i, "label": label, "seed": seed, "truth": truth,
            "magnitude": magnitude}


def fit_config(bank: Path, workers: int | None) -> FitConfig:
    """A case's nominal fit: ``softsbi fit``'s defaults with the simulation bank ``bank`` (the trained task's, or
    the sequential path's own)."""
    return FitConfig(workers=workers, sim_bank=str(bank))


def measurement(case: dict[str, Any]):
    """The case's simulated recording (the lift; its engine and hidden effect by its label)."""
    hidden = [] if case["label"] in ("control", "other-engine") else [case["label"]]
    engine = OTHER_ENGINE if case["label"] == "other-engine" else ENGINE
    return simulate_recording(engine, lift_scenario(None), case["truth"], effects=hidden, seed=1000 + case["index"])


def settings() -> dict[str, Any]:
    """What decides a row besides its case index, as stored JSON: ``fit`` (:class:`FitConfig` of the nominal fit but
    its bank and workers), ``estimator_options`` (the estimator's defaults with the fit's options over them),
    ``diagnose`` (the candidates and :data:`DIAGNOSE`) and ``cases`` (the task, the engines, the counts and the
    magnitudes)."""
    fit = asdict(fit_config(Path("bank"), None))
    for k in ("sim_bank", "workers", "seed"):
        fit.pop(k)
    est = registry().estimator(fit["estimator"])
    options = {**(est.defaults() if hasattr(est, "defaults") else {}), **fit["estimator_options"]}
    cases = {"task": f"lift on {ENGINE}, trained with every shipped candidate", "other_engine": OTHER_ENGINE,
             "counts": COUNTS, "magnitudes": list(MAGNITUDES)}
    return json.loads(json.dumps(runner.portable({"fit": fit, "estimator_options": options,
                                                  "diagnose": {"family": family(), **DIAGNOSE}, "cases": cases})))


def family() -> list[str]:
    """The candidate family ``diagnose`` uses by default on the task: every installed effect mujoco-flex applies,
    generic force terms included (the hidden effects, :data:`~benchmarks.diagnosis_protocol.EFFECTS`, are its
    non-generic ones)."""
    reg = registry()
    return [n for n in reg.simulator(ENGINE).effects if n in reg.tables["effect"]]


def diagnose_case(case: dict[str, Any], run_dir: Path, bank: Path, workers: int | None) -> dict[str, Any]:
    """Fit, check and diagnose one case's recording into ``run_dir`` with the bank ``bank``, each step timed: the
    verdict, the named effects, check's p-value, the nominal and every candidate's score with its standard error
    (the amortised ones and the refits'), the refits (with their added effects' estimates: interval, off ratio,
    possibly off), and ``fit_s``, ``check_s``, ``diagnose_s``."""
    settings_ = DiagnoseSettings(**DIAGNOSE, workers=workers)
    t0 = time.perf_counter()
    run_fit(run_dir, measurement(case), fit_config(bank, workers), make_plots=False)
    t1 = time.perf_counter()
    check_run(run_dir, plot=False, settings=settings_.check())
    t2 = time.perf_counter()
    d = diagnose_run(run_dir, settings=settings_, plots=False)
    t3 = time.perf_counter()

    def score(s):
        return None if s is None else [s.value, s.se, s.n]

    named = d.refit(d.decision.named) if d.decision.named else None
    return {"verdict": d.verdict, "named": list(d.decision.named),
            "alternatives": [list(a) for a in d.decision.alternatives], "partial": list(d.decision.partial),
            "p_value": d.test.p_value, "n_null": d.test.n_null, "score_nominal": score(d.nominal),
            "score_named": score(named.score) if named is not None else None,
            "amortised": {c.effect: score(c.amortised) for c in d.ranking if c.amortised is not None},
            "refits": [{"effects": list(r.effects), "adequate": r.adequate, "p_value": r.test.p_value,
                        "refined": r.refined_from is not None,
                        "score": score(r.score), "chamfer_m": r.chamfer_m, "amortised": r.amortised,
                        "estimates": {e.name: {"q05": e.q05, "q95": e.q95, "off_ratio": e.off_ratio,
                                               "may_be_off": e.may_be_off} for e in r.estimates}}
                       for r in d.refits],
            "outcome": outcome(case["label"], d.verdict, d.decision.named, d.decision.alternatives),
            "fit_s": t1 - t0, "check_s": t2 - t1, "diagnose_s": t3 - t2}


def run_case(case: dict[str, Any], out: Path, workers: int | None, sequential: bool) -> dict[str, Any]:
    """One case on the trained task (``out/<id>/nominal``, bank ``out/bank``) and, with ``sequential``, on the
    sequential path (``out/<id>/sequential``, bank ``out/sequential-bank``). The row's fields."""
    t0 = time.perf_counter()
    row: dict[str, Any] = dict(case)
    row.update(diagnose_case(case, out / case["id"] / "nominal", out / "bank", workers), status="ok")
    if sequential:
        try:
            row["sequential"] = diagnose_case(case, out / case["id"] / "sequential", out / "sequential-bank",
                                              workers)
        except Exception as e:  # noqa: BLE001  its failure is the path's, not the case's
            row["sequential"] = {"error": f"{type(e).__name__}: {e}"}
    row["wall_s"] = time.perf_counter() - t0
    return row


def train(out: Path, workers: int | None, say=print) -> float:
    """Train the demo's lift task into ``out/bank`` (``softsbi task train``'s defaults: the nominal model and every
    shipped candidate, with check's replicates; stored models are read). Its wall time (s)."""
    from softsbi.workflows.tasks.training import train_task
    from softsbi.workflows.demo import demo_recording
    t0 = time.perf_counter()
    rec, _ = demo_recording(quick=True)
    train_task(rec, fit_config(out / "bank", workers), message=say)
    return time.perf_counter() - t0


def task_record(bank: Path) -> dict[str, Any] | None:
    """What the task trained in ``bank`` learned, per model with a training report: ``n_prior``, ``replicates``
    (check's calibration; 0 without), ``verdict`` (calibration on held-out prior simulations) and ``width_ratio``
    (per parameter, the median over held-out prior simulations of its 90% interval's width over the prior's). None
    unless the bank holds every model of the task (the nominal one and one per shipped effect,
    :data:`~benchmarks.diagnosis_protocol.EFFECTS`: ``task train`` trains no generic force term)."""
    from softsbi.workflows.criticism.check_null import NULL_FILE
    from softsbi.workflows.fit.task_store import TaskStore
    models = {}
    for t in TaskStore(bank / "tasks").list():
        if t.report is None or t.identity.get("backend", ENGINE) != ENGINE:
            continue
        null = t.path / NULL_FILE
        models[t.model] = {"n_prior": t.n_prior, "verdict": t.report.verdict,
                           "replicates": len(json.loads(null.read_text())["statistics"]) if null.is_file() else 0,
                           "width_ratio": {k: c.width_ratio for k, c in t.report.contraction.items()}}
    need = {"nominal", *(f"nominal+{e}" for e in EFFECTS)}
    return dict(sorted(models.items())) if need <= set(models) else None


def run(split: str, indices: Sequence[int], out: Path, workers: int | None, command: str,
        path: Path | None = None, sequential: Sequence[int] | None = None) -> None:
    """Run the cases of ``indices`` whose latest row in ``path`` (default ``results/diagnosis-<split>.jsonl``) is
    not ``ok`` (none, or an error: run again); append each row as it finishes, ``status`` ``ok`` or ``error``, with
    the commit, machine, command and :func:`settings`. The cases of ``sequential`` (default
    :func:`~benchmarks.diagnosis_protocol.sequential_cases`) also run the sequential path.

    Raises:
        SystemExit: before any case runs, when ``path`` holds rows of other (or unknown) settings
            (:func:`~benchmarks.diagnosis_protocol.settings_conflict`).
    """
    path = path or RESULTS / f"diagnosis-{split}.jsonl"
    seq = set(sequential_cases(SPLIT_SEEDS[split]) if sequential is None else sequential)
    append_rows(path, [make_case(split, i) for i in indices],
                lambda case: run_case(case, out, workers, case["index"] in seq), command, settings(),
                lambda row: {k: row.get(k) for k in ("id", "label", "verdict", "named", "outcome", "wall_s", "error")})


def append_rows(path: Path, cases: Sequence[dict[str, Any]], run_one: Callable[[dict[str, Any]], dict[str, Any]],
                command: str, settings_: dict[str, Any], shown: Callable[[dict[str, Any]], Any]) -> None:
    """Run each of ``cases`` whose latest row in ``path`` is not ``ok`` (none, or an error: run again) by ``run_one``
    (its row), and append each row as it finishes, with the commit, machine, ``command`` and ``settings_``; a case
    that raises is a row of ``status`` ``error`` with its error, and the run goes on. ``shown(row)``: the line
    printed (JSON, on stderr) per row. The rows loop of every resumable split (this suite's, the motions split's).

    Raises:
        SystemExit: before any case runs, when ``path`` holds rows of other (or unknown) settings
            (:func:`~benchmarks.diagnosis_protocol.settings_conflict`).
    """
    stored = read_rows(path)
    done = done_ids(stored)
    prov = {**runner.commit(), "machine": runner.machine(), "command": command, "settings": settings_}
    todo = [case for case in cases if case["id"] not in done]
    if todo and (problem := settings_conflict(stored, prov["settings"], runner.portable(path))):
        raise SystemExit(problem)
    for case in todo:
        try:
            row = run_one(case)
        except Exception as e:  # noqa: BLE001  a case that fails is a row with its error, and the run goes on
            row = {**case, "status": "error", "error": f"{type(e).__name__}: {e}"}
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("a") as f:
            f.write(json.dumps({**row, **prov}) + "\n")
        print(json.dumps(shown(row)), file=sys.stderr, flush=True)


#: ``--full``: every case of the split (:data:`~benchmarks.diagnosis_protocol.COUNTS`)
FULL = {"cases": f"0:{N_CASES}"}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--split", choices=sorted(SPLIT_SEEDS), default="test")
    ap.add_argument("--cases", default="0:12", help="start:stop or i,j,k: the cases to run where not yet stored "
                                                   f"(none: only summarise the stored rows; --full: {FULL['cases']})")
    ap.add_argument("--out", type=Path, default=runner.REPO / "runs" / "diagnosis",
                    help="folder of the cases' runs and of the trained task's bank (out/bank)")
    ap.add_argument("--train", action="store_true", help="train the lift task into out/bank first (resumes)")
    ap.add_argument("--sequential", default=None,
                    help="i,j,k: the cases also run on the sequential path (default: the split's first 4 controls "
                         "and first 8 hidden-effect cases; none: no case)")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--results", type=Path, default=None, help="rows file (default results/diagnosis-SPLIT.jsonl)")
    ap.add_argument("--development", action="store_true",
                    help="rerun the test split's failure cases (development_cases) under the current rule into "
                         "results/diagnosis-development.jsonl (resumes), and table them beside their stored verdicts")


def _indices(text: str, flag: str) -> list[int]:
    lo, _, hi = text.partition(":")
    try:
        return list(range(int(lo), int(hi))) if hi else [int(x) for x in text.split(",") if x]
    except ValueError:
        raise SystemExit(f"{flag} {text}: give start:stop, i,j,k or none") from None


def suite(a: argparse.Namespace) -> dict[str, Any]:
    """Train the task when asked, run ``--split``'s cases not yet stored, then summarise every split with stored
    rows (dev, then test).

    Raises:
        SystemExit: one line for bad ``--cases`` or ``--sequential``, before any work.
    """
    path = a.results or RESULTS / f"diagnosis-{a.split}.jsonl"
    idx = [] if a.cases == "none" else _indices(a.cases, "--cases")
    if a.development:  # the test split's failure cases, rerun apart from its rows
        path, a.split = DEVELOPMENT, "test"
        idx = development_cases(read_rows(RESULTS / "diagnosis-test.jsonl"))
    seq = None if a.sequential is None else [] if a.sequential == "none" else _indices(a.sequential, "--sequential")
    bad = [i for i in idx if not 0 <= i < N_CASES]
    if bad:
        raise SystemExit(f"--cases {a.cases}: a split has cases 0 to {N_CASES - 1}")
    if a.train:
        train(a.out, a.workers)
    if (task := task_record(a.out / "bank")) is not None:
        TASK_RESULTS.write_text(json.dumps({**runner.commit(), "models": task}, indent=1) + "\n")
    elif TASK_RESULTS.is_file():
        task = json.loads(TASK_RESULTS.read_text())["models"]
    if idx:
        run(a.split, idx, a.out, a.workers, a.command, path, seq)
    out: dict[str, Any] = {"tables": [], "notes": [], "data": {}}
    for split in SPLIT_SEEDS:
        rows = read_rows(path if split == a.split and not a.development else RESULTS / f"diagnosis-{split}.jsonl")
        if not rows:
            continue
        s = summary(rows, split)
        rep = report(s, split, task)
        out["tables"] += rep["tables"]
        out["notes"] += [f"{split.capitalize()} split: {n}" for n in rep["notes"]]
        out["data"][split] = s
    if (dev := read_rows(DEVELOPMENT)):
        out["tables"].append(development_table(read_rows(RESULTS / "diagnosis-test.jsonl"), dev))
    if not out["data"]:
        out["notes"].append(f"No case is stored yet: the test split runs with `python -m benchmarks run diagnosis "
                            f"--split test --train --full --out OUTSIDE` ({N_CASES} cases; it resumes).")
    return out
