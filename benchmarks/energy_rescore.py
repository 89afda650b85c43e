"""Re-score stored diagnoses' refits with the energy score (the statistical benchmark's run directories).

``diagnose`` reports each refit's posterior-predictive Chamfer and, since the fourteenth session, its energy score
(:func:`softsbi.workflows.stats.energy_score`). Rows stored before carry the Chamfer drop only. For a row whose
run directory is still on disk (``--runs``: ``<case id>/`` with its nominal fit and ``refit-<named>/``), this
re-simulates the fit's own evaluation samples of the nominal fit and of the named effect's refit with their seeds
(the same rollouts, so the Chamfer reproduces the stored drop) and prints one JSON line per row: the truth, the
named effect, the Chamfer drop and the energy score's drop, with both scores.

Usage:
    python benchmarks/energy_rescore.py --runs /work/bench_runs/s34/ds/* > energy_rescore.jsonl
    python benchmarks/energy_rescore.py --table energy_rescore.jsonl
    python benchmarks/energy_rescore.py --merge energy_rescore.jsonl   # into benchmarks/results/diagnose_stats.jsonl
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from softsbi.workflows.stats import PosteriorPredictive, energy_score


def rescore(run_dir: Path, row: dict) -> dict | None:
    """The energy score of the nominal fit in ``run_dir`` and of its refit with the row's named effect
    (None when the row named nothing or the refit is not on disk)."""
    refit = run_dir / f"refit-{row['named']}"
    if not row.get("named") or not (refit / "report.json").exists():
        return None
    out = {}
    for k, p in (("before", run_dir), ("after", refit)):
        pool = PosteriorPredictive(p, 1)
        out[k] = energy_score(pool.ensure(len(pool.run.post_theta)))
    b, a = out["before"], out["after"]
    return {"id": row["id"], "truth": row["truth_label"], "named": row["named"], "correct": row["correct"],
            "chamfer_drop": 1 - a["chamfer_m"] / b["chamfer_m"], "energy_drop": 1 - a["energy_m"] / b["energy_m"],
            "before": b, "after": a}


def table(path: Path) -> str:
    """A markdown table of re-scored rows, with the medians over the correctly named ones."""
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    out = ["| case | hidden | named | Chamfer [cm] | spread [cm] | energy score [cm] | Chamfer drop | energy drop |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        b, a = r["before"], r["after"]
        out.append(f"| {r['id'].split('-refit')[0]} | {r['truth']} | {r['named']} | "
                   f"{b['chamfer_m'] * 100:.2f} -> {a['chamfer_m'] * 100:.2f} | "
                   f"{b['spread_m'] * 100:.2f} -> {a['spread_m'] * 100:.2f} | "
                   f"{b['energy_m'] * 100:.2f} -> {a['energy_m'] * 100:.2f} | {r['chamfer_drop'] * 100:+.0f}% | "
                   f"{r['energy_drop'] * 100:+.0f}% |")
    ok = [r for r in rows if r["correct"]]
    if ok:
        out.append(f"\nCorrectly named: {len(ok)}; median Chamfer drop "
                   f"{np.median([r['chamfer_drop'] for r in ok]) * 100:.0f}%, median energy-score drop "
                   f"{np.median([r['energy_drop'] for r in ok]) * 100:.0f}%.")
    return "\n".join(out)


def merge(rescored: Path, results: Path) -> int:
    """Store each re-scored row's energy drop in its stored row (``results``): the named effect's refit entry gains
    the drop as its seventh field, where ``diagnose_stats.py`` stores it for new rows, and the row is marked
    ``energy_rescored``. Only where the re-scoring reproduced the stored Chamfer drop (to 1e-6), i.e. the same
    rollouts. Returns the number of rows changed."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from diagnose_stats import load_rows, save_rows
    rows = load_rows(results)
    by_id = {r["id"]: r for r in rows}
    k = 0
    for e in map(json.loads, rescored.read_text().splitlines()):
        row = by_id.get(e["id"])
        entry = next((x for x in (row or {}).get("refits") or [] if x[0] == e["named"]), None)
        if entry is None or entry[1] is None or abs(entry[1] - e["chamfer_drop"]) > 1e-6:
            print(f"{e['id']}: not merged (no stored refit of {e['named']} with the same Chamfer drop)",
                  file=sys.stderr)
            continue
        entry[6:] = [e["energy_drop"]]
        row["energy_rescored"] = True
        k += 1
    save_rows(results, rows)
    return k


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=Path, nargs="*", default=[], help="the cases' run directories")
    ap.add_argument("--results", type=Path, default=Path("benchmarks/results/diagnose_stats.jsonl"))
    ap.add_argument("--table", type=Path, default=None, help="print the table of a re-scored JSONL file")
    ap.add_argument("--merge", type=Path, default=None, help="store the energy drops of a re-scored JSONL file in "
                                                             "--results (merge)")
    a = ap.parse_args()
    if a.table:
        print(table(a.table))
        return
    if a.merge:
        print(f"{merge(a.merge, a.results)} rows given their energy-score drop")
        return
    if not a.runs:
        sys.exit("name the run directories to re-score (--runs DIR ...), or --table FILE")
    rows = {r["id"]: r for r in map(json.loads, a.results.read_text().splitlines())}
    for d in a.runs:
        row = rows.get(d.name)
        res = rescore(d, row) if row else None
        if res:
            print(json.dumps(res), flush=True)


if __name__ == "__main__":
    main()
