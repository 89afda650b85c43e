"""The posterior-calibration suite: is every trained model of the lift task calibrated on its held-out simulations?

The demo's task (the built-in lift on mujoco-flex, the demo's recording, the fit's defaults) is trained by
``softsbi task train``'s workflow for the nominal model and every shipped candidate effect the backend applies
(the built-in, non-generic effects: what ``diagnose`` refits), each on ``--prior-sims`` prior simulations, with a
training report on ``--n-test`` held-out prior simulations (``--n-draws`` posterior draws each). The trained models
are stored in the simulation bank under ``--out``, so a run that stops resumes where it stopped: the same command
reads every model already trained.

Per model, the table reads its training report against the issue's three criteria, each at a stated level:

- TARP (Lemos et al. 2023): the KS test of uniformity of its ranks passes at p >= ``TARP_MIN_P`` (0.01);
- HPD coverage at 50% and 90%: inside the binomial band of a calibrated estimator (the report's band at the
  verdict's level, from ``n_test`` held-out cases);
- SBC (Talts et al. 2018) per marginal: the KS p-value of every parameter's rank histogram above ``0.05 / D``
  (Bonferroni over the model's ``D`` parameters).

Usage: ``python -m benchmarks run posterior-calibration --out DIR [--prior-sims 1000] [--n-test 200]
[--candidates a,b]``; ``--full`` is the issue's configuration (every shipped candidate, 1000 + 200 simulations).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from benchmarks.runner import in_out_folder, table

#: the TARP criterion: the KS p-value of TARP's ranks at least this
TARP_MIN_P = 0.01
#: the family-wise level of the per-marginal SBC tests (Bonferroni over a model's parameters)
SBC_LEVEL = 0.05


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--prior-sims", type=int, default=300, help="prior simulations each model is trained on")
    ap.add_argument("--n-test", type=int, default=200, help="held-out prior simulations of each training report")
    ap.add_argument("--n-draws", type=int, default=1000, help="posterior draws per held-out simulation")
    ap.add_argument("--candidates", default="wind",
                    help="comma-separated candidate effects trained beside the nominal model; 'shipped': every "
                         "built-in candidate the backend applies")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None,
                    help="the simulation bank the models are trained into and read back from (a run resumes there)")


FULL = {"prior_sims": 1000, "n_test": 200, "candidates": "shipped"}


def shipped_candidates(backend: str) -> list[str]:
    """The built-in, non-generic effects ``backend`` applies: the candidates ``diagnose`` refits on a task trained
    with every shipped candidate (installed third-party effects left out)."""
    from softsbi.effects.builtin import softsbi_effects
    from softsbi.plugins import registry
    from softsbi.workflows.criticism.screening import is_generic
    sim = registry().simulator(backend)
    return [e.name for e in softsbi_effects() if not is_generic(e()) and sim.supports(e) is None]


def criteria(report: Any) -> dict[str, Any]:
    """One model's training report against the three criteria (module docstring): each value and whether it
    passes."""
    d = len(report.parameters)
    sbc_p = dict(zip(report.parameters, report.sbc.ks_pvalue))
    sbc_fail = sorted(n for n, p in sbc_p.items() if p < SBC_LEVEL / d)
    cov = report.coverage
    lo50, hi50 = cov.band_50 or (None, None)
    lo90, hi90 = cov.band_90 or (None, None)
    in50 = lo50 is not None and lo50 <= cov.at_50 <= hi50
    in90 = lo90 is not None and lo90 <= cov.at_90 <= hi90
    tarp_p = report.tarp.ks_pvalue
    return {"tarp_p": tarp_p, "tarp_ok": tarp_p is not None and tarp_p >= TARP_MIN_P,
            "at_50": cov.at_50, "band_50": (lo50, hi50), "in_50": in50,
            "at_90": cov.at_90, "band_90": (lo90, hi90), "in_90": in90,
            "sbc_min_p": min(sbc_p.values()), "sbc_threshold": SBC_LEVEL / d, "sbc_fail": sbc_fail,
            "passes": bool(tarp_p is not None and tarp_p >= TARP_MIN_P and in50 and in90 and not sbc_fail),
            "verdict": report.verdict}


def _measure(args: argparse.Namespace, bank: Path) -> dict:
    from softsbi.workflows.demo import demo_recording
    from softsbi.workflows.fit.config import FitConfig
    from softsbi.workflows.tasks.training import train_task
    recording, _ = demo_recording(False)
    cfg = FitConfig(workers=args.workers, sim_bank=str(bank))
    names = (shipped_candidates(cfg.backend) if args.candidates == "shipped"
             else [n for n in args.candidates.split(",") if n])
    t0 = time.perf_counter()
    tasks = train_task(recording, cfg, n_prior=args.prior_sims, candidates=names, n_test=args.n_test,
                       n_draws=args.n_draws, check_null=0, message=print)
    rows, data = [], []
    for t in tasks:
        c = criteria(t.report)
        model = t.model
        data.append({"model": model, "n_test": t.report.n_test, "n_prior": t.n_prior, **c})
        rows.append([model, t.report.n_test, _p(c["tarp_p"]), _ok(c["tarp_ok"]),
                     f"{c['at_50']:.3f} ({_band(c['band_50'])})", _ok(c["in_50"]),
                     f"{c['at_90']:.3f} ({_band(c['band_90'])})", _ok(c["in_90"]),
                     f"{c['sbc_min_p']:.2g} vs {c['sbc_threshold']:.2g}", ", ".join(c["sbc_fail"]) or "none",
                     "passes" if c["passes"] else "fails"])
    n_pass = sum(d["passes"] for d in data)
    return {"tables": [table(
        f"Each trained model of the lift task on its {args.n_test} held-out prior simulations ({args.prior_sims} "
        f"prior simulations each, estimator rkhs)",
        ["model", "held-out", "TARP KS p", f">= {TARP_MIN_P}", "HPD coverage 50% (band)", "inside",
         "HPD coverage 90% (band)", "inside", "SBC min KS p vs Bonferroni", "SBC marginals off", "all three"],
        rows)],
        "notes": [f"{n_pass} of {len(data)} models pass all three criteria. Training and reading the "
                  f"{len(data)} models took {time.perf_counter() - t0:.0f} s (models already in the bank are read, "
                  f"not trained)."],
        "data": {"models": data, "candidates": names}}


def _p(p: float | None) -> str:
    return "-" if p is None else f"{p:.2g}"


def _ok(ok: bool) -> str:
    return "yes" if ok else "no"


def _band(b: tuple[float | None, float | None]) -> str:
    return "-" if b[0] is None else f"{b[0]:.3f}-{b[1]:.3f}"


def suite(args: argparse.Namespace) -> dict:
    return in_out_folder(_measure, args)
