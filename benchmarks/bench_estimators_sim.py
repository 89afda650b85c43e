"""The paper's six-method comparison in simulation (issue 4): cloth lift or rope winding.

A measurement of ``--scenario lift`` (cloth lift) or ``--scenario wind`` (the paper's
*winding*: a rope wound onto a spool, partly occluded by it) is simulated with
``mujoco-flex`` at hidden parameters and observed as K
noisy points per frame, resampled (so unordered) frame to frame. Each estimator runs
``run_fit`` for 1..R rounds (each call resumes the previous run and adds a round); after
each round ``n_eval`` rollouts at posterior samples are compared with the truth's dense
clouds (bidirectional Chamfer, mean over frames) -> mean +- std per round and method.
Bulk methods (``sequential = False``) draw every round from the prior, so their round r is
"bulk with r x sims_per_round simulations".

Usage::

    nice -n 15 python benchmarks/bench_estimators_sim.py --out /tmp/bench_lift [--scenario lift]
        [--rounds 3] [--sims 100] [--eval 10] [--grid 6] [--points 32] [--methods rkhs mdnn ...]

Writes ``<out>/results.json`` and ``<out>/chamfer_per_round.png`` and prints a table.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

METHODS = ["rkhs", "mdnn", "mdrff", "bayeszoom-rkhs", "nn-bulk", "gp-bulk"]
#: hidden parameters (unit-cube position in the backend's parameter order) per scenario
TRUTH_UNIT = {"lift": [0.6, 0.4, 0.5, 0.5, 0.6],  # bend, stretch, friction, scale, mass
              "wind": [0.6, 0.4, 0.5, 0.6]}  # young, friction, scale, mass (rope)
TITLE = {"lift": "cloth lift", "wind": "rope winding (spool occludes part of the rope)"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="/tmp/bench_lift")
    ap.add_argument("--scenario", default="lift", choices=sorted(TRUTH_UNIT))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--sims", type=int, default=100)
    ap.add_argument("--eval", type=int, default=10)
    ap.add_argument("--grid", type=int, default=6)
    ap.add_argument("--points", type=int, default=32)
    ap.add_argument("--noise", type=float, default=0.005)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--methods", nargs="+", default=METHODS)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    from softsbi.scenarios.builtin import make_scenario
    from softsbi.core.errors import PosteriorError
    from softsbi.workflows.fit import FitConfig, run_fit
    from softsbi.workflows.measurement import simulate_recording
    from softsbi.plugins import registry

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sc = make_scenario(args.scenario)
    bopts = {"grid": args.grid}
    sim = registry().simulator("mujoco-flex")(**bopts)
    space = sim.param_space(sc)
    truth = space.as_dict(space.from_unit(np.array(TRUTH_UNIT[args.scenario])))
    meas = simulate_recording("mujoco-flex", sc, truth, backend_options=bopts, n_points=args.points,
                                n_dense=300, noise=args.noise, seed=7)
    results = {"truth": truth, "config": vars(args), "methods": {}}
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
                print(f"{m:15s} round {R}: FAILED ({exc})", flush=True)
                break
            rep = res.report
            rows.append({"round": R, "simulations": R * args.sims,
                         "chamfer_mean_m": rep["chamfer_posterior_m"], "chamfer_std_m": rep["chamfer_posterior_std_m"],
                         "chamfer_prior_m": rep["chamfer_prior_m"],
                         "train_seconds": rep["per_round"][-1]["train_seconds"], "wall_s": time.perf_counter() - t0,
                         "posterior_mean": rep["posterior_mean"], "posterior_std": rep["posterior_std"]})
            print(f"{m:15s} round {R}: chamfer {100 * rows[-1]['chamfer_mean_m']:.2f} +- "
                  f"{100 * rows[-1]['chamfer_std_m']:.2f} cm (prior {100 * rep['chamfer_prior_m']:.2f}), "
                  f"train {rows[-1]['train_seconds']:.1f} s, wall {rows[-1]['wall_s']:.0f} s", flush=True)
        results["methods"][m] = rows
        (out / "results.json").write_text(json.dumps(results, indent=2))
    plot(results, out / "chamfer_per_round.png")


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


if __name__ == "__main__":
    main()
