"""The estimators-gauss suite: estimators on the ``toy-gauss`` simulator (tests/plugins/softsbi_toy; analytic
posterior), and their expected coverage.

(a) Sequential fit through ``run_fit`` (rounds 1..R, each call resumes and adds a round;
    bulk estimators draw every round from the prior): C2ST between the proposal-corrected
    posterior after each round and the analytic posterior (truncated to the prior box),
    2000 samples each (:func:`softsbi.inference.c2st.c2st`).
(b) Expected coverage of the amortised (round-1) posterior: each estimator is trained on
    ``--train`` prior simulations and evaluated on ``--test`` held-out prior simulations;
    the truth is inside the 50 % / 90 % highest-density region of q (truncated to the prior
    box, 2000 samples) in the stated fraction of cases when q is calibrated.

``--lift-store RUN.zarr`` takes the coverage pool from the prior simulations of a bulk lift run instead of the toy.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks.runner import in_out_folder, table

METHODS = ["rkhs", "mdnn", "mdrff", "bayeszoom-rkhs", "nn-bulk", "gp-bulk"]


def toy_pool(n: int, T: int, K: int, seed: int, sigma: float | None = None):
    from softsbi.perception.pointcloud import PointCloudObserver
    from softsbi.plugins import registry
    import softsbi_toy.plugin as toy
    sim = registry().simulator("toy-gauss")(**({} if sigma is None else {"sigma": sigma}))
    sc = toy.toy_scenario(T)
    space = sim.param_space(sc)
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    th = space.from_unit(u)
    obs = PointCloudObserver(K)
    xs = []
    for i in range(n):
        ro = sim.simulate(sc, {"a": th[i, 0], "b": th[i, 1]}, seed=int(rng.integers(2**31)))
        xs.append(obs.observe(ro, np.random.default_rng([seed, i])).state())
    return u, np.stack(xs)


def coverage(est, u_test, x_test, n=2000, seed=0):
    rng = np.random.default_rng(seed)
    ranks = []
    for ui, xi in zip(u_test, x_test):
        q = est.posterior_at(xi)
        s = q.sample(3 * n, rng)
        s = s[np.all((s >= 0) & (s <= 1), axis=1)][:n]
        if len(s) < 50:
            ranks.append(1.0)
            continue
        ranks.append(float(np.mean(q.log_prob(s) > q.log_prob(ui[None])[0])))
    ranks = np.array(ranks)
    return {"cov50": float(np.mean(ranks < 0.5)), "cov90": float(np.mean(ranks < 0.9))}


FULL = {"rounds": 3, "sims": 200, "train": 600, "test": 200, "methods": METHODS}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--out", type=Path, default=None, help="folder of the fits (default: a temporary one)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--sims", type=int, default=100)
    ap.add_argument("--train", type=int, default=300)
    ap.add_argument("--test", type=int, default=100)
    ap.add_argument("--methods", nargs="+", default=["rkhs", "mdnn"])
    ap.add_argument("--skip", nargs="*", default=[], choices=["c2st", "coverage"])
    ap.add_argument("--toy-sigma", type=float, default=None,
                    help="noise of toy-gauss for the coverage pool (default 0.05: the posterior is wide and "
                         "truncated by the prior box; 0.01 keeps it inside)")
    ap.add_argument("--lift-store", default=None,
                    help="coverage on the prior simulations (round data) of a bulk lift run store instead of toy")


def suite(args: argparse.Namespace) -> dict:
    return in_out_folder(measure, args)


def measure(args: argparse.Namespace, out: Path) -> dict:
    """(a) and (b) of the module's docstring, fits in ``out``."""
    import softsbi_toy.plugin as toy
    from softsbi.workflows.fit.run import FitConfig, run_fit
    from softsbi.inference.c2st import c2st
    from softsbi.workflows.measurement import simulate_recording
    from softsbi.core.errors import DependencyMissing
    from softsbi.plugins import registry

    out.mkdir(parents=True, exist_ok=True)
    results: dict = {"c2st": {}, "coverage": {}}
    tables, notes = [], []
    T, K = 3, 16
    if "c2st" not in args.skip:
        meas = simulate_recording("toy-gauss", toy.toy_scenario(T), {"a": 0.3, "b": -0.4}, n_points=K, n_dense=64,
                                  seed=5)
        mean, cov = toy.analytic_posterior(meas.x[:, 1:, :].mean(1))
        rng = np.random.default_rng(0)
        ref = rng.multivariate_normal(mean, cov, 20000)
        ref = ref[np.all(np.abs(ref) <= 1, axis=1)][:2000]
        for m in args.methods:
            accs = []
            for R in range(1, args.rounds + 1):
                cfg = FitConfig(backend="toy-gauss", estimator=m, rounds=R, sims_per_round=args.sims, workers=1,
                                n_points=K, n_eval=5, n_dense=64, seed=1, proposal="corrected")  # the paper's BayesSim rounds
                res = run_fit(out / m, meas, cfg, make_plots=False)
                th = res.param_space.from_unit(res.posterior.sample(2000, np.random.default_rng(R)))
                accs.append(round(c2st(th, ref, seed=R, max_n=2000), 3))
            results["c2st"][m] = accs
        tables.append(table(f"C2ST against the analytic posterior after each round ({args.sims} simulations per round, "
                            f"T={T}, K={K}, truth (0.3, -0.4); 0.5 = indistinguishable)",
                            ["estimator", *[f"round {r}" for r in range(1, args.rounds + 1)]],
                            [[m, *a] for m, a in results["c2st"].items()]))
    if "coverage" not in args.skip:
        if args.lift_store:
            from softsbi.workflows.fit.rounds import usable_simulations
            from softsbi.core.store import RunStore
            st = RunStore.open(args.lift_store)
            u, x, _ = usable_simulations(st, len(st.completed_rounds()) - 1)
            args.train = min(args.train, len(u) - args.test)
        else:
            u, x = toy_pool(args.train + args.test, T, K, seed=11, sigma=args.toy_sigma)
        reg = registry()
        for m in list(args.methods) + ["sbi-npe"]:
            t0 = time.perf_counter()
            try:
                est = reg.estimator(m)()
                est.fit(u[:args.train], x[:args.train], seed=0)
            except DependencyMissing as exc:  # e.g. sbi-npe without sbi
                notes.append(f"{m} skipped: {exc}")
                continue
            cv = coverage(est, u[args.train:], x[args.train:])
            cv["train_s"] = time.perf_counter() - t0
            results["coverage"][m] = cv
        pool = "a bulk lift run's prior simulations" if args.lift_store else "toy-gauss prior simulations"
        tables.append(table(f"Expected coverage of the amortised posterior ({pool}: {args.train} train, {args.test} "
                            "test; calibrated: 0.50 / 0.90)", ["estimator", "at 50 %", "at 90 %", "train + test s"],
                            [[m, round(c["cov50"], 3), round(c["cov90"], 3), round(c["train_s"], 1)]
                             for m, c in results["coverage"].items()]))
    return {"tables": tables, "notes": notes, "data": results}
