"""The real-lift suite: fit the DiffCloud lift recordings with the defaults of `softsbi fit` and tabulate.

Each recording ``lift_<r>`` of ``--data`` is fitted by ``softsbi fit --observed DATA/lift_<r> --out OUT/<r>`` (plus
``--extra``), in a process of its own; a fit already finished in ``--out`` is reused (resumable). Tables: Chamfer
prior vs posterior under each fit's sensor model (the headline metric), the posterior/prior ratio, the one-sided
measured -> simulated Chamfer, posterior mean ± std per parameter, wall time and failures; the contraction
(posterior 90% width over the prior's per parameter, "not informed" above 0.5); and, with both repeats of a fabric
and two fabrics, the distance between repeats of a fabric vs between different fabrics (prior-normalised units).
Per recording the data also hold the best fit (its Chamfer, source, refinement), the widened bounds and the bounds
still pressed.
"""
from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.fabric_distances import material_unit_means, repeat_fabric_distances
from benchmarks.runner import REPO, in_out_folder, table

RECS = ["tan", "tan2", "navy", "navy2", "paper", "paper2", "polka", "polka2", "redblack", "redblack2"]
FULL = {"only": RECS}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--out", type=Path, default=None, help="folder of the fits, one per recording (resumable; "
                                                           "default: a temporary one)")
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "diffcloud_lift")
    ap.add_argument("--only", nargs="+", default=["tan2"], choices=RECS, help="recordings")
    ap.add_argument("--workers", type=int, default=1, help="simulation workers per fit")
    ap.add_argument("--extra", nargs=argparse.REMAINDER, default=[], help="extra arguments for softsbi fit (last)")


def suite(a: argparse.Namespace) -> dict:
    return in_out_folder(measure, a)


def fit_all(a: argparse.Namespace, out: Path, recs: list[str]) -> dict[str, dict]:
    """Fit every recording of ``recs`` not yet fitted in ``out``; their ``report.json``."""
    for r in recs:
        if (out / r / "report.json").exists():
            continue
        subprocess.run([sys.executable, "-m", "softsbi.cli", "fit", "--observed", str(a.data / f"lift_{r}"),
                        "--out", str(out / r), "--workers", str(a.workers), *a.extra],
                       check=True, stdout=subprocess.DEVNULL)
    return {r: json.loads((out / r / "report.json").read_text()) for r in recs}


def measure(a: argparse.Namespace, out: Path) -> dict:
    from softsbi.inference.contraction import contraction_from_report

    reps = fit_all(a, out, [r for r in RECS if r in a.only])
    names = [p["name"] for p in next(iter(reps.values()))["parameters"]]
    main = []
    for r, rep in reps.items():
        one = rep.get("chamfer_posterior_one_sided_m")
        main.append([r, round(rep["chamfer_prior_m"] * 100, 2), round(rep["chamfer_posterior_m"] * 100, 2),
                     round(rep["chamfer_posterior_m"] / rep["chamfer_prior_m"], 2),
                     None if one is None else round(one * 100, 2),
                     *[f"{rep['posterior_mean'][n]:.3g} ± {rep['posterior_std'][n]:.2g}" for n in names],
                     round(rep["wall_time_s"]), rep["failed_simulations"]])
    first = next(iter(reps.values()))
    budget = f"{first['rounds']} x {first['sims_per_round']}"
    tables = [table(f"Fits ({budget} simulations + posterior rollouts, {first['backend']}, {first['estimator']}): "
                    "headline Chamfer [cm] and posterior mean ± std",
                    ["recording", "prior", "posterior predictive", "posterior/prior", "one-sided posterior", *names,
                     "wall s", "failed"], main)]
    limit = first.get("informed_max_width_ratio", 0.5)
    con = []
    for r, rep in reps.items():
        c = contraction_from_report(rep)
        con.append([r, *[f"{c[n]['width_ratio']:.2f}{'' if c[n]['informed'] else '*'}" for n in names],
                    f"{sum(c[n]['informed'] for n in names)} of {len(names)}"])
    tables.append(table(f"Contraction: posterior 90% width / prior 90% width (own scale; * = not informed, ratio > "
                        f"{limit})", ["recording", *names, "informed"], con))
    notes = []
    mat, u = material_unit_means(reps, names)
    same, diff = repeat_fabric_distances(u)
    if same and diff:
        rows = [["all (Euclidean)", round(np.mean(same), 3), round(np.mean(diff), 3)]]
        for i, n in enumerate(mat):
            s_ = [abs(u[x][i] - u[y][i]) for x, y in itertools.combinations(u, 2) if x.rstrip("2") == y.rstrip("2")]
            d_ = [abs(u[x][i] - u[y][i]) for x, y in itertools.combinations(u, 2) if x.rstrip("2") != y.rstrip("2")]
            rows.append([n, round(np.mean(s_), 3), round(np.mean(d_), 3)])
        tables.append(table(f"Distance between posterior means, unit-cube units ({len(same)} pairs of repeats, "
                            f"{len(diff)} of different fabrics)", ["parameters", "repeats of a fabric",
                                                                   "different fabrics"], rows))
    data = {r: {"posterior_over_prior": rep["chamfer_posterior_m"] / rep["chamfer_prior_m"],
                "chamfer_prior_m": rep["chamfer_prior_m"], "chamfer_posterior_m": rep["chamfer_posterior_m"],
                "posterior_mean": rep["posterior_mean"], "posterior_std": rep["posterior_std"],
                "best_fit": {k: (rep.get("best_fit") or {}).get(k) for k in ("chamfer_m", "source", "theta", "refine")},
                "widened": rep.get("widened") or [],
                "still_pressed": [(e["param"], e["side"], e["mass"]) for e in rep.get("posterior_at_bounds") or []],
                "wall_time_s": rep["wall_time_s"], "simulations": rep["simulations"]}
            for r, rep in reps.items()}
    return {"tables": tables, "notes": notes, "data": data}
