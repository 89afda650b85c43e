"""The newton-demo suite: the demo's story on newton-cloth, against mujoco-flex in the same run.

``softsbi demo --backend B`` for each backend of ``--backends``: a lift recording is simulated on B at hidden
parameters with a hidden wind, fitted with B's nominal model, checked and diagnosed on B (the installed effects B
applies are the candidates; the top one is refitted), and the two fits are compared. Each demo runs in a fresh
process with an empty simulation bank (as on a fresh machine). A row: the verdict, the named effect, the
posterior-predictive Chamfer and the energy score before and after, the nominal fit's simulations per second
(its simulations over its wall time; newton-cloth's workers roll them out in batches) and the demo's wall time.

Needs the optional Newton package for newton-cloth; without it the suite stops in one line naming
``pip install "softsbi[newton]"``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.runner import table

FULL = None


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--backends", nargs="+", default=["newton-cloth", "mujoco-flex"],
                    help="simulator plugins the demo runs on, one demo each")
    ap.add_argument("--workers", type=int, default=2, help="worker processes of each demo")


def _demo(backend: str, workers: int, tmp: Path) -> tuple[dict, float]:
    """``softsbi demo --backend BACKEND --json``'s document and wall seconds. Raises SystemExit with the demo's last
    error line when it fails."""
    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "1"),
               SOFTSBI_SIM_BANK=str(tmp / f"bank-{backend}"))
    cmd = [sys.executable, "-m", "softsbi.cli", "demo", "--backend", backend, "--out", str(tmp / backend),
           "--workers", str(workers), "--json"]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        last = (res.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise SystemExit(f"`softsbi demo --backend {backend}` failed (exit {res.returncode}): {last}")
    return json.loads(res.stdout), wall


def _cm(x: float | None) -> float | None:
    return None if x is None else round(100 * x, 2)


def suite(a: argparse.Namespace) -> dict:
    if "newton-cloth" in a.backends:
        from softsbi.backends.newton_cloth import import_newton
        from softsbi.core.errors import DependencyMissing
        try:
            import_newton()
        except DependencyMissing as exc:
            raise SystemExit(str(exc)) from None
    rows, data = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for backend in a.backends:
            doc, wall = _demo(backend, a.workers, Path(tmp))
            nominal = doc["nominal"]
            verdict = ((doc.get("diagnosis") or {}).get("decision") or {}).get("verdict")
            fit_rate = round(nominal["simulations"] / nominal["wall_time_s"], 2)
            row = {"backend": backend, "verdict": verdict, "named": doc.get("named"),
                   "named_correctly": doc.get("named_correctly"),
                   **{f"{k}_cm": _cm(doc.get(f"{k}_m")) for k in ("chamfer_before", "chamfer_after", "energy_before",
                                                                   "energy_after")},
                   "fit_simulations": nominal["simulations"], "fit_per_s": fit_rate, "demo_s": round(wall, 1)}
            data.append(row)
            rows.append([backend, row["verdict"], row["named"] or "-", row["chamfer_before_cm"],
                         row["chamfer_after_cm"], row["energy_before_cm"], row["energy_after_cm"], fit_rate,
                         row["demo_s"]])
    note = (f"Hidden effect: wind (the demo's). {a.workers} workers per demo, an empty simulation bank each. Chamfer: "
            "posterior-predictive Chamfer of the nominal fit and of the named effect's refit; energy: the Chamfer "
            "energy score (a proper score) of the same rollouts; fit sims/s: the nominal fit's simulations over its "
            "wall time.")
    return {"tables": [table("softsbi demo on each engine: the hidden wind simulated, fitted, diagnosed and refitted "
                             "on the same engine",
                             ["backend", "verdict", "named", "Chamfer before cm", "Chamfer after cm",
                              "energy before cm", "energy after cm", "fit sims/s", "demo s"], rows, note=note)],
            "data": {"rows": data}}
