"""The real-diagnosis suite: what `softsbi diagnose` finds missing on the DiffCloud recordings, with its defaults.

Each lift recording ``lift_<r>`` of ``--data``/diffcloud_lift and each fold ``fold_<r>`` (imported with
``--fold-scenario``) is fitted, checked and diagnosed by the CLI with its defaults (``softsbi fit``, ``check``,
``diagnose``, ``--workers``), each in a process of its own, in ``--out/<task>_<r>``; a step already stored there is
reused (resumable). The suite's own simulation bank (``--out/bank``) serves every recording of a task: the lifts
share one task (:func:`softsbi.scenarios.builtin.lift_task`), and the folds of one rig calibration share one;
``softsbi task train`` trains each task first with its defaults (the nominal model and every candidate; skipped with
``--no-train``, and a model already stored is not trained again), so every fit stops at its trained task and its
diagnosis scores each candidate through its amortised posterior before refitting.

Tables: per recording the check's p-value, the verdict, the effects named, the screening's top candidates with the
share of the residual each explains, the residual's shape (flagged frames, the centroid's offset, the worst
regions), the posterior-predictive Chamfer and the best fit; per task with two recordings or more, the diagnosis
across its recordings (``softsbi diagnose RUN RUN ... --out``: one verdict for the set, each candidate's summed
score, adequacy and switched-on count) with each recording's own verdict beside it; then the candidates' screening
shares across the recordings of each task; then the candidates of ``--weigh`` (by default the rig's hypotheses,
:data:`RIG_HYPOTHESES`) weighed on each task's set (``diagnose RUN RUN ... --candidate``), with each recording's
posterior-predictive Chamfer under the nominal model and under each of them (from their checks); with folds, each fold's posterior/prior and posterior-predictive Chamfer
beside the fold suite's stored run. The figure has one row per task.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.fabric_distances import material_unit_means, repeat_fabric_distances
from benchmarks.runner import REPO, RESULTS, in_out_folder, table

LIFTS = ["tan", "tan2", "navy", "navy2", "paper", "paper2", "polka", "polka2", "redblack", "redblack2"]
FULL = {"lifts": LIFTS, "folds": LIFTS}
#: screening candidates shown per recording
TOP = 3
#: the rig's hypotheses about what its recordings lack (the motion's real duration, a grasp that holds a patch,
#: anisotropic stretch, the rig's sensor), weighed on every task's set by default
RIG_HYPOTHESES = ["duration-scale", "grasp-patch", "aniso-stretch", "arm-mask", "camera-offset"]


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--out", type=Path, default=None, help="folder of the runs, one per recording, and their "
                                                           "simulation bank (resumable; default: a temporary one)")
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data")
    ap.add_argument("--lifts", nargs="*", default=["tan2"], choices=LIFTS, help="lift recordings")
    ap.add_argument("--folds", nargs="*", default=[], choices=LIFTS, help="fold recordings")
    ap.add_argument("--fold-scenario", type=Path, default=REPO / "examples" / "fold.yaml")
    ap.add_argument("--workers", type=int, default=2, help="simulation workers per command")
    ap.add_argument("--figure", type=Path, default=REPO / "docs" / "figures" / "real_diagnosis_residual.png",
                    help="where the figure of the residual across recordings is written")
    ap.add_argument("--weigh", nargs="*", default=RIG_HYPOTHESES,
                    help="candidates refitted on every recording of a task and weighed for the set, beside its "
                         "default diagnosis (none: skip)")
    ap.add_argument("--no-train", dest="train", action="store_false",
                    help="do not train the lift task first (every fit then runs its sequential rounds)")


def suite(a: argparse.Namespace) -> dict:
    return in_out_folder(measure, a)


def _softsbi(env: dict, *args: str) -> float:
    """Run one softsbi command (output discarded); its wall time in seconds."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "softsbi.cli", *args], check=True, stdout=subprocess.DEVNULL, env=env)
    return time.perf_counter() - t0


def diagnose_recording(observed: Path, run: Path, workers: int, env: dict) -> dict:
    """Fit, check and diagnose one recording with the CLI's defaults (each step skipped when stored in ``run``);
    the wall time of each step run now (s)."""
    wall = {}
    steps = [("fit", run / "report.json", ["fit", "--observed", str(observed), "--out", str(run)]),
             ("check", run / "check.json", ["check", str(run)]),
             ("diagnose", run / "diagnosis.json", ["diagnose", str(run)])]
    for name, done, args in steps:
        if not done.exists():
            wall[name] = _softsbi(env, *args, "--workers", str(workers))
    return wall


def measure(a: argparse.Namespace, out: Path) -> dict:
    from softsbi.core.results import CheckResult, Diagnosis, from_json

    env = {**os.environ, "SOFTSBI_SIM_BANK": str(out / "bank")}
    cases = [("lift", r, a.data / "diffcloud_lift" / f"lift_{r}") for r in a.lifts]
    if a.folds:
        folds = out / "recordings" / "fold"
        if not folds.exists():
            _softsbi(env, "import", "diffcloud", str(a.data / "diffcloud_fold"), str(folds), "--scenario",
                     str(a.fold_scenario))
        cases += [("fold", r, folds / f"fold_{r}") for r in a.folds]
    trained = None
    if a.train and cases:
        # the lifts are one task, trained from the first lift; a fold's task depends on its rig's calibration, so
        # every fold is trained from (a fold whose task an earlier fold trained reuses the stored models)
        train_from = [c[2] for c in cases if c[0] == "lift"][:1] + [c[2] for c in cases if c[0] == "fold"]
        trained = sum(_softsbi(env, "task", "train", "--observed", str(obs), "--workers", str(a.workers))
                      for obs in train_from)
    rows, shares, data, curves, reports, notes = [], {}, {}, {}, {}, []
    for task, r, observed in cases:
        run = out / f"{task}_{r}"
        wall = diagnose_recording(observed, run, a.workers, env)
        rep = json.loads((run / "report.json").read_text())
        reports.setdefault(task, {})[r] = rep
        check = from_json(CheckResult, json.loads((run / "check.json").read_text()))
        d = from_json(Diagnosis, json.loads((run / "diagnosis.json").read_text()))
        screened = sorted((c for c in d.ranking if c.explained is not None), key=lambda c: -c.explained)
        for c in screened:
            shares.setdefault(task, {}).setdefault(c.effect, {})[r] = c.explained
        res = d.residual
        curves[f"{task} {r}"] = (check.times_s, check.chamfer.mean, None if res is None else res.centroid_offset_cm,
                                 check.metric_frames)
        best = (rep.get("best_fit") or {}).get("chamfer_m")
        rows.append([f"{task} {r}", f"{d.test.omnibus.p_value:.3g}", d.verdict, ", ".join(d.decision.named) or "-",
                     ", ".join(f"{c.effect} {100 * c.explained:.0f}%" for c in screened[:TOP]) or "-",
                     "-" if res is None else " ".join(f"{s[0]}-{s[1]}" for s in res.frame_spans) or "-",
                     "-" if res is None else " ".join(f"{v:+.1f}" for v in res.centroid_offset_cm),
                     "-" if res is None else ", ".join(res.worst_regions) or "-",
                     round(100 * rep["chamfer_posterior_m"], 2), None if best is None else round(100 * best, 2)])
        data[f"{task}_{r}"] = {"verdict": d.verdict, "named": list(d.decision.named),
                               "p": d.test.omnibus.p_value, "check_misspecified": check.test.misspecified,
                               "explained": {c.effect: c.explained for c in screened},
                               "refits": [{"effects": list(f.effects), "adequate": f.adequate,
                                           "score": None if f.score is None else f.score.value} for f in d.refits],
                               "chamfer_posterior_m": rep["chamfer_posterior_m"], "best_fit_m": best,
                               "wall_s": wall}
    tables = [table("Per recording: the check's p-value, the diagnosis and the residual's shape (frames flagged, the "
                    "measured centroid's offset from the simulated one in cm as x y z, the worst regions); "
                    "posterior-predictive Chamfer and best fit [cm]",
                    ["recording", "check p", "verdict", "named", f"screening: top {TOP} (share of the residual)",
                     "frames flagged", "centroid offset", "worst regions", "posterior predictive", "best fit"], rows)]
    for task, by_effect in shares.items():
        recs = sorted({r for v in by_effect.values() for r in v}, key=lambda r: LIFTS.index(r))
        order = sorted(by_effect, key=lambda e: -sum(by_effect[e].values()))
        tables.append(table(f"{task}: share of the residual each candidate explains in the screening, per recording",
                            ["candidate", *recs],
                            [[e, *[None if r not in by_effect[e] else f"{100 * by_effect[e][r]:.0f}%" for r in recs]]
                             for e in order]))
    joint = {}
    for task in dict.fromkeys(c[0] for c in cases):  # one diagnosis across each task's recordings
        runs = [out / f"{t}_{r}" for t, r, _ in cases if t == task]
        if len(runs) >= 2:
            tables[1:1], joint[task], _ = joint_tables(task, runs, out / f"joint_{task}", a.workers, env)
        if len(runs) >= 3 and a.weigh:
            weighed, joint[f"{task} weighed"], j = joint_tables(task, runs, out / f"joint_{task}_weighed",
                                                                 a.workers, env, a.weigh)
            tables += weighed[:1] + weighed[2:]
            if task == "lift" and (note := duration_note(a.data / "diffcloud_lift" / f"lift_{a.lifts[0]}", j)):
                notes.append(note)
    for task, reps in reports.items():  # do repeats of a fabric agree better than different fabrics?
        names = [p["name"] for p in next(iter(reps.values()))["parameters"]]
        mat, u = material_unit_means(reps, names)
        same, diff = repeat_fabric_distances(u)
        if same and diff:
            notes.append(f"{task}: distance between posterior means ({', '.join(mat)}; unit-cube units): repeats of a "
                         f"fabric {np.mean(same):.3f} ({len(same)} pairs), different fabrics {np.mean(diff):.3f} "
                         f"({len(diff)} pairs).")
    if "fold" in reports:
        tables.append(fold_beside_fold_suite(reports["fold"]))
    reused = sum(not v["wall_s"] for v in data.values())
    if reused:
        notes.append(f"{reused} of {len(data)} recordings were read back from --out, where an earlier run of this "
                     f"command stored their fit, check and diagnosis (the run's wall time does not include them).")
    figures = []
    if curves:
        plot_residuals(curves, a.figure)
        if a.figure.resolve().is_relative_to(REPO / "docs"):
            figures.append({"path": str(a.figure.resolve().relative_to(REPO / "docs")),
                            "caption": "the residual across recordings: posterior-predictive Chamfer per frame, and "
                                       "the measured centroid's offset from the simulated one in the flagged frames"})
    notes[:0] = [f"Each task was trained by `softsbi task train` with its defaults (this run's commands took "
             f"{trained:.0f} s; a model stored by an earlier run of the same folder, or for an earlier recording of "
             f"the same task, is not trained again)."
             if trained is not None else "No task trained (--no-train): every fit ran its sequential rounds."]
    return {"tables": tables, "notes": notes, "figures": figures,
            "data": {"recordings": data, "train_s": trained, "joint": joint}}


def joint_tables(task: str, runs: list[Path], folder: Path, workers: int, env: dict,
                 candidates: list[str] | None = None) -> tuple[list[dict], dict, Any]:
    """The diagnosis across a task's recordings (``softsbi diagnose RUN RUN ... --out folder``, reused when stored
    there; ``candidates``: those weighed on the set, ``--candidate``, instead of the default ones): its candidates'
    table, each recording's own verdict beside it and, with ``candidates``, each recording's posterior-predictive
    Chamfer under the nominal model and under each candidate (:func:`chamfer_table`); and its data (verdict, named,
    the summary sentence, wall time, and with ``candidates`` the Chamfer medians); and the
    :class:`~softsbi.core.results.joint.JointDiagnosis` itself."""
    from softsbi.core.results.joint import JointDiagnosis
    from softsbi.core.results import from_json
    from softsbi.report.joint_text import JOINT_COLUMNS, RECORDING_COLUMNS, joint_rows, joint_summary, recording_rows
    from softsbi.workflows.criticism.joint import JOINT_FILE
    wall = None
    if not (folder / JOINT_FILE).exists():
        weigh = [arg for c in candidates or [] for arg in ("--candidate", c)]
        wall = _softsbi(env, "diagnose", *map(str, runs), "--out", str(folder), "--workers", str(workers), *weigh)
    j = from_json(JointDiagnosis, json.loads((folder / JOINT_FILE).read_text()))
    summary = joint_summary(j)
    what = (f"the candidates {', '.join(candidates)} weighed on its {len(runs)} recordings" if candidates else
            f"one diagnosis across its {len(runs)} recordings")
    tables = [table(f"{task}: {what}, candidates by summed score. {summary}", JOINT_COLUMNS, joint_rows(j)),
              table(f"{task}: each recording's own diagnosis beside the task's", RECORDING_COLUMNS, recording_rows(j))]
    data = {"verdict": j.decision.verdict, "named": list(j.decision.named), "summary": summary, "wall_s": wall}
    if candidates:
        chamfer, data["chamfer_median_cm"] = chamfer_table(task, j)
        tables.append(chamfer)
    return tables, data, j


#: the Kinova Gen3's top Cartesian speed (m/s, its specification sheet): the arm of DiffCloud's rig
ARM_TOP_SPEED = 0.5


def duration_note(lift: Path, j: Any) -> str:
    """What the duration scales weighed on the lifts (the joint diagnosis ``j``) make of the arm's speed: the
    lift's gripper path (its length over the scenario's duration, from ``lift``'s scenario) at each recording's
    estimated ``duration_scale`` is a mean speed, against :data:`ARM_TOP_SPEED`. Empty when duration-scale was not
    weighed."""
    from softsbi.inference.contraction import INFORMED_MAX_RATIO
    from softsbi.scenarios.builtin import lift_task
    c = next((c for c in j.candidates if c.effect == "duration-scale"), None)
    if c is None:
        return ""
    sc, _ = lift_task(lift)
    g = np.asarray(sc.gripper, float).reshape(len(sc.gripper), -1, 3)[:, 0]
    path = float(np.linalg.norm(np.diff(g, axis=0), axis=1).sum())
    s = [x for x in c.estimates("duration_scale") if x is not None]
    if not s:
        return ""
    speeds = [path / (x * sc.duration) for x in s]
    widths = [e.width_ratio for r in c.refits for e in r.estimates
              if e.name == "duration_scale" and e.width_ratio is not None]
    width = float(np.median(widths)) if widths else None
    informed = width is not None and width <= INFORMED_MAX_RATIO
    return (f"duration-scale against the rig: the lift's gripper path is {path:.2f} m over the scenario's "
            f"{sc.duration:.2f} s; the lifts' posterior mean scales {min(s):.2f}-{max(s):.2f} (median "
            f"{float(np.median(s)):.2f}) make the real lift's mean speed {min(speeds):.2f}-{max(speeds):.2f} m/s "
            f"(the arm, a Kinova Gen3, tops out at {ARM_TOP_SPEED:g} m/s)"
            + ("" if width is None else
               f"; its 90% interval is {width:.2f} of the prior's wide (median over the lifts)"
               + ("." if informed else ": the recordings do not inform it, and these speeds are the prior's.")))


def chamfer_table(task: str, j) -> tuple[dict, dict]:
    """Each recording's posterior-predictive Chamfer [cm] under the nominal model and under each candidate of ``j``
    (a :class:`~softsbi.core.results.joint.JointDiagnosis`; each from its check's rollouts), a star where the
    candidate's refit is adequate (its check does not reject at the set's alpha); then the medians over the recordings
    and each candidate's fall of the median from the nominal one. Returns the table and the medians by model."""
    nominal = [d.chamfer_m for d in j.recordings]
    cols = {"nominal": nominal, **{c.effect: [r.chamfer_m for r in c.refits] for c in j.candidates}}
    med = {k: float(np.median([100 * v for v in vals if v is not None])) if any(v is not None for v in vals)
           else None for k, vals in cols.items()}
    rows = []
    for i, run in enumerate(j.runs):
        cells = [None if nominal[i] is None else round(100 * nominal[i], 2)]
        for c in j.candidates:
            r = c.refits[i]
            cells.append("-" if r.chamfer_m is None else f"{100 * r.chamfer_m:.2f}{'*' if r.adequate else ''}")
        rows.append([Path(run).name, *cells])
    rows.append(["median", *[None if v is None else round(v, 2) for v in med.values()]])
    base = med["nominal"]
    rows.append(["fall of the median", "-", *[f"{100 * (1 - med[c.effect] / base):.0f}%"
                                               if base and med[c.effect] is not None else "-" for c in j.candidates]])
    return (table(f"{task}: posterior-predictive Chamfer [cm] per recording, under the nominal model and with each "
                  f"candidate added (*: its refit is adequate, check p >= {j.alpha:g})",
                  ["recording", "nominal", *[c.effect for c in j.candidates]], rows), med)


def fold_beside_fold_suite(reports: dict) -> dict:
    """The folds of this run (the CLI's defaults through the trained fold task) beside the fold suite's stored run
    (``benchmarks/results/fold.json``, its own command and commit): posterior/prior Chamfer, posterior-predictive
    Chamfer [cm] and best fit [cm] per recording."""
    stored = RESULTS / "fold.json"
    run = json.loads(stored.read_text())["runs"].get("default", {}) if stored.exists() else {}
    old = run.get("data", {})
    rows = []
    for r, rep in sorted(reports.items(), key=lambda kv: LIFTS.index(kv[0])):
        o = old.get(r, {})
        best = (rep.get("best_fit") or {}).get("chamfer_m")
        rows.append([r, round(rep["chamfer_posterior_m"] / rep["chamfer_prior_m"], 2),
                     None if "posterior_over_prior" not in o else round(o["posterior_over_prior"], 2),
                     round(100 * rep["chamfer_posterior_m"], 2),
                     None if "chamfer_posterior_m" not in o else round(100 * o["chamfer_posterior_m"], 2),
                     None if best is None else round(100 * best, 2),
                     None if o.get("best_fit_m") is None else round(100 * o["best_fit_m"], 2)])
    source = (f"the fold suite's stored run: commit {run.get('commit')}, `{run.get('command')}`" if run else
              "no stored fold suite run")
    return table("fold: this run beside the fold suite's stored run (posterior/prior Chamfer; posterior-predictive "
                 "Chamfer and best fit [cm])",
                 ["fold", "posterior/prior", "fold suite", "posterior predictive", "fold suite", "best fit",
                  "fold suite"], rows, note=f"Beside: {source}.")


def plot_residuals(curves: dict, path: Path) -> None:
    """One row per task (the first word of a curve's name: lift, fold). Left: each recording's posterior-predictive
    Chamfer per frame (cm, the check's mean over rollouts), solid on the frames the metric scores and dotted, greyed
    and cut at the axis' top on the others; right: the measured centroid's offset from the simulated one (cm, x y z)
    in the residual's flagged frames."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from softsbi.report.style import save_figure

    tasks: dict[str, dict] = {}
    for name, curve in curves.items():
        tasks.setdefault(name.split()[0], {})[name] = curve
    fig, axes = plt.subplots(len(tasks), 2, figsize=(11, 4.2 * len(tasks)), squeeze=False,
                             gridspec_kw={"width_ratios": [1.6, 1]})
    for (task, group), (ax, bx) in zip(tasks.items(), axes):
        _plot_task(task, group, ax, bx)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path)


def _plot_task(task: str, curves: dict, ax, bx) -> None:
    """:func:`plot_residuals`' two panels of one task."""
    names = list(curves)
    top, before, after = 0.0, [], []
    for name, (t, mean, _, scored) in curves.items():
        t, cm = np.asarray(t), 100 * np.asarray(mean)
        scored = np.asarray(scored if scored else range(len(t)), int)
        line, = ax.plot(t[scored], cm[scored], lw=1.4, label=name)
        ax.plot(t, cm, lw=0.7, ls=":", color=line.get_color())
        top = max(top, float(np.nanmax(cm[scored])))
        if scored[0] > 0:
            before.append(0.5 * (t[scored[0] - 1] + t[scored[0]]))
        if scored[-1] < len(t) - 1:
            after.append(0.5 * (t[scored[-1]] + t[scored[-1] + 1]))
    left, right = ax.get_xlim()
    if before:  # the frames before the metric's first (the same on every recording of a task)
        ax.axvspan(left, max(before), color="0.88", zorder=0)
        ax.text(0.5 * (left + max(before)), 1.65 * top, "frames the metric\ndoes not score", ha="center",
                va="top", fontsize=7, color="0.3")
    if after:  # and after its last
        ax.axvspan(min(after), right, color="0.88", zorder=0)
    ax.set_xlim(left, right)
    ax.set_ylim(0, 1.7 * top)  # headroom above the curves for the legend
    ax.set(xlabel="time [s]", ylabel="Chamfer [cm]", title=f"{task}: posterior-predictive Chamfer per frame")
    ax.legend(fontsize=7, ncol=3, loc="upper right")
    offsets = np.array([c[2] if c[2] is not None else (np.nan,) * 3 for c in curves.values()], float)
    y = np.arange(len(names))
    for k, (axis, colour) in enumerate(zip("xyz", ("tab:red", "tab:green", "tab:blue"))):
        bx.barh(y + (k - 1) * 0.27, offsets[:, k], height=0.27, color=colour, label=axis)
    for i in np.nonzero(np.isnan(offsets).all(axis=1))[0]:
        bx.text(0, i, " no frame flagged", va="center", fontsize=7)
    bx.set_yticks(y, names, fontsize=7)
    bx.invert_yaxis()
    bx.axvline(0, color="k", lw=0.8)
    bx.set(xlabel="measured - simulated centroid [cm]", title=f"{task}: centroid offset, flagged frames")
    bx.legend(fontsize=7)

