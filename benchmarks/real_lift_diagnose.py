"""`softsbi diagnose` on every real lift fit of a folder, and the verdict table (issue 19, item 6).

Usage: python benchmarks/real_lift_diagnose.py --fits /work/bench_runs/trunc [--only tan,navy2]
    [--workers 1] [--table-only]
Runs `softsbi diagnose FIT --confirm 2` on each fit that has no diagnosis.json yet (fits from
`benchmarks/real_lift_all.py`), then prints one Markdown row per recording: posterior/prior, the joint
test's two components (omnibus p; directional p with its strongest candidate and that candidate's
share of the residual), the joint p, the verdict, and each refit's Chamfer change and the joint p of
check on the refit (rule 3 needs more than 0.2).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

RECS = ["tan", "tan2", "navy", "navy2", "paper", "paper2", "polka", "polka2", "redblack", "redblack2"]


def p_short(m: dict) -> str:
    """A joint / component p as the table prints it: ``<= k/(n+1)`` at the floor, else two decimals."""
    n = m["n_null"]
    if m.get("exceed") == 0 or m.get("at_floor"):  # a component beyond every null, or the joint test at its floor
        return f"<= {round(m['resolution'] * (n + 1))}/{n + 1}"
    return f"{m['p_value']:.2g}"


def row(rec: str, fit: Path) -> str:
    rep = json.loads((fit / "report.json").read_text())
    d = json.loads((fit / "diagnosis.json").read_text())
    m = d["misspecification"]
    om, di = m["omnibus"], m["directional"]
    refits = "; ".join(
        f"{c['effect']} {-c['drop'] * 100:+.0f}%, p {p_short(c['misspecification_after'])}"
        for c in d["confirmed"] if c.get("drop") is not None and c.get("misspecification_after")) or "-"
    return (f"| {rec} | {rep['chamfer_posterior_m'] / rep['chamfer_prior_m']:.2f} | {p_short(om)} | "
            f"{p_short(di)} ({di['effect']}, {di['explained_fraction'] * 100:.0f}%) | {p_short(m)} | "
            f"{d['verdict']} | {refits} |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--fits", type=Path, required=True, help="folder of fits, one per recording")
    ap.add_argument("--only", default="", help="comma-separated recordings (default: all 10)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--table-only", action="store_true", help="only tabulate the diagnoses already there")
    a = ap.parse_args()
    recs = [r for r in RECS if (not a.only or r in a.only.split(",")) and (a.fits / r / "report.json").exists()]
    if not a.table_only:
        for r in recs:
            if not (a.fits / r / "diagnosis.json").exists():
                subprocess.run([sys.executable, "-m", "softsbi.cli", "diagnose", str(a.fits / r), "--workers",
                                str(a.workers), "--confirm", "2"], check=True, stdout=subprocess.DEVNULL)
    print("| recording | posterior/prior | omnibus p | directional p (strongest, share) | joint p | verdict | "
          "refits: Chamfer change, check p |")
    print("|---|---|---|---|---|---|---|")
    for r in recs:
        if (a.fits / r / "diagnosis.json").exists():
            print(row(r, a.fits / r))


if __name__ == "__main__":
    main()
