"""The sbibm suite: C2ST of softsbi's estimators and of sbi's own NPE on SBI-benchmark tasks, against sbibm's
reference posteriors, on the same simulations, observations and C2ST.

Needs the .npy/.npz files written by ``benchmarks/sbibm_export.py`` (run in a separate environment
with sbibm; ``--ref``). Amortised, one round: q(theta | x) is trained on the first ``sims`` prior
simulations of sbibm's simulators (the same ones for every estimator); posterior samples are
drawn at the observation and rejected outside the prior's support (two_moons, slcp have box
priors; gaussian_linear's prior is Gaussian, unbounded).

Estimators (``--estimators``):
    flow: :class:`softsbi.inference.flows.FlowEstimator` (zuko NSF, 5 transforms, 50 hidden, 10 bins:
        the benchmark's NPE architecture; sbi's training settings).
    mdnn-flat: :class:`softsbi.inference.baselines.FlatMDNEstimator` (mdnn network on flat vectors,
        10 full-covariance components).
    sbi-nsf / sbi-maf: sbi's own NPE (``sbi.inference.NPE(prior, density_estimator="nsf"|"maf")``,
        sbi's defaults otherwise: training batch 200, lr 5e-4, 10 % validation, patience 20), posterior
        from ``build_posterior`` (sbi's own rejection to the prior's support). sbibm's published NPE
        used an NSF; sbi 0.27's default density estimator is a MAF.
C2ST: :func:`softsbi.inference.c2st.c2st` (sbibm's recipe, scikit-learn ``MLPClassifier`` when
installed), ``--c2st-n`` samples of each (sbibm uses 10k vs 10k; 2k scatters by about +-0.04).
One torch thread per process (``--threads``).
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one BLAS thread (before numpy):
    os.environ.setdefault(_v, "1")  # a 2-thread OpenBLAS made one gaussian_linear C2ST 30x slower on a loaded machine

import numpy as np  # noqa: E402

from benchmarks.runner import REPO, table  # noqa: E402

PUBLISHED_NPE = {"two_moons": (0.725, 0.606), "slcp": (0.975, 0.901), "gaussian_linear": (0.694, 0.552)}
BOX = {"two_moons": (-1.0, 1.0), "slcp": (-3.0, 3.0), "gaussian_linear": None}
ESTIMATORS = ("flow", "mdnn-flat", "sbi-nsf", "sbi-maf")


def sbi_prior(task: str, dim: int):
    """The task's prior as a torch distribution for sbi (sbibm's definitions)."""
    import torch
    from sbi.utils import BoxUniform

    if BOX[task] is not None:
        lo, hi = BOX[task]
        return BoxUniform(lo * torch.ones(dim), hi * torch.ones(dim))
    return torch.distributions.MultivariateNormal(torch.zeros(dim), 0.1 * torch.eye(dim))  # gaussian_linear


class SbiNPE:
    """sbi's own NPE end to end (training, ``build_posterior``, sampling), for ``--estimators sbi-*``."""

    def __init__(self, task: str, model: str):
        self.task, self.model = task, model

    def fit(self, theta: np.ndarray, x: np.ndarray, seed: int = 0) -> dict:
        import torch
        from sbi.inference import NPE

        t0 = time.perf_counter()
        torch.manual_seed(seed)
        inf = NPE(prior=sbi_prior(self.task, theta.shape[1]), density_estimator=self.model, show_progress_bars=False)
        inf.append_simulations(torch.as_tensor(theta, dtype=torch.float32), torch.as_tensor(x, dtype=torch.float32))
        de = inf.train()
        self.posterior = inf.build_posterior(de)
        return {"seconds": time.perf_counter() - t0, "epochs": int(inf._summary["epochs_trained"][-1])}

    def sample(self, xo: np.ndarray, n: int, seed: int) -> np.ndarray:
        import torch

        torch.manual_seed(seed)
        s = self.posterior.sample((n,), x=torch.as_tensor(xo, dtype=torch.float32), show_progress_bars=False)
        return s.numpy().astype(np.float64)


def make(name: str, task: str, max_seconds: float):
    if name == "flow":
        from softsbi.inference.flows import FlowEstimator
        return FlowEstimator(max_seconds=max_seconds)
    if name == "mdnn-flat":
        from softsbi.inference.baselines import FlatMDNEstimator
        return FlatMDNEstimator(n_components=10, max_seconds=max_seconds)
    if name in ("sbi-nsf", "sbi-maf"):
        return SbiNPE(task, name.split("-")[1])
    raise SystemExit(f"unknown estimator {name!r}; choose from {list(ESTIMATORS)}")


def draw(est, name: str, task: str, xo: np.ndarray, n: int, seed: int) -> np.ndarray:
    """``n`` posterior draws at ``xo (1, F)`` inside the prior's support."""
    if isinstance(est, SbiNPE):
        return est.sample(xo, n, seed)  # sbi rejects outside the prior's support itself
    q = est.posterior_at(xo[0])
    rng = np.random.default_rng(seed)
    out, got = [], 0
    while got < n:
        s = q.sample(2 * n, rng)
        if BOX[task] is not None:
            lo, hi = BOX[task]
            s = s[np.all((s >= lo) & (s <= hi), axis=1)]
        out.append(s)
        got += len(s)
    return np.concatenate(out)[:n]


FULL = {"tasks": list(PUBLISHED_NPE), "budgets": [1000, 10000], "obs": [1, 2, 3],
        "estimators": ["flow", "mdnn-flat", "sbi-nsf"]}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--ref", type=Path, default=REPO / "runs" / "sbibm_ref",
                    help="the folder benchmarks/sbibm_export.py wrote")
    ap.add_argument("--tasks", nargs="+", default=["two_moons"], choices=list(PUBLISHED_NPE))
    ap.add_argument("--budgets", type=int, nargs="+", default=[1000])
    ap.add_argument("--obs", type=int, nargs="+", default=[1])
    ap.add_argument("--estimators", nargs="+", default=["flow", "mdnn-flat"], choices=ESTIMATORS)
    ap.add_argument("--c2st-n", type=int, default=2000)
    ap.add_argument("--max-seconds", type=float, default=600.0, help="training budget of softsbi's estimators")
    ap.add_argument("--threads", type=int, default=1)


def suite(args: argparse.Namespace) -> dict:
    import torch

    from softsbi.inference.c2st import c2st

    if not (args.ref / f"{args.tasks[0]}_sims.npz").exists():
        raise SystemExit(f"no sbibm reference files in {args.ref}: write them with benchmarks/sbibm_export.py (in an "
                         "environment with sbibm) and pass --ref")
    torch.set_num_threads(args.threads)
    rows = []
    for task in args.tasks:
        sims = np.load(args.ref / f"{task}_sims.npz")
        for n in args.budgets:
            for name in args.estimators:
                theta, x = sims["theta"][:n].astype(np.float64), sims["x"][:n].astype(np.float64)
                est = make(name, task, args.max_seconds)
                info = est.fit(theta, x, seed=0)
                for k in args.obs:
                    xo = np.load(args.ref / f"{task}_obs{k}.npy")
                    s = draw(est, name, task, xo, args.c2st_n, seed=k)
                    refs = np.load(args.ref / f"{task}_ref{k}.npy")
                    t0 = time.perf_counter()
                    acc = c2st(s, refs, max_n=args.c2st_n, seed=k)
                    pub = PUBLISHED_NPE[task][0 if n == 1000 else 1] if n in (1000, 10000) else None
                    rows.append({"task": task, "sims": n, "estimator": name, "obs": k, "c2st": acc,
                                 "published_npe": pub, "train_s": info["seconds"], "epochs": info.get("epochs"),
                                 "c2st_s": time.perf_counter() - t0, "threads": args.threads})
    return tables(rows)


def tables(rows: list[dict]) -> dict:
    """The C2ST table (mean over the observations, each observation in brackets) and training seconds, from the
    rows (one per task, budget, estimator and observation)."""
    order = list(PUBLISHED_NPE)
    keys = sorted({(r["task"], r["sims"]) for r in rows}, key=lambda k: (order.index(k[0]), k[1]))
    ests = list(dict.fromkeys(r["estimator"] for r in rows))
    out = []
    for task, n in keys:
        cells, secs = [], []
        for e in ests:
            rs = [r for r in rows if (r["task"], r["sims"], r["estimator"]) == (task, n, e)]
            cells.append(f"{np.mean([r['c2st'] for r in rs]):.3f} (" + " / ".join(f"{r['c2st']:.3f}" for r in rs)
                         + ")" if rs else None)
            secs.append(f"{rs[0]['train_s']:.0f}" if rs else "-")
        pub = next((r["published_npe"] for r in rows if (r["task"], r["sims"]) == (task, n)), None)
        out.append([task, n, *cells, pub, " / ".join(secs)])
    obs = sorted({r["obs"] for r in rows})
    return {"tables": [table("C2ST against sbibm's reference posterior: mean over observations "
                             f"{', '.join(map(str, obs))} (each in brackets); lower is better, 0.5 = indistinguishable",
                             ["task", "simulations", *ests, "sbi NPE published (10 observations, 10k vs 10k)",
                              "training s: " + " / ".join(ests)], out)],
            "data": {"rows": rows}}
