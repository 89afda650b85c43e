"""Training time of one round at 1500 simulations for every estimator (issues 4 and 16).

Data: lift-shaped synthetic states ``(1500, T=25, 1+K=33, 3)`` from the ``blob_task`` of
tests/inference/test_inference.py (2 parameters); training cost depends on shapes and N, not on the
simulator. Default options of every estimator (``rkhs``: the recalibrated ensemble of 5), all with the
same torch thread count (``--threads``, passed as every estimator's ``num_threads``); wall seconds of
``fit`` (early stopping and recalibration included) and the process's CPU seconds during it (with one
torch thread the CPU time is the work done, which other processes on a shared machine do not inflate
the way they inflate the wall time), epochs, and the held-out NLL (nats, unit-cube
coordinates, on ``--n-test`` fresh simulations of the same task) so a faster fit that is worse shows.
Extra variants: ``rkhs-shared`` (the shared-trunk ensemble of issue 16: ``ensemble_shared=trunk,
point_subset=8, lr=0.003, patience=8`` with ``ensemble=5, recalibrate=true``; rkhs's default since then),
``rkhs-old`` (the default before: 5 independent networks on every point), ``rkhs-one``
(``ensemble=1, recalibrate=false`` with the old training: one network), ``rkhs-one-fast`` (one network trained
as member 0 of ``rkhs-shared``), ``rkhs-stacked`` (the old default ensemble trained as one stacked network,
``stack_members=true``); ``rkhs-freeze10`` / ``rkhs-one-freeze10``: ``embedding_epochs=10``
(the embedding frozen after 10 epochs). Before timing, every method is fitted once, untimed, on the first ``--warmup`` simulations (default
100; 0: none), so lazy imports and first-call set-up are not timed (importing sbi inside sbi-npe's first
fit costs ~1.8 CPU s, more than its whole training). ``--repeats R`` runs the whole list R times, interleaved, so every
method sees the same machine load; the ratios to ``sbi-npe`` are taken within each repeat.

Usage::

    nice -n 15 python benchmarks/bench_estimators_speed.py [--n 1500] [--threads 1] [--methods ...]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

METHODS = ["rkhs", "mdnn", "mdrff", "bayeszoom-rkhs", "nn-bulk", "gp-bulk", "sbi-npe"]
# the shared-trunk ensemble of issue 16 (RKHSEstimator.SHARED_TRUNK), rkhs's default since issue 16 (with
# ensemble=5, recalibrate=true); OLD: the training before (independent members, every point, lr 1e-3, patience 15)
SHARED = {"ensemble_shared": "trunk", "point_subset": 8, "lr": 3e-3, "patience": 8}
OLD = {"ensemble_shared": "none", "point_subset": None, "lr": 1e-3, "patience": 15}
VARIANTS = {"rkhs-shared": ("rkhs", SHARED),  # = rkhs (the default) since issue 16
            "rkhs-old": ("rkhs", OLD),  # the default before issue 16's speed change: 5 independent networks
            "rkhs-one": ("rkhs", {**OLD, "ensemble": 1, "recalibrate": False}),  # one network (the paper's)
            "rkhs-one-fast": ("rkhs", {**SHARED, "ensemble": 1, "recalibrate": False}),  # member 0 of rkhs-shared
            "rkhs-stacked": ("rkhs", {**OLD, "stack_members": True}),
            "rkhs-freeze10": ("rkhs", {**OLD, "embedding_epochs": 10}),
            "rkhs-one-freeze10": ("rkhs", {**OLD, "ensemble": 1, "recalibrate": False, "embedding_epochs": 10})}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1500)
    ap.add_argument("--n-test", type=int, default=300)
    ap.add_argument("--threads", type=int, default=1, help="torch threads of every estimator")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--methods", nargs="+", default=METHODS)
    ap.add_argument("--out", default="/tmp/bench_speed.json")
    ap.add_argument("--label", default="", help="a tag stored with every row (e.g. the code version)")
    ap.add_argument("--warmup", type=int, default=100, help="simulations of the untimed warm-up fit per method (0: none)")
    ap.add_argument("--seed", type=int, default=0, help="fit seed of every estimator (initialisation, split, batches)")
    args = ap.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "inference"))
    from test_inference import blob_task

    from softsbi.plugins import registry
    u, x = blob_task(args.n, T=25, K=32, seed=0)
    ut, xt = blob_task(args.n_test, T=25, K=32, seed=1)
    rows = []
    for m in dict.fromkeys(args.methods) if args.warmup else []:
        name, opts = VARIANTS.get(m, (m, {}))
        registry().estimator(name)(**opts, num_threads=args.threads).fit(u[:args.warmup], x[:args.warmup], seed=0)
    for rep in range(args.repeats):
        for m in args.methods:
            name, opts = VARIANTS.get(m, (m, {}))
            est = registry().estimator(name)(**opts, num_threads=args.threads)
            cpu0 = time.process_time()
            info = est.fit(u, x, seed=args.seed)
            cpu = time.process_time() - cpu0
            qs = est.posteriors_at(xt) if hasattr(est, "posteriors_at") else [est.posterior_at(xi) for xi in xt]
            nll = float(-np.mean([q.log_prob(ui[None])[0] for q, ui in zip(qs, ut)]))
            rows.append({"estimator": m, "repeat": rep, "seconds": info["seconds"], "cpu_seconds": cpu, "epochs": info.get("epochs"),
                         "test_nll": nll, "n": args.n, "threads": args.threads,
                         "label": args.label, "seed": args.seed, "warmup": args.warmup,
                         "cov_scale": (info.get("recalibration") or {}).get("cov_scale"),
                         "member_best_epoch": info.get("member_best_epoch")})
            print(json.dumps(rows[-1]), flush=True)
            Path(args.out).write_text(json.dumps(rows, indent=1))
    ref = {r["repeat"]: r for r in rows if r["estimator"] == "sbi-npe"}
    for r in rows:
        if r["repeat"] in ref:
            f = ref[r["repeat"]]
            print(f"{r['estimator']:16s} repeat {r['repeat']}: wall {r['seconds']:7.1f} s = "
                  f"{r['seconds'] / f['seconds']:.2f} x sbi-npe; CPU {r['cpu_seconds']:7.1f} s = "
                  f"{r['cpu_seconds'] / f['cpu_seconds']:.2f} x sbi-npe; test NLL {r['test_nll']:.3f}")


if __name__ == "__main__":
    main()
