"""Training time of one round at 1500 simulations for every estimator (issue 4).

Data: lift-shaped synthetic states ``(1500, T=25, 1+K=33, 3)`` from the ``blob_task`` of
tests/test_inference.py (2 parameters); training cost depends on shapes and N, not on the
simulator. Default options of every estimator; wall seconds of ``fit`` (early stopping
included) and epochs. Run with ``nice``; on a loaded machine figures are upper bounds.

Usage::

    nice -n 15 python benchmarks/bench_estimators_speed.py [--n 1500] [--methods ...]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

METHODS = ["rkhs", "mdnn", "mdrff", "bayeszoom-rkhs", "nn-bulk", "gp-bulk", "sbi-npe"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1500)
    ap.add_argument("--methods", nargs="+", default=METHODS)
    ap.add_argument("--out", default="/tmp/bench_speed.json")
    args = ap.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from test_inference import blob_task

    from softsbi.plugins import registry
    u, x = blob_task(args.n, T=25, K=32, seed=0)
    rows = []
    for m in args.methods:
        est = registry().estimator(m)()
        info = est.fit(u, x, seed=0)
        rows.append({"estimator": m, "seconds": info["seconds"], "epochs": info.get("epochs"), "n": args.n})
        print(json.dumps(rows[-1]), flush=True)
        Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
