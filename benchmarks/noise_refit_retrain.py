"""Is a point-noise refit's noise level identifiable? Retrain the refit's final round with and without the
local-thickness summary (issue 19, BENCHMARKS.md "Fifteenth session: point noise becomes identifiable").

For each case directory of the statistical benchmark (``diagnose_stats.py``'s ``--out``) that holds a
``refit-point-noise`` run, the final round's estimator is retrained on all that refit's stored simulations
(``estimator_variants_twin.retrain``: the fit's own training set and frames, training seed 0) with
``frame_thickness`` off and on, and the posterior of ``noise_std`` at the measurement is printed beside the case's
truth (from ``--results``).

Usage:
    python benchmarks/noise_refit_retrain.py /work/bench_runs/s35/ds/mujoco-more-s0-510-refit2-joint-truncated \
        /work/bench_runs/s34/ds/mujoco-more-s0-482-refit2-joint-truncated
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from estimator_variants_twin import retrain  # noqa: E402

from softsbi.core.store import RunStore  # noqa: E402
from softsbi.workflows.runs import load_run  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", type=Path, nargs="+", help="case directories with a refit-point-noise run")
    ap.add_argument("--results", type=Path, default=Path("benchmarks/results/diagnose_stats.jsonl"))
    a = ap.parse_args()
    rows = {r["id"]: r for r in map(json.loads, a.results.read_text().splitlines()) if r}
    for d in a.cases:
        refit = d / "refit-point-noise"
        if d.name not in rows or not (refit / "run.zarr").exists():
            print(f"{d}: no stored row or no refit-point-noise run; skipped", file=sys.stderr)
            continue
        truth = rows[d.name]["truth"].get("noise_std")
        store, space = RunStore.open(refit / "run.zarr"), load_run(refit).space
        j = space.names.index("noise_std")
        for on in (False, True):
            pm, _, sd = retrain(store, space, {"frame_thickness": on}, 0)
            print(f"{d.name} ({rows[d.name]['scenario']}): truth {truth * 1000:.1f} mm; frame_thickness={on}: "
                  f"posterior mean {pm[j] * 1000:.1f} mm, sd {sd[j]:.3f} (unit cube)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
