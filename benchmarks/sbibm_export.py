"""Export SBI-benchmark observations and reference posterior samples to .npy for the sbibm suite (run in a
SEPARATE virtual environment with sbibm; sbibm pins sbi 0.21, which conflicts with softsbi's sbi). A standalone
script, not a suite: it imports sbibm.

Usage (from the repository root)::

    python3 -m venv .venv-sbibm && .venv-sbibm/bin/pip install torch==2.13.0 &&
    .venv-sbibm/bin/pip install sbibm future torch==2.13.0
    .venv-sbibm/bin/python benchmarks/sbibm_export.py --out runs/sbibm_ref [--obs 1 2 3]
    python -m benchmarks run sbibm --ref runs/sbibm_ref

Writes ``<task>_obs<k>.npy`` (1, F) and ``<task>_ref<k>.npy`` (10000, D) for two_moons,
slcp and gaussian_linear (observations 1-10 by default), plus ``<task>_sims.npz``: ``--n-sims``
prior simulations (``theta (n, D)``, ``x (n, F)``, seed 0) drawn with sbibm's own simulators, so
the main venv needs no sbibm. A budget of N uses the first N of them.
"""
import argparse
from pathlib import Path

import numpy as np
import sbibm
import torch

ap = argparse.ArgumentParser()
ap.add_argument("--out", default="runs/sbibm_ref")
ap.add_argument("--obs", type=int, nargs="+", default=list(range(1, 11)))
ap.add_argument("--n-sims", type=int, default=10000)
args = ap.parse_args()
out = Path(args.out)
out.mkdir(parents=True, exist_ok=True)
for name in ["two_moons", "slcp", "gaussian_linear"]:
    task = sbibm.get_task(name)
    for k in args.obs:
        np.save(out / f"{name}_obs{k}.npy", task.get_observation(num_observation=k).numpy())
        np.save(out / f"{name}_ref{k}.npy", task.get_reference_posterior_samples(num_observation=k).numpy())
    torch.manual_seed(0)
    theta = task.get_prior()(num_samples=args.n_sims)
    x = task.get_simulator()(theta)
    np.savez(out / f"{name}_sims.npz", theta=theta.numpy(), x=x.numpy())
    print(name, theta.shape, x.shape, flush=True)
