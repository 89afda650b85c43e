"""C2ST of softsbi's MDN (``mdnn`` network on flat vectors, :class:`FlatMDNEstimator`) and of
``sbi-npe`` on SBI-benchmark tasks, against sbibm's reference posteriors.

Needs the .npy/.npz files written by ``benchmarks/sbibm_export.py`` (run in a separate venv
with sbibm). Amortised, one round: q(theta | x) is trained on prior simulations from
sbibm's simulators; posterior samples are drawn from q at the observation, rejected outside
the prior's support (two_moons, slcp have box priors; gaussian_linear's prior is Gaussian).
C2ST: :func:`softsbi.inference.c2st.c2st` (torch re-implementation of sbibm's recipe),
``--c2st-n`` samples of each (sbibm uses 10k vs 10k; 2k is noisier by about +-0.01).

Usage::

    nice -n 15 python benchmarks/sbibm_c2st.py --ref /tmp/sbibm_ref --budgets 1000 10000 --obs 1
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

PUBLISHED_NPE = {"two_moons": (0.725, 0.606), "slcp": (0.975, 0.901), "gaussian_linear": (0.694, 0.552)}
BOX = {"two_moons": (-1.0, 1.0), "slcp": (-3.0, 3.0), "gaussian_linear": None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="/tmp/sbibm_ref")
    ap.add_argument("--tasks", nargs="+", default=list(PUBLISHED_NPE))
    ap.add_argument("--budgets", type=int, nargs="+", default=[1000, 10000])
    ap.add_argument("--obs", type=int, nargs="+", default=[1])
    ap.add_argument("--estimators", nargs="+", default=["mdnn-flat"])
    ap.add_argument("--c2st-n", type=int, default=2000)
    ap.add_argument("--max-seconds", type=float, default=300.0)
    ap.add_argument("--out", default="/tmp/sbibm_c2st.json")
    ap.add_argument("--save-samples", default=None, help="folder for the posterior samples (.npy)")
    args = ap.parse_args()

    from softsbi.inference.baselines import FlatMDNEstimator
    from softsbi.inference.c2st import c2st
    from softsbi.inference.sbi_adapter import SbiNPEEstimator

    ref = Path(args.ref)
    rows = []
    for task in args.tasks:
        sims = np.load(ref / f"{task}_sims.npz")
        for n in args.budgets:
            for name in args.estimators:
                theta, x = sims["theta"][:n].astype(np.float64), sims["x"][:n].astype(np.float64)
                est = (FlatMDNEstimator(n_components=10, max_seconds=args.max_seconds) if name == "mdnn-flat"
                       else SbiNPEEstimator(num_components=10))
                info = est.fit(theta, x, seed=0)
                for k in args.obs:
                    xo = np.load(ref / f"{task}_obs{k}.npy")
                    q = est.posterior_at(xo[0])
                    rng = np.random.default_rng(k)
                    s = q.sample(4 * args.c2st_n, rng)
                    if BOX[task] is not None:
                        lo, hi = BOX[task]
                        s = s[np.all((s >= lo) & (s <= hi), axis=1)]
                    refs = np.load(ref / f"{task}_ref{k}.npy")
                    if args.save_samples:
                        Path(args.save_samples).mkdir(parents=True, exist_ok=True)
                        np.save(Path(args.save_samples) / f"{task}_{name}_{n}_obs{k}.npy", s[:args.c2st_n])
                    t0 = time.perf_counter()
                    acc = c2st(s[:args.c2st_n], refs, max_n=args.c2st_n, seed=k)
                    pub = PUBLISHED_NPE[task][0 if n == 1000 else 1] if n in (1000, 10000) else None
                    rows.append({"task": task, "sims": n, "estimator": name, "obs": k, "c2st": acc,
                                 "published_npe": pub, "train_s": info["seconds"], "epochs": info.get("epochs"),
                                 "c2st_s": time.perf_counter() - t0})
                    print(json.dumps(rows[-1]), flush=True)
                Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
