"""Fit all 10 DiffCloud lift recordings with the defaults of `softsbi fit` and tabulate.

Usage: python benchmarks/real_lift_all.py --out runs/real [--data ../shared/data/diffcloud_lift]
    [--only tan2,navy2] [--workers 1] [--extra --refine 150 --widen]
Each fit is resumable (re-running skips finished recordings). Prints a Markdown table
(Chamfer prior vs posterior under each fit's sensor model, posterior/prior ratio, the one-sided
measured -> simulated Chamfer, posterior mean ± std per parameter, wall time, failures), the
contraction table (posterior 90% width over the prior's per parameter, "not informed" above 0.5;
issue 16) and the distance between repeats of a fabric vs between different fabrics
(prior-normalised units). The last line is one JSON object per recording (issue 56): posterior/prior Chamfer,
the best fit (its Chamfer, source, refinement), the widened bounds and the bounds still pressed.
"""
from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from fabric_distances import material_unit_means, repeat_fabric_distances

from softsbi.inference.contraction import contraction_from_report

RECS = ["tan", "tan2", "navy", "navy2", "paper", "paper2", "polka", "polka2", "redblack", "redblack2"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, default=Path("runs/real"))
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared/data/diffcloud_lift")
    ap.add_argument("--only", default="", help="comma-separated recordings (default: all 10)")
    ap.add_argument("--workers", type=int, default=None, help="simulation workers per fit")
    ap.add_argument("--extra", nargs=argparse.REMAINDER, default=[], help="extra arguments for softsbi fit")
    a = ap.parse_args()
    recs = [r for r in RECS if not a.only or r in a.only.split(",")]
    extra = [*a.extra, *(["--workers", str(a.workers)] if a.workers else [])]
    for r in recs:
        out = a.out / r
        if (out / "report.json").exists():
            continue
        subprocess.run([sys.executable, "-m", "softsbi.cli", "fit", "--observed", str(a.data / f"lift_{r}"),
                        "--out", str(out), *extra],
                       check=True, stdout=subprocess.DEVNULL)
    reps = {r: json.loads((a.out / r / "report.json").read_text()) for r in recs
            if (a.out / r / "report.json").exists()}
    names = [p["name"] for p in next(iter(reps.values()))["parameters"]]
    print("| recording | Chamfer prior [cm] | Chamfer posterior [cm] | posterior/prior | one-sided posterior [cm] | "
          + " | ".join(names) + " | wall [s] | failed |")
    print("|" + "---|" * (7 + len(names)))
    for r, rep in reps.items():
        ratio = rep["chamfer_posterior_m"] / rep["chamfer_prior_m"]
        one = rep.get("chamfer_posterior_one_sided_m")
        cells = [f"{rep['posterior_mean'][n]:.3g} ± {rep['posterior_std'][n]:.2g}" for n in names]
        print(f"| {r} | {rep['chamfer_prior_m'] * 100:.2f} | {rep['chamfer_posterior_m'] * 100:.2f} | {ratio:.2f} | "
              + ("n/a" if one is None else f"{one * 100:.2f}") + " | "
              + " | ".join(cells) + f" | {rep['wall_time_s']:.0f} | {rep['failed_simulations']} |")
    print("\ncontraction: posterior 90% width / prior 90% width (own scale; * = not informed, ratio > "
          f"{next(iter(reps.values())).get('informed_max_width_ratio', 0.5)})\n")
    print("| recording | " + " | ".join(names) + " | informed |")
    print("|" + "---|" * (2 + len(names)))
    for r, rep in reps.items():
        c = contraction_from_report(rep)
        cells = [f"{c[n]['width_ratio']:.2f}{'' if c[n]['informed'] else '*'}" for n in names]
        print(f"| {r} | " + " | ".join(cells) + f" | {sum(c[n]['informed'] for n in names)} of {len(names)} |")
    # repeats vs other fabrics: distance between posterior means in prior-normalised (unit-cube) units
    names, u = material_unit_means(reps, names)
    same, diff = repeat_fabric_distances(u)
    if same and diff:
        print(f"\ndistance between posterior means (unit-cube units, {', '.join(names)}): repeats of a fabric {np.mean(same):.3f} "
              f"(n={len(same)}), different fabrics {np.mean(diff):.3f} (n={len(diff)})")
        for n_i, n in enumerate(names):
            s_ = [abs(u[x][n_i] - u[y][n_i]) for x, y in itertools.combinations(u, 2) if x.rstrip("2") == y.rstrip("2")]
            d_ = [abs(u[x][n_i] - u[y][n_i]) for x, y in itertools.combinations(u, 2) if x.rstrip("2") != y.rstrip("2")]
            print(f"  {n}: repeats {np.mean(s_):.3f}, different fabrics {np.mean(d_):.3f}")
    print(json.dumps({r: {"posterior_over_prior": rep["chamfer_posterior_m"] / rep["chamfer_prior_m"],
                          "chamfer_prior_m": rep["chamfer_prior_m"], "chamfer_posterior_m": rep["chamfer_posterior_m"],
                          "best_fit": {k: (rep.get("best_fit") or {}).get(k) for k in ("chamfer_m", "source", "theta",
                                                                                       "refine")},
                          "widened": rep.get("widened") or [],
                          "still_pressed": [(e["param"], e["side"], e["mass"]) for e in rep.get("posterior_at_bounds")
                                            or []],
                          "wall_time_s": rep["wall_time_s"], "simulations": rep["simulations"]}
                      for r, rep in reps.items()}))


if __name__ == "__main__":
    sys.exit(main())
