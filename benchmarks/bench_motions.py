"""The motions suite: which shipped effects each built-in motion informs, from trained tasks' reports.

Each motion's task (the built-in lift of the demo, the wipe and the fling on mujoco-flex, the nominal model and every
shipped candidate, ``--prior-sims`` prior and ``--n-test`` held-out simulations each) is read from ``--bank``; with
``--train`` the missing models are trained first (``softsbi task train`` without replicate recordings: the reports
are all this table reads; a resumable run, since every trained model is stored). A motion *informs* an effect when
its trained model's median 90% interval of the effect's best-informed parameter over its prior's, on the held-out
prior simulations, is at most ``INFORMED_MAX_RATIO`` (the training report's criterion, the one ``diagnose`` and
``design`` read).

Beside it, ``softsbi design``'s estimate for the same cells as it stands where a motion has no trained task: the
linear estimate at a fit of the demo's lift (its trained task, one round), scaled by the lift's own trained widths
over its bounds (:func:`~softsbi.workflows.criticism.design.efficiency_factor`). The estimate reads no wipe or fling
task, so on those motions it is a prediction that their trained reports judge.

Usage: ``python -m benchmarks run motions --bank DIR [--train] [--motions lift wipe fling] [--workers 2]``.
"""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from benchmarks.runner import in_out_folder, table

BACKEND = "mujoco-flex"
MOTIONS = ("lift", "wipe", "fling")


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--bank", type=Path, default=None, help="simulation bank holding the motions' trained tasks "
                    "(required)")
    ap.add_argument("--train", action="store_true", help="train the models the bank does not hold (hours)")
    ap.add_argument("--motions", nargs="+", default=list(MOTIONS), choices=MOTIONS)
    ap.add_argument("--prior-sims", type=int, default=1000, help="prior simulations each model is trained on")
    ap.add_argument("--n-test", type=int, default=200, help="held-out prior simulations of each training report")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="keep the lift fit the estimate is made at here")


FULL = None


def task_recording(motion: str):
    """The recording a motion's task is trained on: the demo's lift, else the built-in scenario at the prior's
    midpoint (``softsbi simulate``'s default values; a task reads a recording's scenario and sensor settings)."""
    if motion == "lift":
        from softsbi.workflows.demo import demo_recording
        return demo_recording(False)[0]
    from softsbi.workflows.measurement import simulate_recording
    return simulate_recording(BACKEND, motion)


def _cell(width: float | None, limit: float) -> str | None:
    return None if width is None else f"{width:.3f}{' *' if width <= limit else ''}"


def measure(a: argparse.Namespace, folder: Path) -> dict:
    from softsbi.core.defaults import INFORMED_MAX_RATIO as LIMIT
    from softsbi.workflows.criticism.design import trained_width
    from softsbi.workflows.criticism.screening import default_candidates, is_generic
    from softsbi.workflows.fit.run import FitConfig
    from softsbi.workflows.fit.task_store import task_store_of
    from softsbi.workflows.tasks.training import train_task
    cfg = FitConfig(backend=BACKEND, workers=a.workers, sim_bank=str(a.bank))
    recs = {m: task_recording(m) for m in a.motions}
    family = [c.name for c in default_candidates(BACKEND, recs[a.motions[0]].scenario, []) if not is_generic(c)]
    notes = []
    if a.train:
        for m in a.motions:
            train_task(recs[m], cfg, a.prior_sims, n_test=a.n_test, check_null=0, refit_null=0, message=print)
    tasks = task_store_of(str(a.bank)).list()
    trained = {m: {e: trained_width(tasks, BACKEND, m, e) for e in family} for m in a.motions}
    rows = [[e, *[_cell(trained[m][e], LIMIT) for m in a.motions],
             ", ".join(m for m in a.motions if (trained[m][e] or 1.0) <= LIMIT) or "none"] for e in family]
    counts = {m: (sum((w or 1.0) <= LIMIT for w in trained[m].values()), sum(w is not None for w in trained[m].values()))
              for m in a.motions}
    tables = [table(f"Which shipped effects each motion informs: the trained model's median 90% width / prior of the "
                    f"effect's best-informed parameter on its held-out simulations (* informed, <= {LIMIT})",
                    ["effect", *a.motions, "informed by"], rows)]
    notes.append("Informed, of the trained candidates: " + "; ".join(
        f"{m} {k} of {n}" for m, (k, n) in counts.items()) + ".")
    none = [e for e in family if all(trained[m][e] is not None for m in a.motions)
            and not any(trained[m][e] <= LIMIT for m in a.motions)]
    if all(n == len(family) for _, n in counts.values()):
        notes.append(f"Informed by none of them: {', '.join(none) or 'none'}.")
    if "lift" in a.motions:
        notes += _prediction(a, folder, cfg, recs["lift"], family, trained, LIMIT, tables)
    return {"tables": tables, "notes": notes,
            "data": {"trained": trained, "limit": LIMIT, "family": family}}


def _prediction(a, folder, cfg, lift_rec, family, trained, limit, tables) -> list[str]:
    """``design``'s estimate of each motion's cells at a fit of the demo's lift, beside the trained widths (a table
    appended to ``tables``); returns the notes."""
    from softsbi.core.types import Scenario
    from softsbi.scenarios.catalog import load_scenario
    from softsbi.workflows.criticism.check import loaded
    from softsbi.workflows.criticism.design import efficiency_factor, linear_widths
    from softsbi.workflows.fit.run import run_fit
    run_dir = folder / "lift-fit"
    run_fit(run_dir, lift_rec, replace(cfg, rounds=1), make_plots=False)
    run = loaded(run_dir)
    own = Scenario.from_json(run.record.scenario)
    scen = {m: own if m == "lift" else load_scenario(m) for m in a.motions}
    bounds, sims = {}, 0
    for m in a.motions:
        bounds[m], n, _ = linear_widths(run, scen[m], family, a.workers)
        sims += n
    factor = efficiency_factor({e: w for e, w in trained["lift"].items() if w is not None}, bounds["lift"])
    est = {m: {e: None if b is None else min(1.0, b * (factor or 1.0)) for e, b in bounds[m].items()}
           for m in a.motions}
    others = [m for m in a.motions if m != "lift" and any(w is not None for w in trained[m].values())]
    rows = [[e, *[x for m in a.motions for x in (_cell(est[m][e], limit), _cell(trained[m][e], limit))]]
            for e in family]
    tables.append(table(f"design's estimate (the linear bound at a fit of the demo's lift, scaled by the lift's "
                        f"efficiency {factor:.2f}) beside each trained model's width (* informed, <= {limit})",
                        ["effect", *[f"{m} {k}" for m in a.motions for k in ("estimate", "trained")]], rows))
    out = [f"The estimate cost {sims} simulations ({len(a.motions)} motions)."]
    for m in others:
        both = [e for e in family if trained[m][e] is not None and est[m][e] is not None]
        agree = sum((est[m][e] <= limit) == (trained[m][e] <= limit) for e in both)
        out.append(f"{m}: the estimate agrees with the trained report on {agree} of {len(both)} effects (a "
                   f"prediction: it read no {m} task).")
    if trained["lift"]:
        both = [e for e in family if trained["lift"][e] is not None and est["lift"][e] is not None]
        agree = sum((est["lift"][e] <= limit) == (trained["lift"][e] <= limit) for e in both)
        out.append(f"lift: the estimate agrees with the trained report on {agree} of {len(both)} effects (in sample: "
                   f"the scaling is the lift's own).")
    return out


def suite(a: argparse.Namespace) -> dict:
    if a.bank is None:
        raise SystemExit("motions: give --bank DIR, the simulation bank holding (or, with --train, to hold) the "
                         "motions' trained tasks")
    return in_out_folder(measure, a)
