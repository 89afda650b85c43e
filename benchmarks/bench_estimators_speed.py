"""The estimators-speed suite: training time of one round at 1500 simulations for every estimator.

Data: lift-shaped synthetic states ``(1500, T=25, 1+K=33, 3)`` from the ``blob_task`` of
tests/inference/test_inference.py (2 parameters); training cost depends on shapes and N, not on the
simulator. Default options of every estimator (``rkhs``: the recalibrated ensemble of 5), all with the
same torch thread count (``--threads``, passed as every estimator's ``num_threads``); wall seconds of
``fit`` (early stopping and recalibration included) and the process's CPU seconds during it (with one
torch thread the CPU time is the work done, which other processes on a shared machine do not inflate
the way they inflate the wall time), epochs, and the held-out NLL (nats, unit-cube
coordinates, on ``--n-test`` fresh simulations of the same task) so a faster fit that is worse shows.
Extra variants: ``rkhs-shared`` (the shared-trunk ensemble: ``ensemble_shared=trunk,
point_subset=8, lr=0.003, patience=8`` with ``ensemble=5, recalibrate=true``; rkhs's default),
``rkhs-old`` (the default before: 5 independent networks on every point), ``rkhs-one``
(``ensemble=1, recalibrate=false`` with the old training: one network), ``rkhs-one-fast`` (one network trained
as member 0 of ``rkhs-shared``), ``rkhs-stacked`` (the old default ensemble trained as one stacked network,
``stack_members=true``); ``rkhs-freeze10`` / ``rkhs-one-freeze10``: ``embedding_epochs=10``
(the embedding frozen after 10 epochs). Before timing, every method is fitted once, untimed, on the first ``--warmup`` simulations (default
100, at least 50), so lazy imports and first-call set-up are not timed (importing sbi inside sbi-npe's first
fit costs ~1.8 CPU s, more than its whole training). ``--repeats R`` runs the whole list R times, interleaved, so every
method sees the same machine load; the ratios to ``sbi-npe`` (when sbi is installed) are taken within each repeat.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from benchmarks.runner import REPO, table

METHODS = ["rkhs", "mdnn", "mdrff", "bayeszoom-rkhs", "nn-bulk", "gp-bulk", "sbi-npe"]
# the shared-trunk ensemble (RKHSEstimator.SHARED_TRUNK), rkhs's default when this suite was run (with ensemble=5,
# recalibrate=true); OLD: the training before it (independent members, every point, lr 1e-3, patience 15)
SHARED = {"ensemble_shared": "trunk", "point_subset": 8, "lr": 3e-3, "patience": 8}
OLD = {"ensemble_shared": "none", "point_subset": None, "lr": 1e-3, "patience": 15}
VARIANTS = {"rkhs-shared": ("rkhs", SHARED),  # = rkhs's default when this suite was run
            "rkhs-old": ("rkhs", OLD),  # the default before the shared trunk: 5 independent networks
            "rkhs-one": ("rkhs", {**OLD, "ensemble": 1, "recalibrate": False}),  # one network (the paper's)
            "rkhs-one-fast": ("rkhs", {**SHARED, "ensemble": 1, "recalibrate": False}),  # member 0 of rkhs-shared
            "rkhs-stacked": ("rkhs", {**OLD, "stack_members": True}),
            "rkhs-freeze10": ("rkhs", {**OLD, "embedding_epochs": 10}),
            "rkhs-one-freeze10": ("rkhs", {**OLD, "ensemble": 1, "recalibrate": False, "embedding_epochs": 10})}


FULL = {"methods": METHODS, "repeats": 2}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--n", type=int, default=1500)
    ap.add_argument("--n-test", type=int, default=300)
    ap.add_argument("--threads", type=int, default=1, help="torch threads of every estimator")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--methods", nargs="+", default=["rkhs", "mdnn", "sbi-npe"],
                    help=f"estimators or variants ({', '.join(VARIANTS)}); sbi-npe is skipped without sbi")
    ap.add_argument("--warmup", type=int, default=100,
                    help="simulations of the untimed warm-up fit per method (at least 50)")
    ap.add_argument("--seed", type=int, default=0, help="fit seed of every estimator (initialisation, split, batches)")


def suite(args: argparse.Namespace) -> dict:
    sys.path.insert(0, str(REPO / "tests" / "inference"))
    from test_inference import blob_task

    from softsbi.core.errors import DependencyMissing
    from softsbi.plugins import registry
    u, x = blob_task(args.n, T=25, K=32, seed=0)
    ut, xt = blob_task(args.n_test, T=25, K=32, seed=1)
    methods, notes, rows = [], [], []
    for m in dict.fromkeys(args.methods):  # the untimed warm-up fit; a method whose package is missing is skipped
        name, opts = VARIANTS.get(m, (m, {}))
        try:
            registry().estimator(name)(**opts, num_threads=args.threads).fit(u[:max(args.warmup, 50)],
                                                                            x[:max(args.warmup, 50)], seed=0)
            methods.append(m)
        except DependencyMissing as exc:
            notes.append(f"{m} skipped: {exc}")
    for rep in range(args.repeats):
        for m in methods:
            name, opts = VARIANTS.get(m, (m, {}))
            est = registry().estimator(name)(**opts, num_threads=args.threads)
            cpu0 = time.process_time()
            info = est.fit(u, x, seed=args.seed)
            cpu = time.process_time() - cpu0
            qs = est.posteriors_at(xt) if hasattr(est, "posteriors_at") else [est.posterior_at(xi) for xi in xt]
            nll = float(-np.mean([q.log_prob(ui[None])[0] for q, ui in zip(qs, ut)]))
            rows.append({"estimator": m, "repeat": rep, "seconds": info["seconds"], "cpu_seconds": cpu,
                         "epochs": info.get("epochs"), "test_nll": nll,
                         "cov_scale": (info.get("recalibration") or {}).get("cov_scale")})
    ref = {r["repeat"]: r for r in rows if r["estimator"] == "sbi-npe"}
    out = [[r["estimator"], r["repeat"] + 1, round(r["seconds"], 1), round(r["cpu_seconds"], 1),
            round(r["cpu_seconds"] / ref[r["repeat"]]["cpu_seconds"], 1) if r["repeat"] in ref else None,
            r["epochs"], round(r["test_nll"], 2)] for r in rows]
    return {"tables": [table(f"One fit on {args.n} simulations, {args.threads} torch thread(s), held-out NLL on "
                             f"{args.n_test}", ["estimator", "repeat", "wall s", "CPU s", "CPU / sbi-npe",
                                                "epochs (sum over members)", "held-out NLL"], out)],
            "notes": notes, "data": {"rows": rows}}
