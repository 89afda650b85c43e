"""How much of a hidden physics effect's motion can a sensor effect reproduce? (issue 19; BENCHMARKS.md, twenty-ninth
session)

For benchmark cases of ``diagnose_stats.py`` (their hidden truths, :func:`diagnose_stats.make_case`), two rollouts at
the truth, with and without the hidden physics effect, and for each sensor effect asked the share of the difference
its observation transform reproduces (:func:`softsbi.workflows.mimicry.best_sensor_match`, as ``diagnose`` measures it
at a refit's estimates). One JSON line per case; ``--table`` prints the Markdown table of a results file.

    python benchmarks/mimicry.py --suite mujoco --cases 1324,1209,1004 --out runs/mimicry.jsonl
    python benchmarks/mimicry.py --table runs/mimicry.jsonl
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from diagnose_stats import make_case  # noqa: E402

import softsbi  # noqa: E402
from softsbi.plugins import registry  # noqa: E402
from softsbi.workflows.mimicry import MIMIC_SHARE, best_sensor_match, motion_distance  # noqa: E402

SENSORS = ("time-offset", "calibration-offset")


def case_mimicry(suite: str, index: int, sensors: tuple[str, ...] = SENSORS, seed: int = 0) -> dict:
    """The share of case ``index``'s hidden physics effect that each of ``sensors`` reproduces, at the case's truth."""
    case = make_case(suite, seed, index)
    label = case["truth_label"]
    names = registry().effect(label)().param_space().names
    on = softsbi.simulate(case["scenario"], case["truth"], effects=[label])
    off = softsbi.simulate(case["scenario"], {k: v for k, v in case["truth"].items() if k not in names})
    effect = motion_distance(on, off)
    row = {"suite": suite, "index": index, "effect": label, "scenario": case["scenario"],
           "magnitude": case["magnitude"], "effect_m": effect, "sensors": {}}
    for s in sensors:
        residual, est = best_sensor_match(on, off, s)
        row["sensors"][s] = {"share": 1.0 - residual / effect, "residual_m": residual, "estimate": est}
    return row


def table(path: Path) -> str:
    """The Markdown table of a results file written by ``--out`` (one row per case; shares at or above
    :data:`~softsbi.workflows.mimicry.MIMIC_SHARE` in bold; estimates in the sensor parameters' units)."""
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    sensors = sorted({s for r in rows for s in r["sensors"]})
    out = ["| case | hidden effect | scenario, magnitude | its motion [cm] | "
           + " | ".join(f"share reproduced by {s} (estimate)" for s in sensors) + " |",
           "|---" * (4 + len(sensors)) + "|"]
    for r in rows:
        cells = []
        for s in sensors:
            m = r["sensors"][s]
            est = ", ".join(f"{v:.3g}" for v in m["estimate"].values())
            mark = "**" if m["share"] >= MIMIC_SHARE else ""
            cells.append(f"{mark}{m['share']:.2f}{mark} ({est})")
        out.append(f"| {r['suite']} {r['index']} | {r['effect']} | {r['scenario']}, {r['magnitude']:.2f} | "
                   f"{r['effect_m'] * 100:.2f} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> None:
    """Command line: measure ``--cases`` of ``--suite`` (appending to ``--out``), or print ``--table``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", default="mujoco")
    ap.add_argument("--cases", default="", help="comma-separated case indices of --suite (hidden physics effects)")
    ap.add_argument("--out", type=Path, help="append one JSON line per case here")
    ap.add_argument("--table", type=Path, help="print the Markdown table of a results file and exit")
    a = ap.parse_args(argv)
    if a.table:
        print(table(a.table))
        return
    for i in (int(c) for c in a.cases.split(",") if c):
        row = json.dumps(case_mimicry(a.suite, i))
        print(row, flush=True)
        if a.out:
            with a.out.open("a") as f:
                f.write(row + "\n")


if __name__ == "__main__":
    main()
