"""The estimators-sim suite: the paper's six-method comparison in simulation, cloth lift or rope winding.

A measurement of ``--scenario lift`` (cloth lift) or ``--scenario wind`` (the paper's
*winding*: a rope wound onto a spool, partly occluded by it) is simulated with
``mujoco-flex`` at hidden parameters and observed as K
noisy points per frame, resampled (so unordered) frame to frame. Each estimator runs
``run_fit`` for 1..R rounds (each call resumes the previous run and adds a round); after
each round ``n_eval`` rollouts at posterior samples are compared with the truth's dense
clouds (bidirectional Chamfer, mean over frames) -> mean +- std per round and method.
Bulk methods (``sequential = False``) draw every round from the prior, so their round r is
"bulk with r x sims_per_round simulations".

``--figure PATH`` also draws the Chamfer per round and method.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks.runner import REPO, in_out_folder, table

METHODS = ["rkhs", "mdnn", "mdrff", "bayeszoom-rkhs", "nn-bulk", "gp-bulk"]
#: hidden parameters (unit-cube position in the backend's parameter order) per scenario
TRUTH_UNIT = {"lift": [0.6, 0.4, 0.5, 0.5, 0.6],  # bend, stretch, friction, scale, mass
              "wind": [0.6, 0.4, 0.5, 0.6]}  # young, friction, scale, mass (rope)
TITLE = {"lift": "cloth lift", "wind": "rope winding (spool occludes part of the rope)"}


FULL = {"rounds": 3, "sims": 100, "eval": 10, "methods": METHODS}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--out", type=Path, default=None, help="folder of the fits (default: a temporary one)")
    ap.add_argument("--scenario", default="lift", choices=sorted(TRUTH_UNIT))
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--sims", type=int, default=50)
    ap.add_argument("--eval", type=int, default=5)
    ap.add_argument("--grid", type=int, default=6)
    ap.add_argument("--points", type=int, default=32)
    ap.add_argument("--noise", type=float, default=0.005)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--methods", nargs="+", default=["rkhs", "mdnn"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--figure", type=Path, default=None, help="also draw the Chamfer per round into this PNG")


def suite(args: argparse.Namespace) -> dict:
    return in_out_folder(measure, args)


def measure(args: argparse.Namespace, out: Path) -> dict:
    """Every method's fit round by round in ``out``; the Chamfer table."""
    from softsbi.scenarios.builtin import make_scenario
    from softsbi.core.errors import PosteriorError
    from softsbi.workflows.fit.run import FitConfig, run_fit
    from softsbi.workflows.measurement import simulate_recording
    from softsbi.plugins import registry

    out.mkdir(parents=True, exist_ok=True)
    sc = make_scenario(args.scenario)
    bopts = {"grid": args.grid}
    sim = registry().simulator("mujoco-flex")(**bopts)
    space = sim.param_space(sc)
    truth = space.as_dict(space.from_unit(np.array(TRUTH_UNIT[args.scenario])))
    meas = simulate_recording("mujoco-flex", sc, truth, backend_options=bopts, n_points=args.points,
                              n_dense=300, noise=args.noise, seed=7)
    results = {"truth": truth, "config": {k: v for k, v in vars(args).items() if k not in ("out", "figure")},
               "methods": {}}
    for m in args.methods:
        rows = []
        for R in range(1, args.rounds + 1):
            cfg = FitConfig(backend="mujoco-flex", backend_options=bopts, estimator=m, rounds=R,
                            sims_per_round=args.sims, n_eval=args.eval, n_dense=300, n_points=args.points,
                            workers=args.workers, seed=args.seed, proposal="corrected")  # the paper's BayesSim rounds
            t0 = time.perf_counter()
            try:
                res = run_fit(out / m, meas, cfg, make_plots=False)
            except PosteriorError as exc:  # e.g. q with no mass in the prior box: the method fails here
                rows.append({"round": R, "simulations": R * args.sims, "failed": str(exc)})
                break
            rep = res.report.to_json()
            rows.append({"round": R, "simulations": R * args.sims,
                         "chamfer_mean_m": rep["chamfer_posterior_m"], "chamfer_std_m": rep["chamfer_posterior_std_m"],
                         "chamfer_prior_m": rep["chamfer_prior_m"],
                         "train_seconds": rep["per_round"][-1]["train_seconds"], "wall_s": time.perf_counter() - t0,
                         "posterior_mean": rep["posterior_mean"], "posterior_std": rep["posterior_std"]})
        results["methods"][m] = rows
    figures = []
    if args.figure is not None:
        plot(results, args.figure)
        if args.figure.resolve().is_relative_to(REPO / "docs"):
            figures.append({"path": str(args.figure.resolve().relative_to(REPO / "docs")),
                            "caption": f"estimators on {TITLE[args.scenario]}"})
    cm = lambda r: ("failed" if "failed" in r else  # noqa: E731
                    f"{100 * r['chamfer_mean_m']:.2f} ± {100 * r['chamfer_std_m']:.2f}")
    rows = [[m, *[cm(r) for r in rs], *["-"] * (args.rounds - len(rs)),
             next((round(r["train_seconds"], 1) for r in reversed(rs) if "failed" not in r), None)]
            for m, rs in results["methods"].items()]
    prior = next((r["chamfer_prior_m"] for rs in results["methods"].values() for r in rs if "failed" not in r), None)
    return {"tables": [table(f"{TITLE[args.scenario]}: Chamfer [cm] of {args.eval} rollouts at posterior samples to "
                             f"the truth's dense clouds (mean ± std) after each round of {args.sims} simulations",
                             ["estimator", *[f"{r * args.sims} simulations" for r in range(1, args.rounds + 1)],
                              "train s (last round)"], rows,
                             note=None if prior is None else f"Prior rollouts: {100 * prior:.2f} cm.")],
            "figures": figures, "data": results}


def plot(results: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(9.5, 4.2))
    prior = None
    for i, (m, rows) in enumerate(results["methods"].items()):
        rows = [r for r in rows if "failed" not in r]
        if not rows:
            ax.plot([], [], ls="none", label=f"{m}: failed (no posterior mass in the prior box)")
            continue
        n = np.array([r["simulations"] for r in rows]) + (i - 2.5) * 2.0  # small offset so bars do not overlap
        mu = 100 * np.array([r["chamfer_mean_m"] for r in rows])
        sd = 100 * np.array([r["chamfer_std_m"] for r in rows])
        ax.errorbar(n, mu, yerr=sd, marker="o", capsize=3, label=m, ls="--" if m.endswith("bulk") else "-")
        prior = rows[0]["chamfer_prior_m"]
    if prior:
        ax.axhline(100 * prior, color="grey", ls=":", label="prior samples")
    ax.set_xlabel("simulations used (sequential: rounds x sims/round; bulk: all from the prior)")
    ax.set_ylabel("Chamfer to truth (cm), mean +- std")
    cfg = results["config"]
    scen = cfg.get("scenario", "lift")
    what = f"{TITLE[scen]}, mujoco-flex" + (f" grid {cfg['grid']}" if scen == "lift" else "")
    ax.set_title(f"{what}\nK={cfg['points']} noisy unordered points per frame, {cfg['eval']} rollouts at posterior samples",
                 fontsize=10)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=120)

