"""Which point of a softsbi posterior to roll out (issue 17: the posterior-mean rollout vs CMA-ES's best).

For finished fits of real lift recordings: one rollout each, through the fit's own job and headline
metric (the sensor view, the fit's frames; :func:`cmaes_baseline.score` with ``metric="fit"``), at

* ``mean``: the arithmetic posterior mean in physical units (``report.json``'s ``posterior_mean``);
* ``own-scale mean``: the mean in each parameter's own scale, i.e. the geometric mean of a
  log-scaled parameter (``report.json``'s ``contraction[...]["center"]``, the value the CLI table
  prints);
* ``median``: the per-parameter posterior median.

A log-uniform parameter whose posterior stays wide (bend, stretch on the real lifts) has an
arithmetic mean far above the bulk of its posterior (e.g. 3.3e-5 +- 7.5e-5 N m), so the arithmetic
mean's rollout need not resemble any likely simulation. The own-scale mean was chosen as the point
to compare on this principle, before these rollouts were run.

Usage:
    python benchmarks/point_estimates.py --fits /work/bench_runs/real19 [--only tan2,navy2]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from cmaes_baseline import DATA, contexts, score  # noqa: E402

from softsbi.workflows.jobs import simulate_job  # noqa: E402

POINTS = ("mean", "own-scale mean", "median")


def points(rep: dict, names: list[str]) -> dict[str, dict[str, float]]:
    """The three point estimates ``{point: {parameter: value}}`` (physical units) of a report."""
    con = rep["contraction"]
    return {"mean": {k: rep["posterior_mean"][k] for k in names},
            "own-scale mean": {k: con[k]["center"] for k in names},
            "median": {k: rep["posterior_median"][k] for k in names}}


def evaluate(fit_dir: Path) -> dict:
    """Headline Chamfer (m) of one rollout (seed 0) at each point estimate of the fit in ``fit_dir``."""
    rep = json.loads((fit_dir / "report.json").read_text())
    rec_name = Path(rep["observed"]).name
    _, space, sensor, ctx, _ = contexts(DATA / rec_name)
    frames = sensor["metric_frames"]
    out = {"recording": rec_name, "posterior_predictive_m": rep["chamfer_posterior_m"],
           "prior_m": rep["chamfer_prior_m"], "points": {}}
    for name, p in points(rep, space.names).items():
        th = space.as_array(p)
        out["points"][name] = {"theta": p, "chamfer_m": score(simulate_job(ctx, (th, 0)), "fit", frames)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fits", type=Path, required=True, help="folder of fit directories (one per recording)")
    ap.add_argument("--only", default=None, help="comma-separated fit directory names")
    ap.add_argument("--out", type=Path, default=None, help="JSON file for the results")
    a = ap.parse_args()
    names = a.only.split(",") if a.only else sorted(p.name for p in a.fits.iterdir() if (p / "run.zarr").exists())
    rows = []
    print("| recording | " + " | ".join(f"{p} rollout [cm]" for p in POINTS) + " | posterior predictive [cm] |")
    print("|---|" + "---|" * (len(POINTS) + 1))
    for n in names:
        r = evaluate(a.fits / n)
        rows.append(r)
        print(f"| {n} | " + " | ".join(f"{r['points'][p]['chamfer_m'] * 100:.2f}" for p in POINTS)
              + f" | {r['posterior_predictive_m'] * 100:.2f} |", flush=True)
    if a.out:
        a.out.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
