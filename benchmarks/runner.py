"""The benchmark runner: the declared suites, their results JSON and the page rendered from them.

A suite is a module of this package with three names:

* ``add_arguments(parser)``: its options (``argparse``), whose defaults are the suite's default (small)
  configuration;
* ``FULL``: the option values of ``--full`` (the configuration the project's reported numbers use), or None when
  the suite has only one configuration;
* ``suite(options) -> dict``: runs it and returns ``{"tables": [...], "notes": [...], "data": {...},
  "figures": [...]}`` (every key optional; a table is :func:`table`'s dict, a figure ``{"path", "caption"}`` with
  ``path`` relative to ``docs/``).

and optionally ``config(options) -> str``: the name its run is stored under, for a suite whose runs differ by more
than ``--full`` (newton-throughput: ``default-cuda`` for a GPU run); ``default`` / ``full`` otherwise.

``python -m benchmarks run SUITE [--full] [options]`` runs one and stores the run in ``benchmarks/results/SUITE.json``
under its configuration (``default`` or ``full``; a run of the other configuration is kept), with the commit, the
machine kind (cores, CPU model, OS: never a path) and the exact command; then it renders ``docs/benchmarks.md`` from
every stored results file (:func:`render`), so the suite's section is written from scratch. Runs recorded before
this runner existed carry ``"source": "recorded"`` and the commit, machine and command their measurement used.
"""
from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import shlex
import subprocess
import time
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from types import ModuleType
from typing import Any, Sequence

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
DOC = REPO / "docs" / "benchmarks.md"
#: the page's groups, in order
GROUPS = ("Engines", "Executors", "Estimators and calibration", "Images", "Real recordings", "Diagnosis", "Speed")
#: the configurations a run stores, in the order the page shows them (other keys follow, sorted)
CONFIGS = ("default", "full")


@dataclass(frozen=True)
class Suite:
    """A declared suite: its ``name`` (``python -m benchmarks run NAME``), the page's ``group``, a ``title`` and a
    ``summary`` (what it measures, one paragraph), and its ``module`` (a module name of this package, or a module
    object with the three names of this module's docstring)."""

    name: str
    group: str
    title: str
    summary: str
    module: str | ModuleType

    def load(self) -> ModuleType:
        """The suite's module."""
        return importlib.import_module(self.module) if isinstance(self.module, str) else self.module


_SUITES = [
    Suite("backends", "Engines", "speed, overhead, throughput and memory of the two backends",
          "Wall time per simulated second of every built-in scenario on mujoco-flex and pybullet-massspring "
          "(prior midpoint, median of the repeats), softsbi's rollout against a raw engine loop of the same scene "
          "(lift), rollouts per second with one and two LocalExecutor workers, and the resident memory over many "
          "consecutive rollouts of one simulator instance.", "benchmarks.bench_backends"),
    Suite("backend-units", "Engines", "one physical meaning per cloth parameter: a clamped strip's droop",
          "A square cloth (0.2 m, 9x9 grid) clamped along half its rows droops under its own weight (gravity "
          "pointing up, so the table never touches it) on both engines at the same bending rigidity D; the tip "
          "deflection against the Euler-Bernoulli value w a^4 / (8 D) for overhang a. pybullet-massspring's "
          "bending-spring factor was calibrated on one rigidity (D = 3e-4 N m, g = 9.81) against mujoco-flex.",
          "benchmarks.bench_backend_units"),
    Suite("newton-throughput", "Engines", "lift rollouts per second: newton-cloth one by one and batched",
          "Lift rollouts per second for N = 1, 8 (64 with --full) parameter sets from the prior: mujoco-flex and "
          "newton-cloth one by one, and newton-cloth as one batch of N worlds in one Newton model; --device cuda "
          "runs newton-cloth on a GPU (stored as its own configuration). Needs the optional Newton package.",
          "benchmarks.bench_newton_throughput"),
    Suite("newton-demo", "Diagnosis", "the demo's hidden wind found on newton-cloth",
          "softsbi demo --backend B on newton-cloth and on mujoco-flex in the same run: a lift simulated on B with a "
          "hidden wind, fitted, checked, diagnosed and refitted on B. The verdict, the named effect, the error "
          "before and after, and the fit's simulations per second. Needs the optional Newton package.",
          "benchmarks.bench_newton_demo"),
    Suite("identifiability", "Engines", "how far each parameter moves the object, per backend and scenario",
          "Mean vertex displacement over all frames and vertices between a rollout at a parameter's low and at its "
          "high prior bound, the others at the prior midpoint: a parameter that barely moves the object in a "
          "scenario is hard to infer from it. Units differ between engines where a parameter has no shared meaning "
          "(the mujoco-flex rope's young is Young's modulus; the pybullet-massspring rope's own spring knobs are not "
          "shown).",
          "benchmarks.identifiability"),
    Suite("mujoco-lift", "Engines", "one mujoco-flex lift rollout against the grid size",
          "Wall seconds of one rollout of the built-in lift (1 s simulated, 25 frames: XML build, compile and "
          "simulate) at the prior midpoint, single thread; stiff corners of the prior take up to about 1.5x.",
          "benchmarks.bench_mujoco_lift"),
    Suite("render", "Engines", "rendering cost per frame",
          "Milliseconds per rendered frame (colour, depth and segmentation, robot included; the once-per-rollout "
          "set-up apart) of each backend on the wipe scenario (grid 9, 31 frames), and the wall time of a rendered "
          "rollout over a plain one.", "benchmarks.bench_render"),
    Suite("executors", "Executors", "simulations per second of the executors",
          "Prior draws of the real lift_tan scenario on mujoco-flex (each job also computes its Chamfer to the "
          "recording, as in a fit), workers warmed up first: softsbi's LocalExecutor with 1 and 2 processes, a bare "
          "multiprocessing.Pool(2) running the same job, and the RayExecutor on a local Ray.",
          "benchmarks.bench_executors"),
    Suite("estimators-gauss", "Estimators and calibration", "estimators against an analytic posterior",
          "On the linear-Gaussian toy simulator (toy-gauss, analytic posterior): the C2ST between each estimator's "
          "posterior after every round of a sequential fit and the analytic posterior (0.5: indistinguishable), and "
          "the expected coverage of the amortised posterior at 50 % and 90 % on held-out prior simulations.",
          "benchmarks.bench_estimators_gauss"),
    Suite("estimators-sim", "Estimators and calibration", "the paper's six-method comparison in simulation",
          "A cloth lift (or the rope winding) simulated by mujoco-flex at hidden parameters and seen as noisy "
          "unordered points; each estimator fits it round by round (the paper's corrected proposals) and "
          "rollouts at posterior samples are compared with the truth's dense clouds (Chamfer, mean over frames).",
          "benchmarks.bench_estimators_sim"),
    Suite("estimators-speed", "Estimators and calibration", "training time of one round",
          "One round at 1500 lift-shaped synthetic simulations (25 frames of 33 points), every estimator with its "
          "default options and one torch thread: wall and CPU seconds of the fit (after an untimed warm-up fit), "
          "epochs, and the held-out negative log-likelihood (nats, unit-cube coordinates).",
          "benchmarks.bench_estimators_speed"),
    Suite("calibration", "Estimators and calibration", "expected coverage of the posterior estimators",
          "One round of prior simulations of a simulated measurement (mujoco-flex lift grid 6 or the rope winding, "
          "32 noisy points per frame), then simulation-based calibration: fresh test simulations from the run's "
          "proposal, each estimator variant retrained on the run's own simulations; expected HPD coverage at 50 % "
          "and 90 % (a calibrated estimator gives 0.50 / 0.90), TARP and the verdict of `softsbi calibrate`.",
          "benchmarks.bench_calibration"),
    Suite("posterior-calibration", "Estimators and calibration", "every trained model of the lift task on its "
          "held-out simulations",
          "The demo's lift task trained by `softsbi task train` for the nominal model and each candidate effect "
          "(`--full`: every shipped candidate, 1000 prior and 200 held-out simulations each); per model, its training "
          "report against three criteria: TARP's KS p >= 0.01, HPD coverage at 50% and 90% inside the binomial band "
          "of a calibrated estimator, and every marginal's SBC KS p above 0.05 / D (Bonferroni).",
          "benchmarks.bench_posterior_calibration"),
    Suite("sbibm", "Estimators and calibration", "C2ST on SBI-benchmark tasks",
          "softsbi's flow and flat-vector mixture density network, and sbi's own NPE, trained on the same "
          "simulations of sbibm's simulators, one round; the C2ST of their posteriors against sbibm's reference "
          "posteriors at the same observations (sbibm's recipe, 2000 vs 2000 samples, lower is better, 0.5 = "
          "indistinguishable). The reference files come from benchmarks/sbibm_export.py, run in a separate "
          "environment with sbibm.", "benchmarks.sbibm_c2st"),
    Suite("heatmap", "Images", "the supervised heatmap keypoint extractor on the real wiping images",
          "Trained on the wiping keypoint set (real and simulated cloth images, 4 corners) with a block split by "
          "source image (no test image or augmented copy of it is seen in training); keypoint error at 320 px on "
          "the held-out frames, set-matched (Hungarian), and prediction speed on CPU.", "benchmarks.bench_heatmap"),
    Suite("transporter", "Images", "unsupervised Transporter keypoints, robot masked out of the loss or not",
          "Transporter keypoints (Kulkarni et al. 2019) trained on rendered wipe rollouts with and without the "
          "robot's pixels masked out of the reconstruction loss (same data, seed and budget): the fraction of "
          "held-out keypoints on the cloth and on the robot, training time and inference speed.",
          "benchmarks.bench_transporter"),
    Suite("real-lift", "Real recordings", "the DiffCloud lift recordings with the defaults of `softsbi fit`",
          "Each recording fitted by `softsbi fit` with its defaults (mujoco-flex grid 9, rkhs, 4 rounds x 150 "
          "truncated + 30 posterior rollouts, 64 points per frame, the recording's sensor model); Chamfer of prior "
          "and posterior-predictive rollouts on the headline metric (the fit's sensor view and frames), posterior "
          "mean and standard deviation, how much each parameter's 90 % interval contracted, and the distance "
          "between repeats of a fabric against different fabrics.", "benchmarks.real_lift_all"),
    Suite("real-diagnosis", "Real recordings", "what `softsbi diagnose` finds missing on the DiffCloud recordings",
          "Each lift and fold recording fitted, checked and diagnosed by the CLI with its defaults (the lifts share "
          "one task and the suite's simulation bank); per recording the check's p-value, the verdict, the effects "
          "named, the screening's top candidates with the share of the residual each explains, the residual's "
          "shape, the posterior-predictive Chamfer and the best fit; and each candidate's share across the "
          "recordings of a task.", "benchmarks.real_diagnosis"),
    Suite("fold", "Real recordings", "the DiffCloud fold recordings through the generic path",
          "Each fold recording imported with examples/fold.yaml (no fold-specific code) and fitted by `softsbi fit` "
          "with its defaults: Chamfer of prior and posterior-predictive rollouts on the headline metric, posterior "
          "mean and standard deviation, and repeats of a fabric against different fabrics.",
          "benchmarks.fold_table"),
    Suite("cmaes", "Real recordings", "CMA-ES against softsbi at equal simulation budget",
          "CMA-ES (the cma library) minimises the fit's headline metric over the fit's own unit-cube parameter "
          "space through the fit's own simulation job, with the budget of a default fit (4 x 150 + 30 = 630); "
          "beside it softsbi's posterior-mean rollout and posterior predictive on the same metric and, with "
          "--refine, the best fit `softsbi fit --refine` finds.", "benchmarks.cmaes_baseline"),
    Suite("diagnosis", "Diagnosis", "how often `softsbi diagnose` is right on cases it was not chosen on",
          "The demo's lift task trained once with every shipped candidate; lift recordings at prior draws: "
          "controls, one shipped effect hidden at a magnitude in the upper two thirds of its on range, or data from "
          "the other engine; each is fitted, checked and diagnosed with the CLI's defaults, each step timed, and "
          "12 of them also on the sequential path (no trained task). The test split's cases are run once under the "
          "frozen rule; rows are stored per case (benchmarks/results/diagnosis-SPLIT.jsonl), so a run resumes.",
          "benchmarks.diagnosis"),
    Suite("calibrated-check", "Diagnosis", "is check's p-value uniform on controls, and its power, calibrated or not",
          "The demo's lift task trained once; controls (the nominal model at prior draws) and recordings with one of "
          "three hidden effects at four magnitudes, each fitted by conditioning the stored estimator and checked as "
          "`check` checks a fit of a trained task: its omnibus and directional statistics combined by min-P and "
          "calibrated against the task's replicate recordings, refitted, checked and screened the same way (Hjort, "
          "Dahl & Steinbakk 2006); beside it the uncalibrated omnibus p-value and a candidate refit's check (the "
          "omnibus test alone against 19 replicates).", "benchmarks.bench_calibrated_check"),
    Suite("diagnosis-motions", "Diagnosis", "the loop a user follows: the lift, then the motions design asks for",
          "Cases drawn as the diagnosis suite's on a seed stream of their own (40 controls, 4 per shipped effect, 8 "
          "from the other engine): each lift fitted on its trained task, checked and diagnosed; while the diagnosis "
          "leaves candidates undecided, `softsbi design` advises a motion, the same hidden truth is simulated on it, "
          "fitted on its trained task and the recordings diagnosed as one rig (at most 3 motions). Scored strictly "
          "after the lift and after the last motion; rows stored per case "
          "(benchmarks/results/diagnosis-motions.jsonl), so a run resumes.", "benchmarks.diagnosis_motions"),
    Suite("motions", "Diagnosis", "which shipped effects each motion informs, trained and estimated",
          "Each built-in motion's task (the demo's lift, the wipe and the fling on mujoco-flex) trained by `softsbi "
          "task train` with every shipped candidate; per effect and motion, the trained model's median 90% interval "
          "width over the prior's on its held-out simulations (informed at the report's criterion), and beside it "
          "`softsbi design`'s linear estimate at a fit of the demo's lift, which reads no wipe or fling task: a "
          "prediction their trained reports judge.", "benchmarks.bench_motions"),
    Suite("tasks", "Speed", "a task trained once against every recording fitted from scratch",
          "The demo's task (lift, mujoco-flex, the nominal model) trained once by `softsbi task train`, with its "
          "training report on held-out prior simulations; then new recordings of the task (the demo's, with its "
          "hidden breeze, and recordings at random hidden parameters) fitted by today's default from scratch "
          "(4 x 150, no bank), by the stored task alone (1 round) and by the stored task plus one round of 150: "
          "wall seconds and posterior-predictive Chamfer of each, in the same run.", "benchmarks.bench_tasks"),
    Suite("speed", "Speed", "what a user waits for",
          "Wall seconds of the command-line tool: startup (`softsbi --help`, `softsbi plugins`), one fit of the toy "
          "simulator and a `check` of it, each in a fresh process; with --full also the demo (against an older "
          "checkout's with --old), check, diagnose and compare on the demo's nominal run against its fit time, fits "
          "of several recordings of one task with and without a simulation bank, and the test tiers.",
          "benchmarks.speed"),
]
SUITES: dict[str, Suite] = {s.name: s for s in _SUITES}


def table(title: str, columns: Sequence[str], rows: Sequence[Sequence[Any]], note: str | None = None) -> dict:
    """A table of a suite's result: ``rows`` of cells (numbers, text, None for a missing value)."""
    return {"title": title, "columns": list(columns), "rows": [list(r) for r in rows],
            **({"note": note} if note else {})}


# ---------------------------------------------------------------- provenance


def _git(*args: str) -> str | None:
    try:
        res = subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    return res.stdout.strip() if res.returncode == 0 else None


def commit() -> dict[str, Any]:
    """The checkout's commit (``git rev-parse``) and whether files other than the results and the page differ from it
    or are not committed yet (``dirty``: git ignored files aside); ``"unknown"`` outside a git checkout."""
    head = _git("rev-parse", "--short=10", "HEAD")
    if head is None:
        return {"commit": "unknown", "dirty": None}
    status = _git("status", "--porcelain", "--", ".", ":(exclude)benchmarks/results",
                  ":(exclude)docs/benchmarks.md")
    return {"commit": head, "dirty": bool(status)}


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine() -> dict[str, Any]:
    """The machine kind: cores, CPU model, OS, Python, the 1-minute load average at the start and the versions of
    the libraries that move timings (never a path or a host name)."""
    versions = {}
    for dist in ("softsbi", "torch", "mujoco", "pybullet", "numpy"):
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return {"cores": os.cpu_count(), "cpu": _cpu_model(), "os": f"{platform.system()} {platform.release()}",
            "python": platform.python_version(), "load": round(os.getloadavg()[0], 1), "versions": versions}


def portable(value: Any) -> Any:
    """``value`` with every path made relative to the repository (``../shared/...`` for the shared data beside it),
    and any other path outside it shown as ``OUTSIDE/NAME``: options and commands name no machine's folders; nested
    lists and dicts too."""
    if isinstance(value, dict):
        return {k: portable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [portable(v) for v in value]
    if isinstance(value, Path) or (isinstance(value, str) and os.path.isabs(value)):
        rel = os.path.relpath(os.path.abspath(value), REPO)  # symbolic links kept: ../shared may be one
        inside = not rel.startswith("..") or rel.startswith(os.path.join("..", "shared", ""))
        return rel if inside else f"OUTSIDE/{Path(value).name}"
    return value


def command(argv: Sequence[str]) -> str:
    """The exact command of a run, ``python -m benchmarks ARGV`` (absolute paths made relative, :func:`portable`)."""
    return "python -m benchmarks " + shlex.join(str(portable(a)) for a in argv)


# ---------------------------------------------------------------- running


def parser(suite: Suite, module: ModuleType) -> argparse.ArgumentParser:
    """The suite's options (``--full`` where it has a full configuration)."""
    ap = argparse.ArgumentParser(prog=f"python -m benchmarks run {suite.name}", description=suite.summary)
    if getattr(module, "FULL", None) is not None:
        ap.add_argument("--full", action="store_true",
                        help="the full configuration: " + ", ".join(f"{k}={v}" for k, v in module.FULL.items()))
    module.add_arguments(ap)
    return ap


def options(suite: Suite, module: ModuleType, argv: Sequence[str]) -> argparse.Namespace:
    """The run's options: the defaults, ``FULL``'s values with ``--full``, then the options given."""
    ap = parser(suite, module)
    opts = ap.parse_args(list(argv))
    if getattr(opts, "full", False):
        ap.set_defaults(**module.FULL)
        opts = ap.parse_args(list(argv))
    return opts


def run(name: str, argv: Sequence[str] = (), results: Path = RESULTS, doc: Path | None = DOC) -> dict:
    """Run suite ``name`` with the options ``argv``, store the run in ``results/NAME.json`` under its configuration
    and render ``doc`` (None: do not render). Returns the stored run."""
    if name not in SUITES:
        raise SystemExit(f"unknown suite {name!r}; the suites: {', '.join(SUITES)}")
    suite = SUITES[name]
    module = suite.load()
    opts = options(suite, module, argv)
    config = "full" if getattr(opts, "full", False) else "default"
    if hasattr(module, "config"):  # a suite whose runs differ by more than --full (the device) names its own
        config = module.config(opts)
    prov = {**commit(), "machine": machine(), "command": command(["run", name, *argv])}
    stored = portable({k: v for k, v in vars(opts).items() if k != "full"})
    opts.command = prov["command"]  # for a suite whose rows carry their own provenance
    t0 = time.perf_counter()
    out = module.suite(opts) or {}
    record = {"config": config, "source": "measured", **prov, "options": stored,
              "seconds": round(time.perf_counter() - t0, 1), "tables": out.get("tables", []),
              "notes": out.get("notes", []), "figures": out.get("figures", []), "data": out.get("data", {})}
    store(results, name, config, record)
    if doc is not None:
        render(results, doc)
    return record


def store(results: Path, name: str, config: str, record: dict) -> Path:
    """Write ``record`` as run ``config`` of ``results/NAME.json``, keeping the file's other runs."""
    path = results / f"{name}.json"
    data = json.loads(path.read_text()) if path.exists() else {"suite": name, "runs": {}}
    data["runs"][config] = record
    data["runs"] = {k: data["runs"][k] for k in _ordered(data["runs"])}
    results.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, ensure_ascii=False) + "\n")
    return path


def _ordered(runs: dict) -> list[str]:
    return [c for c in CONFIGS if c in runs] + sorted(k for k in runs if k not in CONFIGS)


# ---------------------------------------------------------------- rendering


HEADER = """# softsbi benchmarks

This page is generated: `python -m benchmarks render` writes it from the results in `benchmarks/results/*.json`, and
`python -m benchmarks run SUITE [--full]` measures a suite again and rewrites its section (`python -m benchmarks
list` lists the suites). Every run states the commit it measured, the machine kind and the exact command. A run
marked *recorded* was measured before this runner existed; its command is the one its measurement used. Timings on
a shared machine are upper bounds: the load at the start is given.
"""


def _cell(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v).replace("|", "\\|").replace("\n", " ")


def _machine_text(m: dict | str) -> str:
    if isinstance(m, str):
        return m
    parts = [f"{m['cores']} cores" if m.get("cores") else None, m.get("cpu"), m.get("os"),
             f"Python {m['python']}" if m.get("python") else None]
    vers = m.get("versions") or {}
    if vers:
        parts.append(", ".join(f"{k} {v}" for k, v in vers.items()))
    if m.get("load") is not None:
        parts.append(f"load {m['load']} at the start")
    if m.get("note"):
        parts.append(m["note"])
    return "; ".join(p for p in parts if p)


def render_run(key: str, run: dict) -> list[str]:
    """One run as Markdown lines: its provenance line, tables, notes and figures."""
    recorded = run.get("source") == "recorded"
    dirty = " (with uncommitted changes)" if run.get("dirty") else ""
    took = f", {run['seconds']:.0f} s" if run.get("seconds") is not None else ""
    lines = [f"**{key.capitalize()} configuration{', recorded' if recorded else ''}.** Commit "
             f"`{run['commit']}`{dirty}; machine: {_machine_text(run['machine'])}; command: "
             f"`{run['command']}`{took}.", ""]
    for t in run.get("tables", []):
        lines += [f"*{t['title']}*", "", "| " + " | ".join(_cell(c) for c in t["columns"]) + " |",
                  "|" + "---|" * len(t["columns"])]
        lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in t["rows"]]
        lines.append("")
        if t.get("note"):
            lines += [t["note"], ""]
    for n in run.get("notes", []):
        lines += [n, ""]
    for f in run.get("figures", []):
        lines += [f"![{f['caption']}]({f['path']})", ""]
    return lines


def render_text(results: Path = RESULTS) -> str:
    """The page, from the declared suites and their stored results (deterministic: the same files give the same
    text)."""
    lines = [HEADER]
    for group in GROUPS:
        suites = [s for s in SUITES.values() if s.group == group]
        if not suites:
            continue
        lines += [f"## {group}", ""]
        for s in suites:
            lines += [f"### {s.name}: {s.title}", "", s.summary, ""]
            path = results / f"{s.name}.json"
            runs = json.loads(path.read_text())["runs"] if path.exists() else {}
            if not runs:
                lines += [f"Not measured yet: `python -m benchmarks run {s.name}`.", ""]
            for key in _ordered(runs):
                lines += render_run(key, runs[key])
    return "\n".join(lines).rstrip("\n") + "\n"


def render(results: Path = RESULTS, doc: Path = DOC) -> Path:
    """Write :func:`render_text` to ``doc``."""
    doc.parent.mkdir(parents=True, exist_ok=True)
    doc.write_text(render_text(results))
    return doc


def in_out_folder(measure: Any, args: argparse.Namespace) -> dict:
    """``measure(args, folder)`` in ``args.out``, or in a temporary folder removed afterwards when ``args.out`` is
    None (the suites whose runs are kept only when asked)."""
    import tempfile
    if args.out is None:
        with tempfile.TemporaryDirectory() as tmp:
            return measure(args, Path(tmp))
    return measure(args, args.out)
