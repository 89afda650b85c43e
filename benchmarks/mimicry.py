"""How much of a hidden physics effect's motion can another effect reproduce? (issue 19; BENCHMARKS.md, twenty-ninth
and thirtieth sessions)

For benchmark cases of ``diagnose_stats.py`` (their hidden truths, :func:`diagnose_stats.make_case`), two rollouts at
the truth, with and without the hidden physics effect, and for each stand-in effect asked the share of the difference
it reproduces, as ``diagnose`` measures it at a refit's estimates: a sensor effect's observation transform of the
rollout without the effect (:func:`softsbi.workflows.mimicry.best_sensor_match`), or a physics effect simulated in its
place (:func:`softsbi.workflows.mimicry.best_physics_match`; ``--standins physics`` asks every built-in physics effect
but the hidden one). One JSON line per case; ``--table`` prints the Markdown table of a results file.

    python benchmarks/mimicry.py --suite mujoco --cases 1324,1209,1004 --out runs/mimicry.jsonl
    python benchmarks/mimicry.py --suite mujoco --cases 2,3 --standins physics --out runs/mimicry_physics.jsonl
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
from softsbi.core.errors import SoftsbiError  # noqa: E402
from softsbi.plugins import registry  # noqa: E402
from softsbi.workflows.mimicry import (  # noqa: E402
    MIMIC_SHARE,
    best_physics_match,
    best_sensor_match,
    motion_distance,
)
from softsbi.workflows.screening import effect_kind  # noqa: E402

SENSORS = ("time-offset", "calibration-offset")
#: the built-in physics effects the benchmark hides (diagnose_stats's suites mujoco and mujoco-more)
PHYSICS = ("air-drag", "extra-damping", "wind", "grip-compliance", "table-slope", "heavy-hem", "sticky-patch")


def case_mimicry(suite: str, index: int, standins: tuple[str, ...] = SENSORS, seed: int = 0) -> dict:
    """The share of case ``index``'s hidden physics effect that each of ``standins`` reproduces, at the case's truth
    (the hidden effect itself is skipped). Stored under ``sensors`` (the key of the first version) with each stand-in's
    kind."""
    case = make_case(suite, seed, index)
    label = case["truth_label"]
    names = registry().effect(label)().param_space().names
    base = {k: v for k, v in case["truth"].items() if k not in names}
    on = softsbi.simulate(case["scenario"], case["truth"], effects=[label])
    off = softsbi.simulate(case["scenario"], base)
    effect = motion_distance(on, off)
    row = {"suite": suite, "index": index, "effect": label, "scenario": case["scenario"],
           "magnitude": case["magnitude"], "effect_m": effect, "sensors": {}}
    for s in standins:
        if s == label:
            continue
        kind = effect_kind(registry().effect(s))
        if kind == "sensor":
            residual, est = best_sensor_match(on, off, s)
        else:
            try:
                residual, est = best_physics_match(
                    on, lambda p, s=s: softsbi.simulate(case["scenario"], {**base, **p}, effects=[s]), s)
            except SoftsbiError as e:  # an effect the scenario does not support: no measure
                row["sensors"][s] = {"error": str(e)[:200], "kind": "physics"}
                continue
        row["sensors"][s] = {"share": 1.0 - residual / effect, "residual_m": residual, "estimate": est,
                             "kind": "sensor" if kind == "sensor" else "physics"}
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
            m = r["sensors"].get(s)
            if m is None or "share" not in m:
                cells.append("-")
                continue
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
    ap.add_argument("--standins", default="sensors",
                    help="'sensors' (time and calibration offsets), 'physics' (the built-in physics effects) or a "
                         "comma-separated list of effect names")
    ap.add_argument("--out", type=Path, help="append one JSON line per case here")
    ap.add_argument("--table", type=Path, help="print the Markdown table of a results file and exit")
    a = ap.parse_args(argv)
    if a.table:
        print(table(a.table))
        return
    for i in (int(c) for c in a.cases.split(",") if c):
        standins = {"sensors": SENSORS, "physics": PHYSICS}.get(a.standins) or tuple(a.standins.split(","))
        row = json.dumps(case_mimicry(a.suite, i, standins))
        print(row, flush=True)
        if a.out:
            with a.out.open("a") as f:
                f.write(row + "\n")


if __name__ == "__main__":
    main()
