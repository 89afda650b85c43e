"""The tasks suite: a task trained once against every recording fitted from scratch, on the demo's task.

The demo's task (the built-in lift on mujoco-flex, the nominal model, the fit's defaults) is trained once
(``softsbi task train``: ``--prior-sims`` prior simulations, a training report on ``--n-test`` held-out ones).
Then each of ``--recordings`` new recordings of the task (simulated at hidden parameters drawn from the middle 60%
of each prior, seeded; the first with the demo's hidden breeze, the others without) is fitted three ways, in the
same run:

- *sequential*: today's default fit from scratch (4 rounds x 150, truncated proposals), without a simulation bank
  or a stored task;
- *amortised*: one round, the stored task conditioned on the recording (no training, its prior simulations read
  from the bank), then the fit's 30 posterior-predictive rollouts;
- *amortised + 1 round*: the same and one sequential round of 150 truncated simulations.

Per recording and way: wall seconds of the fit, the posterior-predictive Chamfer (report.json's
``chamfer_posterior_m``), the hidden values inside the 90% intervals, and the informed parameters.

Usage: ``python -m benchmarks run tasks [--recordings 3] [--prior-sims 1000] [--n-test 200] [--out DIR]``.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.runner import in_out_folder, table
from softsbi.core.defaults import CheckSettings, DiagnoseSettings


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--recordings", type=int, default=3, help="new recordings of the task fitted each way")
    ap.add_argument("--prior-sims", type=int, default=1000, help="prior simulations the task is trained on")
    ap.add_argument("--n-test", type=int, default=200, help="held-out prior simulations of the training report")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None,
                    help="keep the runs and the bank here (default: a temporary folder)")


FULL = {"recordings": 5}
#: the candidate effect trained beside the nominal model, and the candidate family of the check and diagnosis
CANDIDATE = "wind"


def _recordings(n: int) -> list:
    from softsbi.plugins import registry
    from softsbi.scenarios.builtin import lift_scenario
    from softsbi.workflows.demo import demo_recording
    from softsbi.workflows.measurement import simulate_recording
    recs = [("demo (hidden breeze)", demo_recording(False)[0])]
    sc = lift_scenario(None)
    space = registry().simulator("mujoco-flex")().param_space(sc)
    rng = np.random.default_rng(2026)
    for i in range(1, n):
        u = 0.2 + 0.6 * rng.random(space.dim)
        truth = space.as_dict(space.from_unit(u[None])[0])
        recs.append((f"random {i}", simulate_recording("mujoco-flex", sc, truth, seed=100 + i)))
    return recs[:n]


def _fit(out: Path, rec, cfg) -> dict:
    from softsbi.workflows.fit.run import run_fit
    t0 = time.perf_counter()
    res = run_fit(out, rec, cfg, make_plots=False)
    r = res.report.to_json()
    inside = r["truth_in_90pct_interval"]
    informed = [n for n, c in r["contraction"].items() if c["informed"]]
    return {"wall_s": time.perf_counter() - t0, "chamfer_m": r["chamfer_posterior_m"],
            "inside": f"{sum(inside.values())} of {len(inside)}", "informed": informed}


def measure(a: argparse.Namespace, folder: Path) -> dict:
    from softsbi.workflows.fit.run import FitConfig
    from softsbi.workflows.tasks.training import train_task
    bank = folder / "bank"
    base = FitConfig(workers=a.workers, sim_bank=str(bank))
    recs = _recordings(a.recordings)
    t0 = time.perf_counter()
    trained = train_task(recs[0][1], base, a.prior_sims, candidates=[CANDIDATE], n_test=a.n_test)
    train_s = time.perf_counter() - t0
    ways = {"sequential (4 x 150, from scratch)": replace(base, sim_bank="off"),
            "amortised (stored task, 1 round)": replace(base, rounds=1),
            "amortised + 1 round of 150": replace(base, rounds=2)}
    rows = []
    for i, (name, rec) in enumerate(recs):
        for j, (way, cfg) in enumerate(ways.items()):
            m = _fit(folder / f"recording{i}-fit{j}", rec, cfg)
            rows.append([name, way, round(m["wall_s"], 1), round(m["chamfer_m"] * 100, 2), m["inside"],
                         ", ".join(m["informed"]) or "none"])
    try:  # the demo recording's stored-task fit
        model_error = _check_and_diagnose(folder / "recording0-fit1", a.workers)
    except Exception as exc:  # noqa: BLE001 - the fits' table stands; the failure is shown in its place
        model_error = [["check + diagnose", None, f"failed: {type(exc).__name__}: {exc}"]]
    return {"tables": [
        table("The task trained once: one amortised posterior per model, measured on held-out prior simulations",
              ["model", "prior simulations", "wall s", "held-out", "coverage 50%", "coverage 90%", "TARP KS p",
               "SBC rejects", "verdict", "90% width / prior (median)"], [_trained_row(t) for t in trained]),
        table("New recordings of the task: from scratch against the stored task",
              ["recording", "fit", "wall s", "posterior-predictive Chamfer cm", "hidden values inside 90%",
               "informed parameters"], rows),
        table(f"check and diagnose of the demo recording's stored-task fit (candidate family: {CANDIDATE}, trained)",
              ["step", "wall s", "result"], model_error)],
        "notes": [f"Training the task (the nominal model and {CANDIDATE}, {a.prior_sims} prior and {a.n_test} "
                  f"held-out simulations each) took {train_s:.0f} s."]}


def _trained_row(task) -> list:
    rep = task.report
    return [task.model, task.n_prior, round(rep.wall_seconds, 1), rep.n_test, round(rep.coverage.at_50, 3),
            round(rep.coverage.at_90, 3), rep.tarp.ks_pvalue,
            ", ".join(n for n, r in zip(rep.parameters, rep.sbc.rejects) if r) or "none", rep.verdict,
            ", ".join(f"{n} {c.width_ratio:.2f}" for n, c in rep.contraction.items())]


def _check_and_diagnose(run, workers: int) -> list:
    from softsbi.workflows.criticism.check import check_run
    from softsbi.workflows.criticism.diagnose import diagnose_run
    from softsbi.workflows.criticism.stats import PosteriorPredictive
    t0 = time.perf_counter()
    pool = PosteriorPredictive(run, workers)
    chk = check_run(run, pool=pool, effects=[CANDIDATE], settings=CheckSettings(workers=workers))
    t1 = time.perf_counter()
    diag = diagnose_run(run, effects=[CANDIDATE], pool=pool, settings=DiagnoseSettings(workers=workers))
    t2 = time.perf_counter()
    refit = diag.refits[0] if diag.refits else None
    return [["check", round(t1 - t0, 1), f"joint p = {chk.test.p_value:.3g} from {chk.test.n_null} null rollouts"],
            ["diagnose", round(t2 - t1, 1), f"{diag.verdict}: {', '.join(diag.decision.named) or 'none'}; refit "
             f"{'none' if refit is None else f'{refit.rounds} round(s)'}"],
            ["check + diagnose", round(t2 - t0, 1), ""]]


def suite(a: argparse.Namespace) -> dict:
    return in_out_folder(measure, a)
