"""The speed suite: what a user waits for, each command in a fresh process (wall seconds).

* startup: ``softsbi --help`` and ``softsbi plugins`` (median of ``--repeats``);
* a fit of the toy simulator (``toy-gauss``, the third-party plugin in tests/plugins/softsbi_toy: ``pip install -e
  tests/plugins/softsbi_toy``): ``softsbi simulate`` writes its recording, then ``softsbi fit --rounds R
  --sims-per-round N --workers W`` and ``softsbi check`` of the run, each once.

Every timing is one row ``(what, command, seconds)`` made by :func:`timed`; a new timing (another command, or the same
commands of another checkout) is one more call of it in :func:`suite`.
"""
from __future__ import annotations

import argparse
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

from benchmarks.runner import table

FULL = None


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--repeats", type=int, default=3, help="runs of each startup command (the median is reported)")
    ap.add_argument("--rounds", type=int, default=2, help="rounds of the toy fit")
    ap.add_argument("--sims", type=int, default=100, help="simulations per round of the toy fit")
    ap.add_argument("--workers", type=int, default=1, help="simulation workers of the toy fit and its check")


def timed(args: Sequence[str], repeats: int = 1, cwd: Path | None = None, env: dict | None = None) -> float:
    """Median wall seconds of ``python -m softsbi.cli ARGS`` over ``repeats`` fresh processes (``cwd``: the folder
    the command runs in; ``env``: its environment, e.g. a PYTHONPATH naming another checkout). Raises SystemExit
    with the command's last error line when it fails."""
    cmd = [sys.executable, "-m", "softsbi.cli", *args]
    walls = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
        walls.append(time.perf_counter() - t0)
        if res.returncode != 0:
            last = (res.stderr.strip().splitlines() or ["(no output)"])[-1]
            raise SystemExit(f"`softsbi {shlex.join(args)}` failed (exit {res.returncode}): {last}")
    return statistics.median(walls)


def suite(opts: argparse.Namespace) -> dict:
    from softsbi.plugins import registry

    if "toy-gauss" not in registry().names("simulator"):
        raise SystemExit("the speed suite's fit needs the toy simulator: pip install -e tests/plugins/softsbi_toy")
    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "1"))
    rows = []

    def add(what: str, args: list[str], repeats: int = 1, shown: list[str] | None = None, **kw) -> None:
        rows.append([what, "softsbi " + shlex.join(shown or args), round(timed(args, repeats, env=env, **kw), 2)])

    add("startup", ["--help"], opts.repeats)
    add("list the plugins", ["plugins"], opts.repeats)
    with tempfile.TemporaryDirectory() as tmp:
        fit = ["fit", "--observed", "rec", "--out", "run", "--backend", "toy-gauss", "--rounds", str(opts.rounds),
               "--sims-per-round", str(opts.sims), "--workers", str(opts.workers)]
        add("simulate the toy recording", ["simulate", "--backend", "toy-gauss", "--out", "rec"], cwd=Path(tmp))
        add(f"toy fit, {opts.rounds} x {opts.sims} simulations", fit, cwd=Path(tmp))
        add("check the toy fit", ["check", "run", "--workers", str(opts.workers)], cwd=Path(tmp))
    return {"tables": [table("Wall seconds, fresh process each (startup: median of the repeats)",
                             ["what", "command", "s"], rows)],
            "data": {"rows": [dict(zip(("what", "command", "seconds"), r)) for r in rows]}}
