"""The speed suite: what a user waits for, each command in a fresh process (wall seconds).

* startup: ``softsbi --help`` and ``softsbi plugins`` (median of ``--repeats``);
* a fit of the toy simulator (``toy-gauss``, the third-party plugin in tests/plugins/softsbi_toy: ``pip install -e
  tests/plugins/softsbi_toy``): ``softsbi simulate`` writes its recording, then ``softsbi fit --rounds R
  --sims-per-round N --workers W`` and ``softsbi check`` of the run, each once;
* with ``--demo`` (``--full``): ``softsbi demo`` (and the same demo of an older checkout, ``--old PATH``, in the same
  run, with the ratio), then on a copy of the demo's nominal run without its derived results: ``check`` and
  ``diagnose`` (default settings) against the run's own fit time, each repeated (reading its stored result), and
  ``compare`` of the two checked runs;
* with ``--bank N`` (``--full``: 3): N simulated recordings of one lift task fitted in a row with the defaults,
  once with a fresh simulation bank and once without (``--no-sim-bank``): wall time and the first round's
  simulations read from the bank;
* with ``--tests`` (``--full``): README command 2's tests (``pytest -m "not slow" -n 2 --dist loadscope``) and the unit tier.

Every timing is one row ``(what, command, seconds)`` made by :func:`timed`; a new timing (another command, or the same
commands of another checkout) is one more call of it in :func:`suite`. Every command runs as on a fresh machine: the
user's simulation bank is a new, empty folder (``SOFTSBI_SIM_BANK``), a run's own bank is on as by default; the bank's
rows fit once without any bank (``--no-sim-bank``).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

from benchmarks.runner import REPO, table

FULL = {"demo": True, "bank": 3, "tests": True}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--repeats", type=int, default=3, help="runs of each startup command (the median is reported)")
    ap.add_argument("--rounds", type=int, default=2, help="rounds of the toy fit")
    ap.add_argument("--sims", type=int, default=100, help="simulations per round of the toy fit")
    ap.add_argument("--workers", type=int, default=1, help="simulation workers of the toy fit and its check")
    ap.add_argument("--demo", action="store_true", help="time the demo and check/diagnose/compare on its run")
    ap.add_argument("--old", type=Path, default=None, help="a checkout of an older commit whose demo is timed too")
    ap.add_argument("--bank", type=int, default=0, help="simulated lift recordings fitted with and without a bank")
    ap.add_argument("--tests", action="store_true", help="time README command 2's tests and the unit tier")


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
    fresh_bank = tempfile.TemporaryDirectory()  # the user's bank of a fresh machine: empty
    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "1"),
               SOFTSBI_SIM_BANK=str(Path(fresh_bank.name) / "bank"))
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
    tables = [table("Wall seconds, fresh process each (startup: median of the repeats)", ["what", "command", "s"],
                    rows)]
    data: dict = {"rows": [dict(zip(("what", "command", "seconds"), r)) for r in rows]}
    if opts.demo:
        data["demo"] = _demo(opts, env, tables)
    if opts.bank:
        data["bank"] = _bank(opts, env, tables)
    if opts.tests:
        data["tests"] = _tests(env, tables)
    fresh_bank.cleanup()
    return {"tables": tables, "data": data}


def _strip(run: Path, dst: Path) -> Path:
    """A copy of run directory ``run`` without its derived results (checks, diagnoses, refits, its own bank)."""
    shutil.copytree(run, dst, ignore=shutil.ignore_patterns("check.*", "diagnosis.json", "refit-*", "sims.zarr",
                                                               "view.*"))
    return dst


def _demo(opts: argparse.Namespace, env: dict, tables: list) -> dict:
    """``softsbi demo`` (new, and ``--old``'s), then check/diagnose/compare on the demo's nominal run."""
    out: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        demo = timed(["demo", "--out", "demo"], cwd=tmp, env=env)
        report = json.loads((tmp / "demo" / "nominal" / "report.json").read_text())
        out.update(demo_s=round(demo, 1), fit_s=round(report["wall_time_s"], 1))
        rows = [["demo (this commit)", "softsbi demo", round(demo, 1), ""]]
        if opts.old is not None:
            old_env = dict(env, PYTHONPATH=str(Path(opts.old).resolve()))
            old = timed(["demo", "--out", "demo-old"], cwd=tmp, env=old_env)
            out.update(old_demo_s=round(old, 1), demo_ratio=round(demo / old, 2))
            rows.append([f"demo ({_commit(opts.old)})", "softsbi demo", round(old, 1), f"new / old {demo / old:.2f}"])
        nominal = _strip(tmp / "demo" / "nominal", tmp / "nominal")
        env = dict(env, SOFTSBI_SIM_BANK=str(tmp / "empty-bank"))  # not the one the demo's own refits filled
        fit = report["wall_time_s"]
        rows.append(["the demo's nominal fit", "(report.json wall_time_s)", round(fit, 1), ""])
        for what, args in (("check", ["check", "nominal"]), ("diagnose", ["diagnose", "nominal"]),
                           ("check again (stored)", ["check", "nominal"]),
                           ("diagnose again (stored)", ["diagnose", "nominal"])):
            sec = timed(args, cwd=tmp, env=env)
            out[what.split(" ")[0] + ("_again_s" if "again" in what else "_s")] = round(sec, 1)
            rows.append([what, "softsbi " + shlex.join(args), round(sec, 1),
                         f"{sec / fit:.2f} x the fit" if "again" not in what else ""])
        refit = next(p.name for p in nominal.iterdir() if p.name.startswith("refit-"))
        sec = timed(["compare", "nominal", f"nominal/{refit}"], cwd=tmp, env=env)
        out["compare_s"] = round(sec, 1)
        rows.append(["compare of two checked runs", f"softsbi compare nominal nominal/{refit}", round(sec, 1), ""])
    tables.append(table("The demo and the model-error commands on its nominal run (wall seconds)",
                        ["what", "command", "s", "ratio"], rows))
    return out


def _bank(opts: argparse.Namespace, env: dict, tables: list) -> dict:
    """``opts.bank`` simulated recordings of the lift at other hidden parameters, fitted in a row with the defaults:
    with a fresh bank and without."""
    from softsbi.core.store import RunStore
    from softsbi.workflows.fit.bank import SimulationBank
    rows, out = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for i in range(opts.bank):
            theta = ["--theta", f"stretch={20 + 40 * i}", "--theta", f"friction={0.3 + 0.2 * i}"]
            timed(["simulate", "--scenario", "lift", *theta, "--out", f"rec{i}"], cwd=tmp, env=env)
        for mode in ("without a bank", "with a bank"):
            envb = dict(env, SOFTSBI_SIM_BANK=str(tmp / "bank") if mode == "with a bank" else "off")
            total, read = 0.0, 0
            for i in range(opts.bank):
                run = f"{'bank' if mode == 'with a bank' else 'nobank'}{i}"  # a run of its own: never resumed
                before = len(SimulationBank(tmp / "bank"))
                total += timed(["fit", "--observed", f"rec{i}", "--out", run], cwd=tmp, env=envb)
                if mode == "with a bank":  # first-round simulations not added to the bank were read from it
                    n0 = int(RunStore.open(tmp / run / "run.zarr").round_data(0)["status"].size)
                    read += n0 - (len(SimulationBank(tmp / "bank")) - before)
            rows.append([f"{opts.bank} lift recordings fitted in a row, {mode}", round(total, 1),
                         read if mode == "with a bank" else 0])
            out[mode.replace(" ", "_")] = {"seconds": round(total, 1), "first_round_from_bank": read}
    tables.append(table("Fits of several recordings of one task (default budget; wall seconds)",
                        ["what", "s", "first-round simulations read from the bank"], rows))
    return out


def _tests(env: dict, tables: list) -> dict:
    """README command 2's tests and the unit tier, wall seconds."""
    out, rows = {}, []
    for what, marks in (("README command 2's tests", "not slow"), ("unit tier", "not slow and not integration")):
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, "-m", "pytest", "-m", marks, "-q", "-n", "2", "--dist", "loadscope",
                              "-p", "no:cacheprovider"],
                             cwd=REPO, env=env, capture_output=True, text=True)
        sec = time.perf_counter() - t0
        last = (res.stdout.strip().splitlines() or [""])[-1]
        rows.append([what, f"pytest -m \"{marks}\" -n 2 --dist loadscope", round(sec, 1), last])
        out[what] = {"seconds": round(sec, 1), "result": last}
    tables.append(table("The test tiers (wall seconds)", ["what", "command", "s", "result"], rows))
    return out


def _commit(path: Path) -> str:
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=path, capture_output=True, text=True).stdout.strip()
