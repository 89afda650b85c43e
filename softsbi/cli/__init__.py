"""Command-line interface: ``softsbi plugins | simulate | fit | train-extractor | check | diagnose | compare |
compare-backends | demo``."""
from __future__ import annotations

import functools
from enum import Enum
import json
import sys
import time
from pathlib import Path
from typing import Any, Optional

import click
import numpy as np
import typer

from ..core.errors import SoftsbiError
from .output import Output, json_error

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="softsbi: Bayesian real-to-sim for deformable objects (BayesSim-RKHS).")

#: help texts shared by several commands (one option name and one text per quantity)
H_JSON = "print one JSON document on stdout (results, or the error) instead of tables"
H_WORKERS = "simulation worker processes (default: one per core)"
H_SEED = "random seed: fixes every parameter draw and every simulation"
H_N_EVAL = "rollouts at posterior samples (the posterior-predictive check's sample size)"
H_BACKEND = "simulator plugin: mujoco-flex or pybullet-fem built in (`softsbi plugins` lists the installed ones)"
H_ESTIMATOR = ("posterior estimator plugin: rkhs (the paper's), mdnn, mdrff, bayeszoom-rkhs, nn-bulk, gp-bulk, "
               "sbi-npe (`softsbi plugins` lists the installed ones)")
H_PROPOSAL = ("how later rounds draw parameters: corrected (BayesSim: from the posterior p/p~*q) or truncated "
              "(TSNPE: from the prior truncated to the posterior's 99.9% region; robust in many dimensions)")


class Proposal(str, Enum):
    """Choices of ``--proposal`` (listed by ``--help``)."""
    corrected = "corrected"
    truncated = "truncated"


class Match(str, Enum):
    """Choices of ``compare-backends --match``."""
    physical = "physical"
    unit = "unit"

#: demo's hidden parameter values (unit-cube positions; the user is not told them before the fit ends)
DEMO_TRUTH_UNIT = {"bend": 0.62, "stretch": 0.45, "friction": 0.35, "scale": 0.55, "mass": 0.5}
#: demo's hidden effect: a breeze the nominal model lacks
DEMO_HIDDEN_EFFECT = {"wind": {"wind_x": 0.0, "wind_y": 0.8}}
DEMO_ROUNDS = 3
DEMO_SIMS = 150


def _parse_kv(items: list[str] | None, what: str) -> dict[str, Any]:
    import re
    out: dict[str, Any] = {}
    for it in items or []:
        for part in re.split(r",(?![^\[]*\])", it):  # commas inside [..] belong to a list value
            if not part:
                continue
            if "=" not in part:
                raise SoftsbiError(f"{what} '{part}' must look like name=value (lists as name=[1,2])")
            k, v = part.split("=", 1)
            out[k.strip()] = _num(v.strip())
    return out


def _num(v: str) -> Any:
    if v.startswith("[") and v.endswith("]"):
        return [_num(x.strip()) for x in v[1:-1].split(",") if x.strip()]
    for cast in (int, float):
        try:
            return cast(v)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(v.lower(), v)


def _parse_bounds(items: list[str] | None) -> dict[str, tuple[float, float]]:
    out = {}
    for it in items or []:
        for part in it.split(","):
            try:
                k, rng = part.split("=", 1)
                lo, hi = rng.split(":")
                out[k.strip()] = (float(lo), float(hi))
            except ValueError:
                raise SoftsbiError(f"--bounds '{part}' must look like name=low:high (e.g. friction=0.1:1.5)") from None
    return out


class ProgressHooks:
    """Progress of :func:`softsbi.core.loop.run_fit` on stderr: bars on a terminal, one line per
    round otherwise."""

    def __init__(self, o: Output, progress: Any):
        self.o, self.p = o, progress
        self.sim_task = None
        self.train_task = None

    def round_start(self, r: int, rounds: int, n_pending: int, n_total: int) -> None:
        label = f"round {r + 1}/{rounds} simulations" if r >= 0 else "posterior rollouts"
        if self.sim_task is not None:
            self.p.remove_task(self.sim_task)
        self.sim_task = self.p.add_task(label, total=n_total, completed=n_total - n_pending)
        if not self.o.err.is_terminal:
            self.o.message(f"{label}: {n_pending} of {n_total} to simulate")

    def simulation_done(self, r: int, done: int, total: int) -> None:
        self.p.update(self.sim_task, completed=done)

    def training_epoch(self, r: int, epoch: int, max_epochs: int, loss: float) -> None:
        if self.train_task is None:
            self.train_task = self.p.add_task(f"round {r + 1} training", total=max_epochs)
        self.p.update(self.train_task, completed=epoch, description=f"round {r + 1} training (loss {loss:.3f})")

    def round_end(self, r: int, s: dict[str, Any]) -> None:
        if self.train_task is not None:
            self.p.remove_task(self.train_task)
            self.train_task = None
        ch = s.get("chamfer_proposal") or {}
        ch_txt = f", Chamfer of this round's rollouts {ch['mean_m'] * 100:.2f} cm" if ch.get("mean_m") else ""
        mean = ", ".join(f"{k}={v:.3g}" for k, v in s["posterior_mean"].items())
        self.o.message(f"round {r + 1}: {s['usable']} usable, {s['failed']} failed{ch_txt}; posterior mean {mean}")

    def message(self, text: str) -> None:
        self.o.message(text, style="yellow")


def _run(o: Output, meas, cfg, out: Path):
    from ..core.loop import run_fit
    with o.progress() as p:
        return run_fit(out, meas, cfg, hooks=ProgressHooks(o, p))


def _pct_change(before: float, after: float) -> str:
    """``"37% lower"`` or ``"12% higher"``: never a negative 'lower'."""
    ch = after / before - 1
    return f"{abs(ch) * 100:.0f}% {'lower' if ch <= 0 else 'higher'}"


def _print_report(o: Output, rep: dict[str, Any], out: Path) -> None:
    truth = rep.get("truth") or {}
    cols = ["parameter", "unit", "mean", "std", "90% interval"] + (["hidden value", "inside 90%?"] if truth else [])
    rows = []
    for p in rep["parameters"]:
        n = p["name"]
        row = [n, p["unit"], f"{rep['posterior_mean'][n]:.4g}", f"{rep['posterior_std'][n]:.3g}",
               f"[{rep['posterior_q05'][n]:.4g}, {rep['posterior_q95'][n]:.4g}]"]
        if truth:
            ok = rep["truth_in_90pct_interval"].get(n)
            row += [f"{truth[n]:.4g}" if n in truth else "-", "-" if ok is None else ("yes" if ok else "NO")]
        rows.append(row)
    o.table(cols, rows, title="Posterior (physical units)")
    if rep.get("mask_chamfer_prior_px") and rep.get("mask_chamfer_posterior_px"):
        o.line(f"Mask Chamfer to the measured frames: prior {rep['mask_chamfer_prior_px']:.2f} px -> posterior "
               f"{rep['mask_chamfer_posterior_px']:.2f} px "
               f"({_pct_change(rep['mask_chamfer_prior_px'], rep['mask_chamfer_posterior_px'])})")
    if rep.get("chamfer_prior_m") and rep.get("chamfer_posterior_m"):
        o.line(f"Chamfer to the measurement: prior {rep['chamfer_prior_m'] * 100:.2f} cm -> posterior "
               f"predictive {rep['chamfer_posterior_m'] * 100:.2f} cm "
               f"({_pct_change(rep['chamfer_prior_m'], rep['chamfer_posterior_m'])})")
    o.line(f"{rep['simulations']} simulations ({rep['failed_simulations']} failed), {rep['wall_time_s']:.0f} s. "
           f"Outputs in {out}: report.json, run.zarr, chamfer_rounds.png, posterior_pairs.png, clouds.png")


def _guard(fn):
    """Run a command: a SoftsbiError prints one line (or a JSON error under ``--json``) and exits 2;
    Ctrl-C says how to resume; under ``--json`` any other error is a JSON error with exit 1."""

    @functools.wraps(fn)
    def wrapper(*a, **kw):
        as_json = bool(kw.get("as_json"))
        try:
            return fn(*a, **kw)
        except (typer.Exit, typer.Abort, click.exceptions.Exit):
            raise
        except SoftsbiError as exc:
            if as_json:
                sys.stdout.write(json_error(exc) + "\n")
            else:
                Output().error(str(exc))
            raise typer.Exit(2)
        except KeyboardInterrupt:
            exc = KeyboardInterrupt("interrupted; finished simulations are kept: re-run the same command to resume")
            if as_json:
                sys.stdout.write(json_error(exc) + "\n")
            else:
                Output().error(str(exc))
            raise typer.Exit(130)
        except Exception as exc:
            if as_json:
                sys.stdout.write(json_error(exc) + "\n")
                raise typer.Exit(1)
            raise
    return wrapper


@app.command()
@_guard
def plugins(as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """List installed simulators, effects, observers, estimators and executors."""
    from ..plugins import registry
    from ..plugins.manager import LOAD_ERRORS
    desc = registry().describe()
    if LOAD_ERRORS:
        desc["load_errors"] = dict(LOAD_ERRORS)
    o = Output(as_json)
    if as_json:
        o.emit_json(desc)
        return
    for kind, rows in desc.items():
        if kind == "load_errors":
            continue
        o.table(["name", "package", "description"],
                [[r["name"], r["package"], (r.get("doc") or "") +
                  (f" scenarios: {', '.join(r['scenarios'])}" if r.get("scenarios") else "")] for r in rows],
                title=kind)
    for name, err in LOAD_ERRORS.items():
        o.line(f"plugin '{name}' failed to load: {err}")


@app.command()
@_guard
def simulate(backend: str = typer.Option("mujoco-flex", help=H_BACKEND),
             scenario: str = typer.Option("lift", help="scenario name: lift, wipe, wind or fling"),
             recording: Optional[Path] = typer.Option(None, help="real recording folder to take the scenario from"),
             theta: list[str] = typer.Option(None, "--theta", help="name=value (repeatable); unset = prior midpoint"),
             effect: list[str] = typer.Option(None, "--effect", help="effect names to switch on"),
             backend_opt: list[str] = typer.Option(None, "--backend-opt", help="backend option name=value"),
             out: Path = typer.Option(Path("rollout"), help="output folder (rollout.zarr + preview.png)"),
             render: Optional[int] = typer.Option(None, help="also render every frame through the scenario's "
                                                             "overhead camera at this square size (px): "
                                                             "OUT/frames/000.png ... + truth.json, a measurement "
                                                             "for `fit --observer heatmap|transporter`"),
             as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Roll a scenario out at given parameters; write Zarr and a PNG preview (and rendered frames)."""
    import zarr
    from ..backends.scenarios import make_scenario
    from ..plugins import registry

    o = Output(as_json)
    try:
        sc = make_scenario(scenario, recording)
    except ValueError as exc:
        raise SoftsbiError(str(exc)) from None
    sim = registry().simulator(backend)(**_parse_kv(backend_opt, "--backend-opt"))
    effects = [e for it in effect or [] for e in it.split(",") if e]
    space = sim.param_space(sc)
    for e in effects:
        space = space + registry().effect(e)().param_space()
    values = space.midpoint()
    values.update(_parse_kv(theta, "--theta"))
    values = space.check(values)
    t0 = time.perf_counter()
    if render:
        from ..core.camera import default_camera
        ro = sim.simulate_images(sc, values, camera=default_camera(sc.name, render), effects=effects)
    else:
        ro = sim.simulate(sc, values, effects=effects)
    dt = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)
    g = zarr.open_group(str(out / "rollout.zarr"), mode="w")
    g.attrs.update({"backend": backend, "scenario": sc.to_json(), "theta": values, "status": int(ro.status),
                    "reason": ro.reason})
    for name, arr, units in (("times", ro.times, "s"), ("gripper", ro.gripper, "m"), ("vertices", ro.vertices, "m"),
                             ("faces", ro.faces, "1")):
        a = g.create_array(name, shape=arr.shape, dtype=arr.dtype, attributes={"units": units})
        a[...] = arr
    doc: dict[str, Any] = {"backend": backend, "scenario": scenario, "theta": values, "status": int(ro.status),
                           "reason": ro.reason, "frames": len(ro.times), "vertices": int(ro.vertices.shape[1]),
                           "wall_s": dt, "rollout": str(out / "rollout.zarr")}
    o.line(f"{backend} {scenario}: status {'ok' if ro.ok else ro.reason}, {len(ro.times)} frames, "
           f"{ro.vertices.shape[1]} vertices, {dt:.2f} s wall -> {out / 'rollout.zarr'}")
    if ro.ok:
        _preview(ro, out / "preview.png", f"{backend} {scenario}")
        doc["preview"] = str(out / "preview.png")
        o.line(f"preview: {out / 'preview.png'}")
    if ro.ok and render:
        from ..perception.images import save_frames
        save_frames(ro.rgb, out / "frames")
        (out / "frames" / "truth.json").write_text(json.dumps(values, indent=2))
        doc["frames_dir"] = str(out / "frames")
        o.line(f"{len(ro.rgb)} rendered frames ({render}x{render} px): {out / 'frames'} (truth.json holds "
               f"the parameters; `softsbi fit --observed {out / 'frames'} --scenario {scenario} "
               f"--observer heatmap --extractor ...` fits them)")
    if as_json:
        o.emit_json(doc)


def _preview(ro, path: Path, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    T = len(ro.times)
    frames = sorted({0, T // 3, 2 * T // 3, T - 1})
    fig, axes = plt.subplots(1, len(frames), figsize=(3 * len(frames), 3.2), squeeze=False)
    for ax, f in zip(axes[0], frames):
        v = ro.vertices[f]
        ax.scatter(v[:, 1], v[:, 2], s=4)
        ax.plot(ro.gripper[f, 1], ro.gripper[f, 2], "r+", ms=10)
        ax.set_title(f"t = {ro.times[f]:.2f} s (side view)", fontsize=9)
        ax.set_xlabel("y [m]")
        ax.set_ylabel("z [m]")
        ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


#: ``--frames auto``: frames in which the gripper is at least this high above the table (m); in
#: the DiffCloud recordings the cloud is complete only once the cloth hangs clear (frame 10 on)
LIFTED_HEIGHT = 0.10


def _parse_frames(spec: str | None, scenario=None) -> list[int] | None:
    if not spec or spec == "all":
        return None
    if spec == "auto":
        if scenario is None:
            return None
        h = scenario.gripper[:, 2] - scenario.table_z
        lifted = [int(i) for i in np.nonzero(h >= LIFTED_HEIGHT)[0]]
        return lifted or None
    out: list[int] = []
    try:
        for part in spec.split(","):
            if ":" in part:
                a, b = part.split(":")
                out.extend(range(int(a), int(b)))
            else:
                out.append(int(part))
    except ValueError:
        raise SoftsbiError(f"--frames '{spec}' must be indices or ranges like 10:25 or 0,5,10") from None
    return out


def _fit_config(backend, estimator, rounds, sims_per_round, seed, points, workers, effect, bounds, fix,
                backend_opt, estimator_opt, n_eval, min_height=None, frames=None, executor="local",
                executor_options=None, proposal="corrected"):
    from ..core.loop import FitConfig
    effects = [e for it in effect or [] for e in it.split(",") if e]
    return FitConfig(backend=backend, backend_options=_parse_kv(backend_opt, "--backend-opt"), effects=effects,
                     estimator=estimator, estimator_options=_parse_kv(estimator_opt, "--estimator-opt"),
                     rounds=rounds, sims_per_round=sims_per_round, seed=seed, n_points=points, workers=workers,
                     bounds=_parse_bounds(bounds), fixed=_parse_kv(fix, "--fix"), n_eval=n_eval,
                     min_height=min_height, frames=_parse_frames(frames), executor=executor,
                     executor_options=dict(executor_options or {}), proposal=Proposal(proposal).value)


DEFAULT_ROUNDS = 4
#: real depth clouds contain no cloth lying flat on the table (checked on all 10 DiffCloud recordings).
#: With the placement yaw inferred, fitting every frame without this sensor model lowers lift_tan's total
#: Chamfer further (3.35 vs 3.65 cm) but only by covering the early fragments with a rotated cloth that
#: then hangs crossed to the real one (frames 15-24: 4.77 vs 3.11 cm); BENCHMARKS.md
DEFAULT_MIN_HEIGHT = 0.01
DEFAULT_SIMS = 150


@app.command()
@_guard
def fit(observed: Path = typer.Option(..., help="recording folder (000.npy ... + lift_real2sim.yaml), or with an "
                                                 "image observer a folder of frames 000.png ..."),
        out: Path = typer.Option(..., help="run directory (resumes if it holds a run)"),
        backend: str = typer.Option("mujoco-flex", help=H_BACKEND),
        estimator: str = typer.Option("rkhs", help=H_ESTIMATOR),
        rounds: int = typer.Option(DEFAULT_ROUNDS, help="sequential rounds (paper: 15)"),
        sims_per_round: int = typer.Option(DEFAULT_SIMS, help="simulations per round (paper: 100)"),
        seed: int = typer.Option(0, help=H_SEED),
        points: int = typer.Option(64, help="K, points per frame"),
        workers: Optional[int] = typer.Option(None, help=H_WORKERS),
        effect: list[str] = typer.Option(None, "--effect", help="effects to add (their parameters are inferred)"),
        bounds: list[str] = typer.Option(None, "--bounds", help="prior bounds name=low:high"),
        fix: list[str] = typer.Option(None, "--fix", help="hold a parameter: name=value"),
        backend_opt: list[str] = typer.Option(None, "--backend-opt", help="backend option name=value"),
        estimator_opt: list[str] = typer.Option(None, "--estimator-opt", help="estimator option name=value"),
        n_eval: int = typer.Option(30, "--n-eval", help=H_N_EVAL + "; their mean Chamfer is the reported one"),
        min_height: Optional[float] = typer.Option(
            DEFAULT_MIN_HEIGHT, help="sensor model: points closer than this (m) to the table are not seen, in "
                                     "simulation and recording alike (real depth clouds lack cloth lying flat)"),
        frames: str = typer.Option("auto", help="frames that inform the posterior: 'auto' (the cloth hangs clear: "
                                                "gripper >= 10 cm above the table), 'all', or e.g. 10:25; the "
                                                "Chamfer metric always uses every frame"),
        executor: str = typer.Option("local", help="where simulations run: local (process pool) or ray "
                                                   "(executor plugins; `softsbi plugins` lists them)"),
        ray_address: Optional[str] = typer.Option(None, help="with --executor ray: address of an existing Ray "
                                                             "cluster (head host:port or auto); default: start Ray "
                                                             "on this machine"),
        sim_timeout: Optional[float] = typer.Option(None, help="seconds after which a hung simulation's worker is "
                                                               "killed and the simulation retried (default: none)"),
        retries: int = typer.Option(2, help="re-runs of a simulation whose worker crashed or hung, before it is "
                                            "stored as failed"),
        observer: str = typer.Option("pointcloud", help="observer plugin: pointcloud (3-D clouds), or heatmap / "
                                                        "transporter (keypoints found in RGB frames by a trained "
                                                        "extractor)"),
        extractor: Optional[Path] = typer.Option(None, help="with --observer heatmap|transporter: the trained "
                                                            "extractor checkpoint (softsbi train-extractor)"),
        scenario: str = typer.Option("lift", help="scenario the frames were recorded in: lift, wipe, wind or "
                                                  "fling (image observers; point clouds are always lift)"),
        image_size: int = typer.Option(128, help="image observers: square size (px) of the scenario's built-in "
                                                 "camera; frames are resized to it"),
        proposal: Proposal = typer.Option(Proposal.corrected, help=H_PROPOSAL),
        as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Infer the posterior over physical parameters from a recording (resumable)."""
    from ..perception.measurement import load_image_measurement, load_measurement
    from ..plugins import registry
    exe_opts: dict[str, Any] = {"retries": retries}
    if sim_timeout is not None:
        exe_opts["timeout"] = sim_timeout
    if ray_address:
        if executor != "ray":
            raise SoftsbiError(f"--ray-address needs --executor ray (got --executor {executor})")
        exe_opts["address"] = ray_address
    cfg = _fit_config(backend, estimator, rounds, sims_per_round, seed, points, workers, effect, bounds, fix,
                      backend_opt, estimator_opt, n_eval, min_height, frames, executor, exe_opts, proposal)
    cfg.observer = observer
    images = bool(getattr(registry().observer(observer), "needs_images", False))
    if images:
        if extractor is None:
            raise SoftsbiError(f"--observer {observer} needs --extractor PATH.pt (train one with `softsbi "
                               f"train-extractor {observer} --out PATH.pt`)")
        cfg.observer_options = {"extractor": str(extractor), "size": image_size}
        cfg.min_height = None  # a depth-sensor model; frames show the whole cloth
    elif extractor is not None:
        raise SoftsbiError(f"--extractor is for image observers (heatmap, transporter), not '{observer}'")
    cfg.validate()  # fail fast (e.g. --workers 0) before loading the recording
    if executor == "ray":
        from ..executors.ray_executor import _import_ray
        _import_ray()  # DependencyMissing naming `pip install softsbi[ray]`
    if images:
        meas = load_image_measurement(observed, scenario=scenario, size=image_size)
        if frames == "auto":
            cfg.frames = None
    else:
        if scenario != "lift":
            raise SoftsbiError(f"point-cloud recordings are lift recordings; --scenario {scenario} needs an image "
                               f"observer (--observer heatmap|transporter) and a folder of frames")
        meas = load_measurement(observed, n_points=points, seed=seed)
    if frames == "auto" and not images:
        cfg.frames = _parse_frames("auto", meas.scenario)
    o = Output(as_json)
    res = _run(o, meas, cfg, out)
    if as_json:
        o.emit_json(dict(res.report, run_dir=str(out)))
    else:
        _print_report(o, res.report, out)


@app.command()
@_guard
def demo(out: Path = typer.Option(Path("softsbi-demo"), help="output folder"),
         quick: bool = typer.Option(False, "--quick", help="only fit hidden parameters (no hidden effect)"),
         rounds: int = typer.Option(DEMO_ROUNDS, help="sequential rounds per fit"),
         sims_per_round: int = typer.Option(DEMO_SIMS, help="simulations per round"),
         estimator: str = typer.Option("rkhs", help=H_ESTIMATOR),
         seed: int = typer.Option(0, help=H_SEED),
         workers: Optional[int] = typer.Option(None, help=H_WORKERS),
         proposal: Proposal = typer.Option(Proposal.truncated, help=H_PROPOSAL + "; truncated keeps the "
                                                                                 "7-parameter refit's posterior tight"),
         as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """The whole real-to-sim story on a built-in case that needs no data files.

    A lift measurement is simulated at parameters you are not shown, with a hidden breeze the
    nominal model lacks. softsbi fits the nominal model, checks it against the measurement,
    diagnoses the missing effect among all installed ones, refits with it and compares.
    "Before" and "after" are the posterior-predictive Chamfer of the two fits: the mean over
    rollouts at their posterior samples (report.json's chamfer_posterior_m; compare shows the same).
    """
    from ..backends.scenarios import lift_scenario
    from ..core.diagnostics import check_run, compare_runs, diagnose_run, format_p
    from ..core.loop import FitConfig
    from ..perception.measurement import simulate_measurement
    from ..plugins import registry

    o = Output(as_json)
    proposal = Proposal(proposal).value
    t0 = time.perf_counter()
    sc = lift_scenario(None)
    sim = registry().simulator("mujoco-flex")()
    space = sim.param_space(sc)
    u = np.array([DEMO_TRUTH_UNIT.get(n, 0.5) for n in space.names])
    truth = space.as_dict(space.from_unit(u))
    hidden_effects = [] if quick else list(DEMO_HIDDEN_EFFECT)
    truth_all = dict(truth, **({} if quick else DEMO_HIDDEN_EFFECT["wind"]))
    o.rule("softsbi demo")
    o.line(f"A cloth lift simulated at hidden parameters{'' if quick else ' with a hidden effect'}: "
           f"{rounds} rounds x {sims_per_round} simulations per fit, estimator {estimator}, {proposal} proposals.")
    meas = simulate_measurement("mujoco-flex", sc, truth_all, effects=hidden_effects)
    cfg = FitConfig(estimator=estimator, rounds=rounds, sims_per_round=sims_per_round, seed=seed, workers=workers,
                    proposal=proposal)
    nominal = out / "nominal"
    o.rule("1. fit the nominal model")
    res = _run(o, meas, cfg, nominal)
    _print_report(o, res.report, nominal)
    doc: dict[str, Any] = {"out": str(out), "quick": quick, "nominal": res.report}
    if quick:
        inside = res.report["truth_in_90pct_interval"]
        doc.update(inside_90=sum(inside.values()), parameters=len(inside), wall_s=time.perf_counter() - t0)
        o.line(f"{sum(inside.values())}/{len(inside)} hidden values inside the 90% posterior interval "
               f"({time.perf_counter() - t0:.0f} s).")
        if as_json:
            o.emit_json(doc)
        return
    o.rule("2. check: where does the model miss the measurement?")
    with o.status("posterior predictive check ..."):
        chk = check_run(nominal, workers=workers)
    o.line(chk["summary"])
    o.rule("3. diagnose: which installed effect explains the residual?")
    with o.status("screening candidate effects ..."):
        diag = diagnose_run(nominal, confirm=0, workers=workers)
    o.table(["rank", "effect", "explains", "p-value"],
            [[i + 1, r["effect"], f"{r['explained_fraction'] * 100:.0f}%", format_p(r)]
             for i, r in enumerate(diag["ranking"]) if "statistic" in r])
    o.line(diag["summary"])
    doc.update(check=chk, diagnosis=diag)
    if not diag["significant"]:
        o.line("no effect to add; stopping here")
        if as_json:
            o.emit_json(doc)
        return
    eff = diag["selected"]
    o.rule(f"4. add the effect: refit with --effect {eff}")
    cfg2 = FitConfig(estimator=estimator, rounds=rounds, sims_per_round=sims_per_round, seed=seed, workers=workers,
                     effects=[eff], proposal=proposal)
    refit = out / f"with-{eff}"
    res2 = _run(o, meas, cfg2, refit)
    _print_report(o, res2.report, refit)
    o.rule("5. compare: error before and after")
    with o.status("checking both runs ..."):
        comp = compare_runs(nominal, refit, out, workers=workers)
    o.table(["", "nominal", f"+ {eff}", "change"],
            [[row["what"], f"{row['a'] * 100:.2f} cm", f"{row['b'] * 100:.2f} cm", f"{row['change'] * 100:+.0f}%"]
             for row in comp["table"][:4]])
    inside = res2.report["truth_in_90pct_interval"]
    hidden_ok = eff in DEMO_HIDDEN_EFFECT
    before, after = comp["table"][0]["a"], comp["table"][0]["b"]
    o.rule("the numbers")
    o.line(f"hidden effect: {', '.join(DEMO_HIDDEN_EFFECT)}; diagnosis named: {eff} "
           f"({'correct' if hidden_ok else 'WRONG'}).")
    o.line(f"posterior-predictive Chamfer: {before * 100:.2f} cm (nominal) -> {after * 100:.2f} cm (with {eff}), "
           f"{_pct_change(before, after)}.")
    o.line(f"{sum(inside.values())}/{len(inside)} hidden values inside the refit's 90% posterior interval. "
           f"Total {time.perf_counter() - t0:.0f} s. Figures: {out}/compare.png, {nominal}/check.png, "
           f"{refit}/posterior_pairs.png")
    if as_json:
        doc.update(refit=res2.report, compare={k: v for k, v in comp.items() if k not in ("check_a", "check_b")},
                   named=eff, named_correctly=hidden_ok, chamfer_before_m=before, chamfer_after_m=after,
                   inside_90=sum(inside.values()), parameters=len(inside), wall_s=time.perf_counter() - t0)
        o.emit_json(doc)


@app.command()
@_guard
def check(run: Path = typer.Argument(..., help="run directory of a finished fit"),
          n_eval: int = typer.Option(30, "--n-eval", help=H_N_EVAL),
          workers: Optional[int] = typer.Option(None, help=H_WORKERS),
          as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Posterior predictive check: where and when the fitted model misses the measurement."""
    from ..core.diagnostics import check_run
    o = Output(as_json)
    with o.status("simulating at posterior samples ..."):
        out = check_run(run, n_samples=n_eval, workers=workers)
    if as_json:
        o.emit_json(out)
        return
    o.table(["phase", "time [s]", "gripper height [cm]", "Chamfer [cm]", "worst region"],
            [[ph["phase"], f"{ph['t_s'][0]:.2f}-{ph['t_s'][1]:.2f}",
              f"{ph['gripper_height_m'][0] * 100:.1f}-{ph['gripper_height_m'][1] * 100:.1f}",
              f"{ph['chamfer_m'] * 100:.2f}", ph["worst_region"]] for ph in out["phases"]],
            title="Error by phase of the motion")
    m = out["misspecification"]
    o.line(f"misspecification test: statistic {m['statistic']:.2f} (null mean {m['null_mean']:.2f}), "
           f"p = {m['p_value_gamma']:.3g} (empirical {m['p_value']:.3g}, {m['n_simulations']} rollouts)")
    o.line(out["summary"])
    o.line(f"wrote {run / 'check.json'} and {run / 'check.png'}")


@app.command()
@_guard
def diagnose(run: Path = typer.Argument(..., help="run directory of a finished fit (nominal model)"),
             effect: list[str] = typer.Option(None, "--effect", help="candidate effects (default: all installed)"),
             confirm: int = typer.Option(2, help="refit the top N significant candidates and keep the one whose "
                                                 "refit lowers the error most (0 = no refit)"),
             confirm_rounds: Optional[int] = typer.Option(None, help="rounds of a confirmation refit "
                                                                     "(default: the run's)"),
             confirm_sims: Optional[int] = typer.Option(None, help="simulations per round of a confirmation refit "
                                                                   "(default: the run's)"),
             workers: Optional[int] = typer.Option(None, help=H_WORKERS),
             as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Rank installed effects by how much of the residual each explains; confirm the best by refitting."""
    from ..core.diagnostics import confirm_candidates, diagnose_run, format_p
    o = Output(as_json)
    names = [e for it in effect or [] for e in it.split(",") if e] or None
    budget = {k: v for k, v in (("rounds", confirm_rounds), ("sims_per_round", confirm_sims)) if v}
    with o.status("screening candidate effects ..."):
        out = diagnose_run(run, effects=names, confirm=0, workers=workers)
    if confirm and out["significant"]:
        confirm_candidates(run, out, confirm, budget or None, workers,
                           progress=lambda name: o.message(f"confirming {name} with a refit ..."))
        (run / "diagnosis.json").write_text(json.dumps(out, indent=2))
    if as_json:
        o.emit_json(out)
        return
    by_name = {r["effect"]: r for r in out["ranking"]}
    drops = {c["effect"]: c.get("drop") for c in out["confirmed"]}
    rows = []
    for i, name in enumerate(out.get("final_ranking") or list(by_name)):
        r = by_name[name]
        if "statistic" not in r:
            rows.append([i + 1, r["effect"], "-", "-", r.get("error", ""), "", ""])
            continue
        est = ", ".join(f"{k}={v:.3g}" for k, v in r["estimate"].items())
        d = drops.get(name)
        rows.append([i + 1, r["effect"], f"{r['explained_fraction'] * 100:.0f}%", format_p(r), est,
                     "yes" if r["effect"] in out["significant"] else "no", "" if d is None else f"{d * 100:.0f}%"])
    o.table(["rank", "effect", "explains", "p-value", "estimate", "significant", "refit: error drop"], rows,
            title="Candidate effects, ranked (refitted ones by their error drop, then by evidence)")
    o.line(out["summary"])
    o.line(f"wrote {run / 'diagnosis.json'}")


@app.command()
@_guard
def compare(run_a: Path = typer.Argument(..., help="first run (e.g. nominal model)"),
            run_b: Path = typer.Argument(..., help="second run (e.g. with the effect added)"),
            out: Optional[Path] = typer.Option(None, help="output folder (default: RUN_B)"),
            n_eval: int = typer.Option(30, "--n-eval", help=H_N_EVAL + ", per run"),
            workers: Optional[int] = typer.Option(None, help=H_WORKERS),
            as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Two runs side by side: error per time step and region, before vs after."""
    from ..core.diagnostics import compare_runs
    o = Output(as_json)
    with o.status("checking both runs ..."):
        res = compare_runs(run_a, run_b, out or run_b, n_samples=n_eval, workers=workers)
    if as_json:
        o.emit_json(res)
        return
    o.table(["", str(run_a), str(run_b), "change"],
            [[row["what"], f"{row['a'] * 100:.2f} cm", f"{row['b'] * 100:.2f} cm", f"{row['change'] * 100:+.0f}%"]
             for row in res["table"]], title="Posterior-predictive error")
    o.line(res["summary"])
    o.line(f"wrote {res['png']} and {res['json']}")


@app.command()
@_guard
def view(run: Path = typer.Argument(..., help="run directory of a finished point-cloud fit"),
         n_eval: int = typer.Option(5, "--n-eval", help="posterior-predictive rollouts drawn (faded) against the "
                                                          "measurement"),
         gif: bool = typer.Option(True, help="write RUN/view.gif: measured vs simulated clouds over time"),
         rrd: bool = typer.Option(True, help="write RUN/view.rrd for the rerun viewer (`rerun RUN/view.rrd`); "
                                             "needs `pip install \"softsbi[view]\"`"),
         workers: Optional[int] = typer.Option(None, help=H_WORKERS),
         as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """See the measured cloud move against posterior rollouts: an animation and a rerun recording."""
    from ..viewer import write_view
    o = Output(as_json)
    with o.status(f"simulating {n_eval} posterior rollouts ..."):
        res = write_view(run, n_samples=n_eval, workers=workers, gif=gif, rrd=rrd)
    if as_json:
        o.emit_json(res)
        return
    for key in ("gif", "rrd"):
        if res.get(key):
            o.line(f"wrote {res[key]}" + ("  (open with `rerun " + str(res[key]) + "`)" if key == "rrd" else ""))


@app.command("train-extractor")
@_guard
def train_extractor(kind: str = typer.Argument(..., help="extractor plugin: heatmap (supervised) or transporter "
                                                         "(unsupervised)"),
                    out: Path = typer.Option(..., help="checkpoint to write (.pt)"),
                    data: Optional[Path] = typer.Option(None, help="annotated folder (images/NNNNN.jpg|png + "
                                                                   "keypoints/NNNNN.npy), e.g. "
                                                                   "../shared/data/wiping_keypoints"),
                    simulate: Optional[str] = typer.Option(None, help="instead of --data: render this scenario at "
                                                                      "prior samples (labels = projected cloth "
                                                                      "corners; robot masks from the segmentation)"),
                    backend: str = typer.Option("mujoco-flex", help="with --simulate: simulator plugin"),
                    rollouts: int = typer.Option(40, help="with --simulate: rendered rollouts"),
                    image_size: int = typer.Option(128, help="with --simulate: square camera size (px)"),
                    mask_robot: bool = typer.Option(True, help="transporter: leave the robot out of the "
                                                               "reconstruction loss"),
                    opt: list[str] = typer.Option(None, "--opt", help="extractor option name=value (repeatable)"),
                    seed: int = typer.Option(0, help=H_SEED),
                    as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Train a keypoint extractor on annotated images or on rendered rollouts; report its test error."""
    from ..perception.synthdata import render_training_set, visible_corner_labels
    from ..plugins import registry

    o = Output(as_json)
    cls = registry().extractor(kind)
    if (data is None) == (simulate is None):
        raise SoftsbiError("give exactly one of --data FOLDER (annotated images) or --simulate SCENARIO (rendered)")
    ext = cls(**_parse_kv(opt, "--opt"))
    supervised = bool(getattr(cls, "supervised", True))
    summary: dict[str, Any] = {"extractor": kind}
    if data is not None:
        from ..perception.keypoint_data import block_split, keypoint_errors, load_keypoint_folder
        images, kps, names = load_keypoint_folder(data)
        split = block_split(len(images))
        tr, va, te = split["train"], split["val"], split["test"]
        o.line(f"{len(images)} annotated images from {data}: contiguous blocks, {len(tr)} train / {len(va)} "
                      f"val / {len(te)} test")
        with o.progress() as p:
            task = p.add_task(f"training {kind}", total=None)
            cb = lambda e, m, l: p.update(task, total=m, completed=e, description=f"training {kind} (loss {l:.4g})")  # noqa: E731
            if supervised:
                info = ext.fit(images[tr], kps[tr], seed=seed, progress=cb, val_images=images[va],
                               val_keypoints=kps[va])
            else:
                info = ext.fit(images[np.r_[tr, va]], seed=seed, progress=cb)
        summary["test"] = keypoint_errors(ext.predict(images[te]), kps[te])
        o.line(f"test ({len(te)} frames): mean {summary['test']['mean_px']:.2f} px, PCK@10px "
                      f"{summary['test']['pck@10px'] * 100:.0f}% (set-matched: mean "
                      f"{summary['test']['hungarian_mean_px']:.2f} px)")
    else:
        with o.progress() as p:
            task = p.add_task(f"rendering {simulate} on {backend}", total=rollouts)
            d = render_training_set(backend, simulate, n_rollouts=rollouts, size=image_size, seed=seed,
                                    progress=lambda i, n: p.update(task, completed=i))
            task2 = p.add_task(f"training {kind}", total=None)
            cb = lambda e, m, l: p.update(task2, total=m, completed=e, description=f"training {kind} (loss {l:.4g})")  # noqa: E731
            H, W = d["images"].shape[1:3]
            if supervised:
                info = ext.fit(d["images"], visible_corner_labels(d["corners"], W, H), seed=seed, progress=cb)
            else:
                info = ext.fit(d["images"], None, d["robot_masks"] if mask_robot else None, seed=seed, progress=cb,
                               sequence_ids=d["sequence_ids"])
        summary["frames"] = int(len(d["images"]))
    summary["train"] = {k: v for k, v in info.items() if k != "history"}
    out.parent.mkdir(parents=True, exist_ok=True)
    ext.save(out)
    out.with_suffix(".json").write_text(json.dumps(summary, indent=2, default=float))
    o.line(f"trained {kind}: {info.get('epochs')} epochs, {info.get('seconds', 0):.0f} s -> {out} "
           f"(summary {out.with_suffix('.json')})")
    if as_json:
        o.emit_json(dict(summary, checkpoint=str(out)))


@app.command("compare-backends")
@_guard
def compare_backends_cmd(scenario: str = typer.Option("lift", help="scenario name: lift, wipe, wind or fling"),
                         theta: list[str] = typer.Option(None, "--theta",
                                                         help="name=value (repeatable); unset = each backend's midpoint"),
                         backends: str = typer.Option("mujoco-flex,pybullet-fem", help="comma-separated simulators"),
                         backend_opt: list[str] = typer.Option(None, "--backend-opt",
                                                               help="backend:option=value, e.g. pybullet-fem:grid=7"),
                         match: Match = typer.Option(Match.physical, help="match the engines by 'physical' "
                                                                          "parameter values or by 'unit' prior "
                                                                          "positions in [0, 1]"),
                         out: Path = typer.Option(Path("compare"), help="output folder (compare.json + compare.png)"),
                         as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Roll the same scenario and parameters out on two engines; per-frame Chamfer between them."""
    from ..backends.compare import compare_backends
    from ..backends.scenarios import make_scenario

    try:
        sc = make_scenario(scenario)
    except ValueError as exc:
        raise SoftsbiError(str(exc)) from None
    names = [b for b in backends.split(",") if b]
    opts: dict[str, dict[str, Any]] = {}
    for it in backend_opt or []:
        if ":" not in it:
            raise SoftsbiError(f"--backend-opt '{it}' must look like backend:name=value")
        b, kv = it.split(":", 1)
        opts.setdefault(b, {}).update(_parse_kv([kv], "--backend-opt"))
    try:
        rep = compare_backends(sc, _parse_kv(theta, "--theta"), names, out, backend_options=opts,
                               match=Match(match).value)
    except ValueError as exc:
        raise SoftsbiError(str(exc)) from None
    o = Output(as_json)
    if as_json:
        o.emit_json(rep)
        return
    for b, r in rep["backends"].items():
        o.line(f"{b}: status {r['status']}{' (' + r['reason'] + ')' if r['reason'] else ''}, "
                      f"{r['n_vertices']} vertices, {r['wall_s']:.2f} s; theta "
                      + ", ".join(f"{k}={v:.4g}" for k, v in r["theta"].items()))
    for key, m in rep["mean_chamfer_m"].items():
        o.line(f"mean Chamfer {key}: " + (f"{m * 100:.2f} cm" if m is not None else "n/a (a rollout failed)"))
    o.line(f"wrote {out / 'compare.json'} and {out / 'compare.png'}")


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()
