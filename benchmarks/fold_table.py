"""The fold suite: fit the DiffCloud fold recordings through the generic path and tabulate.

The generic path: ``softsbi import diffcloud DATA OUT/recordings --scenario examples/fold.yaml`` (once), then
``softsbi fit --observed OUT/recordings/fold_<rec> --out OUT/<rec>`` with the defaults of ``softsbi fit`` (plus
``--extra``). No fold-specific code: the task is ``examples/fold.yaml``. A fit already finished in ``--out`` is
reused (resumable). Tables: Chamfer prior vs posterior (headline metric), posterior/prior ratio, posterior mean ± std
per parameter, wall time, failed simulations; how many recordings reach posterior/prior <= 0.70; with both repeats
of a fabric and two fabrics, the distance between repeats of a fabric vs between different fabrics (posterior means
in prior-normalised units, material parameters only). Per recording the data also hold what limits a fit that
misses 0.70: the bounds ``--widen`` moved, the bounds its posterior still presses (and whether each is a physical
limit), the parameters the data did not inform, the best fit's Chamfer over the prior's, and the mass of the last
round's posterior inside the prior box.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.fabric_distances import material_unit_means, repeat_fabric_distances
from benchmarks.runner import REPO, in_out_folder, table

RECS = ["tan", "tan2", "navy", "navy2", "paper", "paper2", "polka", "polka2", "redblack", "redblack2"]
FULL = {"recs": RECS}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--out", type=Path, default=None, help="folder of the recordings and fits (resumable; default: a "
                                                           "temporary one)")
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "diffcloud_fold")
    ap.add_argument("--scenario", type=Path, default=REPO / "examples" / "fold.yaml")
    ap.add_argument("--recs", nargs="+", default=["tan"], choices=RECS)
    ap.add_argument("--workers", type=int, default=1, help="simulation workers per fit")
    ap.add_argument("--extra", nargs=argparse.REMAINDER, default=[], help="extra arguments for softsbi fit (last)")


def suite(a: argparse.Namespace) -> dict:
    return in_out_folder(measure, a)


def measure(a: argparse.Namespace, out: Path) -> dict:
    recordings = out / "recordings"
    if not recordings.is_dir():
        subprocess.run([sys.executable, "-m", "softsbi.cli", "import", "diffcloud", str(a.data), str(recordings),
                        "--scenario", str(a.scenario)], check=True, stdout=subprocess.DEVNULL)
    for r in a.recs:
        if (out / r / "report.json").exists():
            continue
        subprocess.run([sys.executable, "-m", "softsbi.cli", "fit", "--observed", str(recordings / f"fold_{r}"),
                        "--out", str(out / r), "--workers", str(a.workers), *a.extra],
                       check=True, stdout=subprocess.DEVNULL)
    reps = {r: json.loads((out / r / "report.json").read_text()) for r in RECS if r in a.recs}
    first = next(iter(reps.values()))
    names = [p["name"] for p in first["parameters"]]
    rows, ratios = [], []
    for r, rep in reps.items():
        ratio = rep["chamfer_posterior_m"] / rep["chamfer_prior_m"]
        ratios.append(ratio)
        rows.append([r, round(rep["chamfer_prior_m"] * 100, 2), round(rep["chamfer_posterior_m"] * 100, 2),
                     round(ratio, 2), *[f"{rep['posterior_mean'][n]:.3g} ± {rep['posterior_std'][n]:.2g}"
                                        for n in names], round(rep["wall_time_s"]), rep["failed_simulations"]])
    tables = [table(f"Fits ({first['rounds']} x {first['sims_per_round']} simulations + posterior rollouts, "
                    f"{first['backend']}, {first['estimator']}): headline Chamfer [cm] and posterior mean ± std",
                    ["recording", "prior", "posterior predictive", "posterior/prior", *names, "wall s", "failed"],
                    rows, note=f"posterior/prior <= 0.70 on {sum(x <= 0.70 for x in ratios)} of {len(ratios)} "
                               "recordings.")]
    mat, u = material_unit_means(reps, names)
    same, diff = repeat_fabric_distances(u)
    notes = []
    if same and diff:
        notes.append(f"Distance between posterior means (unit-cube units, {', '.join(mat)}): repeats of a fabric "
                     f"{np.mean(same):.3f} ({len(same)} pairs), different fabrics {np.mean(diff):.3f} ({len(diff)}).")
    return {"tables": tables, "notes": notes, "data": {r: limits(rep) for r, rep in reps.items()}}


def limits(rep: dict) -> dict:
    """One fit's numbers: its posterior/prior Chamfer, what widened, what still limits it."""
    ratio = rep["chamfer_posterior_m"] / rep["chamfer_prior_m"]
    best = rep.get("best_fit") or {}
    con = rep.get("contraction") or {}
    return {"posterior_over_prior": ratio, "at_most_0.70": bool(ratio <= 0.70),
            "chamfer_prior_m": rep["chamfer_prior_m"], "chamfer_posterior_m": rep["chamfer_posterior_m"],
            "posterior_mean": rep["posterior_mean"], "posterior_std": rep["posterior_std"],
            "best_fit_m": best.get("chamfer_m"),
            "best_fit_over_prior": best["chamfer_m"] / rep["chamfer_prior_m"] if best.get("chamfer_m") else None,
            "widened": [{"after_round": w["after_round"], "before": w["before"], "bounds": w["bounds"]}
                        for w in rep.get("widened") or []],
            "still_pressed": [{"param": e["param"], "side": e["side"], "mass": e["mass"],
                               "physical_limit": e.get("suggested_bounds") is None}
                              for e in rep.get("posterior_at_bounds") or []],
            "not_informed": [n for n, c in con.items() if not c.get("informed")],
            "width_ratio": {n: c.get("width_ratio") for n, c in con.items()},
            "mass_in_box_last_round": (rep.get("per_round") or [{}])[-1].get("mass_in_box"),
            "simulations": rep.get("simulations"), "wall_time_s": rep.get("wall_time_s"),
            "failed_simulations": rep.get("failed_simulations")}
