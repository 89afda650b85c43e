"""Where a posterior's mass sits next to its prior bounds, against where the hidden value lies (the statistical
benchmark's stored fits): the evidence behind ``softsbi.inference.contraction.BOUND_MASS_MIN``.

For every stored case of ``benchmarks/diagnose_stats.py`` whose run directory is on disk (``--runs``: folders
named by case id, each a nominal fit with its ``refit-<effect>/`` folders), every fit (nominal and refits) and every
parameter with a known hidden value: the share of 4000 posterior draws in the slab of width
:data:`~softsbi.inference.contraction.BOUND_SLAB` next to each bound, in the parameter's own scale. Then, per
threshold: how often the rule fires for hidden values inside the prior (15-85% of the range) in correctly specified
fits (controls), in misspecified nominal fits, and for hidden values within 10% of a bound.

Usage:
    python benchmarks/bound_pressure_study.py --runs '/work/bench_runs/*/ds/*' --out bound_pressure.json
    python benchmarks/bound_pressure_study.py --table bound_pressure.json
"""
from __future__ import annotations

import argparse
import glob
import json
from pathlib import Path

import numpy as np

from softsbi.inference.contraction import BOUND_SLAB
from softsbi.workflows.runs import open_run

RESULTS = Path(__file__).resolve().parent / "results" / "diagnose_stats.jsonl"


def study(pattern: str, results: Path = RESULTS) -> list[dict]:
    """One row per (case, fit, parameter with a hidden value): ``truth_u`` (its place in the prior, unit scale),
    ``low_mass``/``high_mass`` (posterior share within :data:`BOUND_SLAB` of each bound)."""
    rows = {json.loads(line)["id"]: json.loads(line) for line in results.read_text().splitlines() if line.strip()}
    out = []
    for d in sorted(glob.glob(pattern)):
        case = rows.get(Path(d).name)
        if case is None or not (Path(d) / "report.json").exists():
            continue
        fits = [(Path(d), "nominal")] + [(r, "refit:" + r.name[len("refit-"):]) for r in sorted(Path(d).glob("refit-*"))
                                          if (r / "report.json").exists()]
        for path, what in fits:
            post = open_run(path).posterior
            u = post.unit.sample(4000, np.random.default_rng(0))
            u = u[np.all((u >= 0) & (u <= 1), axis=1)]  # the posterior is restricted to the prior box
            for j, p in enumerate(post.space):
                if p.name not in case["truth"]:
                    continue
                ut = float(post.space.subset([p.name]).to_unit(np.array([case["truth"][p.name]]))[0])
                out.append({"id": case["id"], "fit": what, "param": p.name, "truth_u": ut, "label": case["truth_label"],
                            "low_mass": float((u[:, j] <= BOUND_SLAB).mean()),
                            "high_mass": float((u[:, j] >= 1 - BOUND_SLAB).mean())})
    return out


def table(rows: list[dict], thresholds=(0.1, 0.15, 0.2, 0.25, 0.3)) -> str:
    """Markdown: per threshold, how often the rule fires in each group (counted per parameter and bound)."""
    groups = {"controls, hidden value inside": lambda r, s: r["label"] == "control" and 0.15 < r["truth_u"] < 0.85,
              "misspecified nominal fits, hidden value inside": lambda r, s: r["label"] != "control"
              and r["fit"] == "nominal" and 0.15 < r["truth_u"] < 0.85,
              "refits, hidden value within 10% of this bound": lambda r, s: r["fit"] != "nominal"
              and (r["truth_u"] > 0.9 if s == "high" else r["truth_u"] < 0.1)}
    lines = ["| rule: mass within 5% of a bound >= | " + " | ".join(groups) + " |", "|---" * (len(groups) + 1) + "|"]
    for t in thresholds:
        cells = []
        for f in groups.values():
            sel = [(r, s) for r in rows for s in ("low", "high") if f(r, s)]
            cells.append(f"{sum(r[s + '_mass'] >= t for r, s in sel)} of {len(sel)}")
        lines.append(f"| {t:g} | " + " | ".join(cells) + " |")
    ctrl = [max(r["low_mass"], r["high_mass"]) for r in rows if r["label"] == "control"]
    if ctrl:
        lines.append(f"\nLargest slab mass of any parameter in a control fit: {max(ctrl):.3f} "
                     f"({len({r['id'] for r in rows if r['label'] == 'control'})} controls).")
    return "\n".join(lines)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", help="glob of the stored cases' run directories")
    ap.add_argument("--out", type=Path, default=Path("bound_pressure.json"))
    ap.add_argument("--table", type=Path, help="print the table of a stored study")
    a = ap.parse_args()
    if a.table:
        print(table(json.loads(a.table.read_text())))
    else:
        res = study(a.runs)
        a.out.write_text(json.dumps(res))
        print(table(res))
