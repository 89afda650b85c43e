"""Command-line interface: ``softsbi plugins | params | simulate | fit | train-extractor | check | diagnose | compare |
compare-backends | demo``."""
from __future__ import annotations

import functools
from enum import Enum
import sys
import warnings
from pathlib import Path
from typing import Any, Optional

import typer

from softsbi.core.errors import SoftsbiError
from softsbi.core.levels import ALPHA
from softsbi.cli.output import Output, json_error
from softsbi.workflows import defaults as D

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="softsbi: Bayesian real-to-sim for deformable objects (BayesSim-RKHS).")

#: help texts shared by several commands (one option name and one text per quantity)
H_JSON = "print one JSON document on stdout (results, or the error) instead of tables"
H_WORKERS = "simulation worker processes (default: one per core)"
H_SEED = "random seed: fixes every parameter draw and every simulation"
H_N_EVAL = "rollouts at posterior samples (the posterior-predictive check's sample size)"
H_MAX_NULL = ("cap of the adaptive null: when 1/(n+1) > alpha and the first n posterior-predictive rollouts give "
              "p <= 0.1, simulate up to this many before deciding (p is never printed below 1/(cap+1))")
H_RECOMPUTE = "compute again even when the run holds this command's result for the same fit and settings"
H_ALPHA = "family-wise significance level of the verdicts (the tolerated false-alarm rate)"
H_BACKEND = "simulator plugin: mujoco-flex or pybullet-massspring built in (`softsbi plugins` lists the installed ones)"
H_ESTIMATOR = ("posterior estimator plugin: rkhs (the paper's), mdnn, flow, mdrff, bayeszoom-rkhs, nn-bulk, gp-bulk, "
               "sbi-npe (`softsbi plugins` lists the installed ones)")
H_PROPOSAL = ("how later rounds draw parameters: truncated (TSNPE: from the prior truncated to the posterior's "
              "99.9% region; robust in many dimensions) or corrected (the paper's BayesSim: from the posterior "
              "p/p~*q)")


class Proposal(str, Enum):
    """Choices of ``--proposal`` (listed by ``--help``)."""
    corrected = "corrected"
    truncated = "truncated"


class Match(str, Enum):
    """Choices of ``compare-backends --match``."""
    physical = "physical"
    unit = "unit"



def _bound(low: float, why: str = "", strict: bool = False, below: float | None = None):
    """A typer option callback that refuses, when the flags are parsed (before any work), a value under ``low`` (at
    or under it when ``strict``; at or above ``below`` when given): "Invalid value for '--n-draws': must be >= 10
    (got 1): why", exit code 2. ``None`` (an unset optional flag) passes."""

    def check(ctx: typer.Context, param: typer.CallbackParam, value: float | None) -> float | None:
        if value is not None and (value < low or (strict and value <= low) or (below is not None and value >= below)):
            bound = (f"> {low:g}" if strict else f">= {low:g}") + ("" if below is None else f" and < {below:g}")
            raise typer.BadParameter(f"must be {bound} (got {value:g})" + (f": {why}" if why else ""), ctx=ctx,
                                     param=param)
        return value
    return check


#: the option callbacks shared by several commands
AT_LEAST_1_WORKER = _bound(1, "one simulation process at least; leave it out for one per core")
SEED_OK = _bound(0, "seeds are non-negative integers")
ALPHA_OK = _bound(0, "a probability", strict=True, below=1)
N_NULL_OK = _bound(D.MIN_ROLLOUTS, "the null's first stage and the check's error maps need that many posterior "
                                   "rollouts")
ROUNDS_OK = _bound(1, "one round at least")
SIMS_OK = _bound(D.MIN_SIMS_PER_ROUND, "the estimator needs data")


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


def _run(o: Output, meas, cfg, out: Path, retry_failed: bool = False):
    from softsbi.cli.progress import ProgressHooks
    from softsbi.workflows.fit import run_fit
    with o.progress() as p:
        return run_fit(out, meas, cfg, callbacks=ProgressHooks(o, p), retry_failed=retry_failed)


def _print_report(o: Output, rep: dict[str, Any], out: Path) -> None:
    from softsbi.core.metrics import describe_change
    from softsbi.inference.contraction import (INFORMED_MAX_RATIO, bound_sentence, contraction_from_report,
                                               format_estimate)
    truth = rep.get("truth") or {}
    con = contraction_from_report(rep)
    cols = (["parameter", "unit", "estimate", "90% interval", "width / prior"]
            + (["hidden value", "inside 90%?"] if truth else []))
    rows = []
    for p in rep["parameters"]:
        n = p["name"]
        c = con[n]
        row = [n, p["unit"], format_estimate(c), f"[{rep['posterior_q05'][n]:.4g}, {rep['posterior_q95'][n]:.4g}]",
               f"{c['width_ratio']:.2f}" + ("" if c["informed"] else " not informed")]
        if truth:
            ok = rep["truth_in_90pct_interval"].get(n)
            row += [f"{truth[n]:.4g}" if n in truth else "-", "-" if ok is None else ("yes" if ok else "NO")]
        rows.append(row)
    o.table(cols, rows, title="Posterior (physical units)")
    from softsbi.report.text import rollouts, truth_miss_hint
    hint = truth_miss_hint(rep.get("truth_in_90pct_interval") or {}, str(out)) if truth else None
    if hint:
        o.line(hint)
    o.line(f"estimate: mean ± std, or geometric mean ×/÷ multiplicative spread for log-scaled parameters; "
           f"width / prior: the 90% interval's width over the prior's in the parameter's own scale (log for "
           f"log-scaled ones); above {INFORMED_MAX_RATIO:g} the data do not inform the parameter")
    for e in rep.get("posterior_at_bounds") or []:
        o.line("Note: " + bound_sentence(e) + ".")
    _print_best_fit(o, rep)
    if rep.get("mask_chamfer_prior_px") and rep.get("mask_chamfer_posterior_px"):
        o.line(f"Mask Chamfer to the measured frames: prior {rep['mask_chamfer_prior_px']:.2f} px -> posterior "
               f"{rep['mask_chamfer_posterior_px']:.2f} px "
               f"({describe_change(rep['mask_chamfer_prior_px'], rep['mask_chamfer_posterior_px'])})")
    if rep.get("chamfer_prior_m") and rep.get("chamfer_posterior_m"):
        o.line(f"Chamfer to the measurement: prior {rep['chamfer_prior_m'] * 100:.2f} cm -> posterior "
               f"predictive {rep['chamfer_posterior_m'] * 100:.2f} cm{rollouts(rep.get('chamfer_posterior_n'))} "
               f"({describe_change(rep['chamfer_prior_m'], rep['chamfer_posterior_m'])})")
        if rep["chamfer_posterior_m"] > rep["chamfer_prior_m"]:
            o.line("Note: rollouts at the posterior miss the measurement by more than rollouts at the prior: what "
                   "the fit matched (the observed state) does not bring the simulated object closer, a sign that "
                   f"the model cannot reach the data; `softsbi check {out}` shows where and when it misses")
    o.line(f"{rep['simulations']} simulations ({rep['failed_simulations']} failed), {rep['wall_time_s']:.0f} s. "
           f"Outputs in {out}: report.json, run.zarr, chamfer_rounds.png, posterior_pairs.png, clouds.png")


def _print_best_fit(o: Output, rep: dict[str, Any]) -> None:
    """The fit's widened priors and its best fit (``report.json``'s ``widened`` and ``best_fit``)."""
    from softsbi.workflows.widen import widening_sentence
    for w in rep.get("widened") or []:
        o.line("Note: " + widening_sentence(w) + ".")
    b = rep.get("best_fit")
    if not b:
        return
    units = {p["name"]: p["unit"] for p in rep["parameters"]}
    value = (f"Chamfer {b['chamfer_m'] * 100:.2f} cm" if "chamfer_m" in b else
             f"mask Chamfer {b.get('mask_chamfer_px', float('nan')):.2f} px")
    ref = b.get("refine")
    how = f"the lowest of {b['simulations_searched']} simulations" + (
        f", {ref['simulations']} of them by CMA-ES from the posterior" if ref else "")
    o.line("Best fit: " + ", ".join(f"{k}={v:.4g}{'' if units.get(k) in (None, '', '1') else ' ' + units[k]}"
                                    for k, v in b["theta"].items())
           + f"; {value} ({b['source']}; {how}; its rollout in clouds.png and softsbi view)")


def _show_warning(default, message, category, filename, lineno, file=None, line=None) -> None:
    """A :class:`~softsbi.core.errors.SoftsbiWarning` as one ``warning:`` line on stderr; other warnings as
    ``default`` (Python's ``warnings.showwarning``) shows them."""
    from softsbi.core.errors import SoftsbiWarning
    if issubclass(category, SoftsbiWarning):
        Output().err.print(f"warning: {message}", soft_wrap=True)
    else:
        default(message, category, filename, lineno, file, line)


def _guard(fn):
    """Run a command: a SoftsbiError prints one line (or a JSON error under ``--json``) and exits 2;
    Ctrl-C says how to resume; under ``--json`` any other error is a JSON error with exit 1."""

    @functools.wraps(fn)
    def wrapper(*a, **kw):
        as_json = bool(kw.get("as_json"))
        try:
            with warnings.catch_warnings():
                warnings.showwarning = functools.partial(_show_warning, warnings.showwarning)
                return fn(*a, **kw)
        except (typer.Exit, typer.Abort):
            raise
        except SoftsbiError as exc:
            if as_json:
                sys.stdout.write(json_error(exc) + "\n")
            else:
                Output().error(str(exc))
            raise typer.Exit(2)
        except KeyboardInterrupt as stop:
            what = "terminated (SIGTERM)" if isinstance(stop, Terminated) else "interrupted"
            exc = KeyboardInterrupt(f"{what}; finished simulations are kept: re-run the same command to resume")
            if as_json:
                sys.stdout.write(json_error(exc) + "\n")
            else:
                Output().error(str(exc))
            raise typer.Exit(143 if isinstance(stop, Terminated) else 130)
        except Exception as exc:
            from softsbi.core.errors import storage_error
            err = storage_error(exc)  # a full or read-only disk is the machine's state, not a bug
            if err is not None:
                if as_json:
                    sys.stdout.write(json_error(err) + "\n")
                else:
                    Output().error(str(err))
                raise typer.Exit(2)
            if as_json:
                sys.stdout.write(json_error(exc) + "\n")
                raise typer.Exit(1)
            raise
    return wrapper


@app.command()
@_guard
def plugins(as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """List installed simulators, effects (with the backends that can apply each and its parameters), observers,
    estimators and executors."""
    from softsbi.plugins import registry
    from softsbi.plugins.manager import LOAD_ERRORS
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
        if kind == "effects":
            o.table(["name", "kind", "applied by", "parameters [prior] unit", "package", "description"],
                    [[r["name"], r["kind"] + (" (generic)" if r.get("generic") else ""),
                      ", ".join(r["backends"]) or "none installed",
                      "; ".join(_param_text(p) for p in r["parameters"]), r["package"],
                      r.get("description") or r.get("doc") or ""]
                     for r in rows], title=kind)
            continue
        o.table(["name", "package", "description"],
                [[r["name"], r["package"], (r.get("doc") or "") +
                  (f" scenarios: {', '.join(r['scenarios'])}" if r.get("scenarios") else "")] for r in rows],
                title=kind)
    for name, err in LOAD_ERRORS.items():
        o.line(f"plugin '{name}' failed to load: {err}")


def _param_text(p: dict[str, Any]) -> str:
    """``wind_x [-2, 2] m/s`` (``log`` added for a log-uniform prior)."""
    unit = "" if p["unit"] in ("", "1") else f" {p['unit']}"
    return f"{p['name']} [{p['prior'][0]:g}, {p['prior'][1]:g}]{unit}{' log' if p['scale'] == 'log' else ''}"


def _limit_text(limits: list[Any]) -> str:
    lo, hi = ("-inf" if limits[0] is None else f"{limits[0]:g}"), ("inf" if limits[1] is None else f"{limits[1]:g}")
    return f"{lo} to {hi}"


@app.command()
@_guard
def params(scenario: str = typer.Argument(..., help="scenario name (`softsbi scenarios` lists them), scenario file "
                                                    "(.yaml) or recording folder (its scenario)"),
           effect: list[str] = typer.Option(None, "--effect", help="effects to add (their parameters join the "
                                                                   "backend's)"),
           backend: str = typer.Option(D.BACKEND, help=H_BACKEND),
           as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Every parameter a fit of SCENARIO infers: unit, prior bounds, scale and physical limits (`fit --bounds` moves
    a prior up to the limits, `fit --fix` holds a parameter)."""
    from softsbi.scenarios import load_scenario
    from softsbi.workflows.fit import FitConfig, parameter_table
    from softsbi.workflows.measurement import recording_scenario
    effects = [e for it in effect or [] for e in it.split(",") if e]
    sc = recording_scenario(scenario) if Path(scenario).is_dir() else load_scenario(scenario)
    rows = parameter_table(FitConfig(backend=backend, effects=effects), sc)
    o = Output(as_json)
    if as_json:
        o.emit_json({"scenario": sc.name, "backend": backend, "effects": effects, "parameters": rows})
        return
    o.table(["parameter", "from", "unit", "prior", "scale", "physical limits", "description"],
            [[r["name"], r["source"], r["unit"], f"{r['prior'][0]:g} to {r['prior'][1]:g}", r["scale"],
              _limit_text(r["limits"]), r["description"]] for r in rows],
            title=f"Parameters of a fit of '{sc.name}' on {backend}" + (f" with {', '.join(effects)}" if effects else ""))


@app.command()
@_guard
def simulate(backend: str = typer.Option(D.BACKEND, help=H_BACKEND),
             scenario: str = typer.Option(D.SCENARIO, help="scenario name (`softsbi scenarios` lists them) or scenario "
                                                       "file (.yaml)"),
             recording: Optional[Path] = typer.Option(None, help="real recording folder to take the scenario from"),
             theta: list[str] = typer.Option(None, "--theta", help="name=value (repeatable); unset: scale = the scenario's object "
                                                             "size, others = prior midpoint"),
             effect: list[str] = typer.Option(None, "--effect", help="effect names to switch on"),
             backend_opt: list[str] = typer.Option(None, "--backend-opt", help="backend option name=value"),
             out: Path = typer.Option(Path("rollout"), help="output folder: rollout.zarr, preview.png and a "
                                                            "recording (recording.yaml + clouds/) that `softsbi fit "
                                                            "--observed OUT` reads"),
             render: Optional[int] = typer.Option(None, callback=_bound(1), help="also render every frame through the scenario's "
                                                             "overhead camera at this square size (px): "
                                                             "OUT/frames/000.png ... + truth.json, a measurement "
                                                             "for `fit --observer heatmap|transporter`"),
             render_memory_gb: Optional[float] = typer.Option(None, callback=_bound(0, strict=True), help="cap on the rendered frames' estimated "
                                                                         "memory, GB (default 4); larger renders "
                                                                         "are refused before simulating"),
             overwrite: bool = typer.Option(False, "--overwrite", help="replace what --out holds (an earlier "
                                                                       "simulation); without it a non-empty --out "
                                                                       "is refused"),
             as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Roll a scenario out at given parameters; write Zarr and a PNG preview (and rendered frames)."""
    from softsbi.workflows.simulate import RENDER_MEMORY_GB, simulate_to_folder

    o = Output(as_json)
    doc = simulate_to_folder(out, backend=backend, scenario=scenario, recording=recording,
                             theta=_parse_kv(theta, "--theta"), effects=[e for it in effect or [] for e in it.split(",") if e],
                             backend_options=_parse_kv(backend_opt, "--backend-opt"), render=render,
                             render_memory_gb=RENDER_MEMORY_GB if render_memory_gb is None else render_memory_gb,
                             overwrite=overwrite)
    if as_json:
        o.emit_json(doc)
        if doc["status"] != 0:
            raise typer.Exit(1)
        return
    o.line(f"{backend} {scenario}: status {'ok' if doc['status'] == 0 else doc['reason']}, {doc['frames']} frames, "
           f"{doc['vertices']} vertices, {doc['wall_s']:.2f} s wall -> {doc['rollout']}")
    if doc["status"] != 0:  # the failed rollout is kept for a look, but there is no recording to fit
        o.error(f"the simulation failed ({doc['reason']}); no recording was written")
        raise typer.Exit(1)
    if doc.get("recording"):
        o.line(f"recording: {doc['recording']} (`softsbi fit --observed {doc['recording']} --out RUN` fits it)")
    if doc.get("preview"):
        o.line(f"preview: {doc['preview']}")
    if doc.get("frames_dir"):
        o.line(f"{doc['frames']} rendered frames ({render}x{render} px): {doc['frames_dir']} (truth.json holds "
               f"the parameters; `softsbi fit --observed {doc['frames_dir']} --scenario {scenario} "
               f"--observer heatmap --extractor ...` fits them)")


def _fit_config(backend, estimator, rounds, sims_per_round, seed, points, workers, effect, bounds, fix,
                backend_opt, estimator_opt, n_eval, min_height=None, frames=None, executor="local",
                executor_options=None, proposal="truncated"):
    from softsbi.workflows.fit import FitConfig
    effects = [e for it in effect or [] for e in it.split(",") if e]
    return FitConfig(backend=backend, backend_options=_parse_kv(backend_opt, "--backend-opt"), effects=effects,
                     estimator=estimator, estimator_options=_parse_kv(estimator_opt, "--estimator-opt"),
                     rounds=rounds, sims_per_round=sims_per_round, seed=seed, n_points=points, workers=workers,
                     bounds=_parse_bounds(bounds), fixed=_parse_kv(fix, "--fix"), n_eval=n_eval,
                     min_height=min_height, frames=frames, executor=executor,
                     executor_options=dict(executor_options or {}), proposal=Proposal(proposal).value)


@app.command()
@_guard
def fit(observed: Path = typer.Option(..., help="recording directory (recording.yaml + clouds/: `softsbi import "
                                                 "diffcloud`, `softsbi simulate --out`), a DiffCloud folder "
                                                 "(000.npy ... + <task>_real2sim.yaml), or with an image observer "
                                                 "a folder of frames 000.png ..."),
        out: Path = typer.Option(..., help="run directory (resumes if it holds a run)"),
        backend: str = typer.Option(D.BACKEND, help=H_BACKEND),
        estimator: str = typer.Option(D.ESTIMATOR, help=H_ESTIMATOR),
        rounds: int = typer.Option(D.ROUNDS, help="sequential rounds (paper: 15)", callback=ROUNDS_OK),
        sims_per_round: int = typer.Option(D.SIMS_PER_ROUND, help="simulations per round (paper: 100)",
                                           callback=SIMS_OK),
        seed: int = typer.Option(D.SEED, help=H_SEED, callback=SEED_OK),
        points: int = typer.Option(D.N_POINTS, help="K, points per frame", callback=_bound(1)),
        workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=AT_LEAST_1_WORKER),
        effect: list[str] = typer.Option(None, "--effect", help="effects to add (their parameters are inferred)"),
        bounds: list[str] = typer.Option(None, "--bounds", help="prior bounds name=low:high"),
        fix: list[str] = typer.Option(None, "--fix", help="hold a parameter: name=value"),
        backend_opt: list[str] = typer.Option(None, "--backend-opt", help="backend option name=value"),
        estimator_opt: list[str] = typer.Option(None, "--estimator-opt", help="estimator option name=value"),
        n_eval: int = typer.Option(D.N_EVAL, "--n-eval", help=H_N_EVAL + "; their mean Chamfer is the reported one",
                                   callback=_bound(1, "one rollout at least")),
        min_height: Optional[float] = typer.Option(
            None, callback=_bound(0, "0 = every point visible"), help="sensor model: points closer than this (m) to the table are not seen, in simulation and "
                       "recording alike (0 = all visible); default: the recording's (DiffCloud depth clouds lack "
                       "cloth lying flat: 0.01)"),
        frames: Optional[str] = typer.Option(None, help="frames that inform the posterior: 'auto' (the cloth hangs "
                                                        "clear: gripper >= 10 cm above the table), 'all', or e.g. "
                                                        "10:25; default: the recording's (DiffCloud: auto); the "
                                                        "reported Chamfer is the mean over these frames"),
        sensor: str = typer.Option(D.SENSOR, help="sensor model of the metric and the observed state: height (the "
                                                  "--min-height cut, simulation and recording alike) or camera "
                                                  "(simulated clouds from a virtual depth sensor made like "
                                                  "DiffCloud's, from the recording's calibrated cameras; DiffCloud "
                                                  "lift folders only)"),
        executor: str = typer.Option(D.EXECUTOR, help="where simulations run: local (process pool) or ray "
                                                   "(executor plugins; `softsbi plugins` lists them)"),
        ray_address: Optional[str] = typer.Option(None, help="with --executor ray: address of an existing Ray "
                                                             "cluster (head host:port or auto); default: start Ray "
                                                             "on this machine"),
        sim_timeout: Optional[float] = typer.Option(None, callback=_bound(0, strict=True), help="seconds after which a hung simulation's worker is "
                                                               "killed and the simulation retried (default: none)"),
        retries: int = typer.Option(2, callback=_bound(0), help="re-runs of a simulation whose worker crashed or hung, before it is "
                                            "stored as failed"),
        observer: str = typer.Option(D.OBSERVER, help="observer plugin: pointcloud (3-D clouds), or heatmap / "
                                                        "transporter (keypoints found in RGB frames by a trained "
                                                        "extractor)"),
        extractor: Optional[Path] = typer.Option(None, help="with --observer heatmap|transporter: the trained "
                                                            "extractor checkpoint (softsbi train-extractor)"),
        scenario: Optional[str] = typer.Option(None, help="scenario (name or file) the frames were recorded in; "
                                                          "default: the recording's own (image observers: lift)"),
        image_size: int = typer.Option(D.IMAGE_SIZE, callback=_bound(1), help="image observers: square size (px) of the scenario's built-in "
                                                 "camera; frames are resized to it"),
        proposal: Proposal = typer.Option(Proposal(D.PROPOSAL), help=H_PROPOSAL),
        sensor_draws: int = typer.Option(0, "--sensor-draws", callback=_bound(0),
                                         help="observe each simulation at N more values of the sensor effects' "
                                              "parameters (--effect time-offset, point-noise, ...): N times more "
                                              "training pairs along them at no simulation cost (truncated "
                                              "proposals)"),
        retry_failed: bool = typer.Option(False, "--retry-failed",
                                          help="on resume, simulate the stored failed simulations again (after "
                                               "fixing what made them fail); later rounds are drawn again"),
        refine: int = typer.Option(0, "--refine", callback=_bound(0, "0 = no refinement"), help="polish the best fit with N more simulations by CMA-ES, "
                                                        "started at the posterior (stored in the run; resumable; "
                                                        "the posterior is left as it is)"),
        widen: bool = typer.Option(False, "--widen", help="after each round, move a prior bound the posterior "
                                                          "presses (not a physical limit) outward by the rule of the "
                                                          "note under the table, for the following rounds"),
        sim_bank: str = typer.Option(D.SIM_BANK, "--sim-bank", help="simulation bank of the first round: fits of "
                                     "other recordings of the same task read its rollouts instead of simulating "
                                     "them ('default': the user's cache folder; or a folder)"),
        no_sim_bank: bool = typer.Option(False, "--no-sim-bank", help="simulate the first round without a bank"),
        as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Infer the posterior over physical parameters from a recording (resumable)."""
    from softsbi.workflows.measurement import load_image_recording, load_recording
    from softsbi.workflows.bank import check_bank_path
    from softsbi.plugins import registry
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
    cfg.sensor = sensor
    cfg.sensor_draws = sensor_draws
    cfg.refine, cfg.widen = refine, widen
    cfg.sim_bank = "off" if no_sim_bank else sim_bank
    images = bool(getattr(registry().observer(observer), "needs_images", False))
    if images:
        if extractor is None:
            raise SoftsbiError(f"--observer {observer} needs --extractor PATH.pt (train one with `softsbi "
                               f"train-extractor {observer} --out PATH.pt`)")
        cfg.observer_options = {"extractor": str(extractor), "size": image_size}
    elif extractor is not None:
        raise SoftsbiError(f"--extractor is for image observers (heatmap, transporter), not '{observer}'")
    cfg.validate()  # fail fast (e.g. --workers 0) before loading the recording
    check_bank_path(cfg.sim_bank, {"--out": out, "--observed": observed})
    if executor == "ray":
        from softsbi.executors.ray_executor import _import_ray
        _import_ray()  # DependencyMissing naming `pip install softsbi[ray]`
    if images:
        meas = load_image_recording(observed, scenario=scenario, size=image_size)
    else:
        meas = load_recording(observed, n_points=points, seed=seed, scenario=scenario)
    o = Output(as_json)
    res = _run(o, meas, cfg, out, retry_failed=retry_failed)
    if as_json:
        o.emit_json(dict(res.report, run_dir=str(out)))
    else:
        _print_report(o, res.report, out)


@app.command()
@_guard
def demo(out: Path = typer.Option(Path("softsbi-demo"), help="output folder"),
         quick: bool = typer.Option(False, "--quick", help="only fit hidden parameters (no hidden effect)"),
         rounds: int = typer.Option(D.DEMO_ROUNDS, help="sequential rounds per fit", callback=ROUNDS_OK),
         sims_per_round: int = typer.Option(D.DEMO_SIMS, help="simulations per round", callback=SIMS_OK),
         estimator: str = typer.Option(D.ESTIMATOR, help=H_ESTIMATOR),
         seed: int = typer.Option(D.SEED, help=H_SEED, callback=SEED_OK),
         workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=AT_LEAST_1_WORKER),
         proposal: Proposal = typer.Option(Proposal(D.PROPOSAL), help=H_PROPOSAL + "; truncated keeps the "
                                                                                 "7-parameter refit's posterior tight"),
         as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """The whole real-to-sim story on a built-in case that needs no data files.

    A lift measurement is simulated at parameters you are not shown, with a hidden breeze the
    nominal model lacks. softsbi fits the nominal model, checks it against the measurement,
    diagnoses the missing effect among all installed ones, refits with it and compares.
    "Before" and "after" are the posterior-predictive Chamfer of the two fits: the mean over
    rollouts at their posterior samples (report.json's chamfer_posterior_m; compare shows the same).
    """
    from softsbi.cli.progress import DemoPrinter
    from softsbi.workflows.demo import run_demo
    o = Output(as_json)
    doc = run_demo(out, quick=quick, rounds=rounds, sims_per_round=sims_per_round, estimator=estimator, seed=seed,
                   workers=workers, proposal=Proposal(proposal).value, ui=DemoPrinter(o))
    if as_json:
        o.emit_json(doc)


@app.command()
@_guard
def check(run: Path = typer.Argument(..., help="run directory of a finished fit"),
          n_eval: int = typer.Option(D.N_NULL, "--n-eval", help=H_N_EVAL, callback=N_NULL_OK),
          max_null: int = typer.Option(D.MAX_NULL, "--max-null", callback=_bound(D.MIN_ROLLOUTS), help=H_MAX_NULL),
          alpha: float = typer.Option(ALPHA, help=H_ALPHA, callback=ALPHA_OK),
          workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=AT_LEAST_1_WORKER),
          recompute: bool = typer.Option(False, "--recompute", help=H_RECOMPUTE),
          as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Posterior predictive check: where and when the fitted model misses the measurement."""
    from softsbi.core.results import to_json
    from softsbi.report.text import check_summary, joint_test_line
    from softsbi.workflows.check import check_run
    o = Output(as_json)
    from softsbi.cli.progress import shown
    with shown(o):
        out = check_run(run, n_eval=n_eval, workers=workers, alpha=alpha, max_null=max_null, recompute=recompute,
                        message=o.message)
    if as_json:
        o.emit_json(to_json(out))
        return
    o.table(["phase", "time [s]", "Chamfer [cm]", "worst region"],
            [[ph.phase + ("" if ph.in_fit else " (not fitted)"), f"{ph.t_s[0]:.2f}-{ph.t_s[1]:.2f}",
              f"{ph.chamfer_m * 100:.2f}", ph.worst_region] for ph in out.phases],
            title="Error by phase of the motion")
    o.line(joint_test_line(out.test))
    o.line(check_summary(out))


@app.command()
@_guard
def calibrate(run: Path = typer.Argument(..., help="run directory of a finished fit"),
              n_test: int = typer.Option(D.N_TEST, "--n-test", callback=_bound(D.MIN_TEST, "200 or more resolves "
                                         "the 90% coverage"), help="fresh test simulations from the run's proposals "
                                         "(stored in the run; a re-run resumes, a larger number adds to them)"),
              n_draws: int = typer.Option(D.N_DRAWS, "--n-draws", help="posterior draws per test simulation",
                                          callback=_bound(D.MIN_DRAWS, f"one draw per bin of the {D.N_BINS}-bin SBC "
                                                          f"rank histogram, HPD levels (coverage, TARP) resolved to "
                                                          f"1/{D.N_BINS}")),
              workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=AT_LEAST_1_WORKER),
              as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Simulation-based calibration of the run's posterior estimator: expected coverage, SBC ranks, TARP."""
    from softsbi.workflows.calibrate import calibrate_run
    o = Output(as_json)
    from softsbi.cli.progress import shown
    with shown(o):
        out = calibrate_run(run, n_test=n_test, n_draws=n_draws, workers=workers, message=o.message)
    if as_json:
        o.emit_json(out.to_json())
        return
    _print_calibration(o, out)
    o.line(f"verdict: {out.verdict}")
    o.line(f"wrote {run / 'calibration.json'} and {run / 'calibration.png'}")


def _print_calibration(o: Output, out: Any) -> None:
    """``softsbi calibrate``'s table and one line per diagnostic the verdict reads (``out``: a
    :class:`~softsbi.core.fitreport.CalibrationResult`)."""
    from softsbi.inference.calibration import SHAPES
    c, d = out.coverage, out.diagnostics
    conf = 100 * c.band_simultaneous_confidence
    o.table(["level", "expected coverage", f"calibrated range ({conf:.1f}%, whole curve)", "verdict"],
            [[f"{int(100 * g)}%", f"{at:.2f}", f"[{b[0]:.2f}, {b[1]:.2f}]", v]
             for g, at, b, v in ((0.5, c.at_50, c.band_50, out.verdict_50), (0.9, c.at_90, c.band_90, out.verdict_90))],
            title=f"Calibration of '{out.estimator}' on {out.n_test} fresh test simulations")
    out_pw = c.outside_pointwise
    o.line("joint coverage (HPD): " + ("inside" if c.inside_simultaneous else "OUTSIDE")
           + f" the simultaneous {conf:.1f}% band over {len(c.levels) - 2} levels"
           + ("" if c.inside_simultaneous else f" ({d['coverage']['direction']})") + "; "
           + (f"outside the pointwise 95% band at {', '.join(f'{int(round(100 * g))}%' for g in out_pw)}"
              if out_pw else "inside the pointwise 95% band at every level"))
    t = d["tarp"]
    o.line(f"TARP: KS p={t['ks_pvalue']:.2g} (rejects below {t['level']:.3g}), ATC {t['atc']:+.3f}: "
           + (f"rejects ({t['direction']})" if t["rejects"] else "consistent with calibrated"))
    s = d["sbc"]
    bad = [p for p in s["parameters"] if p["rejects"]]
    o.line(f"SBC per parameter (KS, mean, spread and histogram band, each at {s['level']:.2g}: Bonferroni over "
           f"{len(s['parameters'])} parameters): "
           + ("; ".join(f"{p['name']} " + " and ".join(SHAPES[k] for k in p["shapes"]) for p in bad) if bad
              else "every rank histogram uniform")
           + (f"; uniform: {', '.join(p['name'] for p in s['parameters'] if not p['rejects'])}"
              if bad and len(bad) < len(s["parameters"]) else ""))


@app.command()
@_guard
def diagnose(run: Path = typer.Argument(..., help="run directory of a finished fit (nominal model)"),
             effect: list[str] = typer.Option(None, "--effect", help="candidate effects (default: all installed)"),
             confirm: int = typer.Option(D.CONFIRM, callback=_bound(0, "0 = no refit"), help="refit the top N named candidates by evidence (and at most "
                                                          "one pair when none explains the misfit alone; 0 = no "
                                                          "refit)"),
             refit_rounds: Optional[int] = typer.Option(None, help="rounds of a refit (default: the run's)",
                                                        callback=_bound(1, "leave it out for the run's own")),
             refit_sims: Optional[int] = typer.Option(None, help="simulations per round of a refit "
                                                                 "(default: the run's)",
                                                      callback=_bound(D.MIN_SIMS_PER_ROUND, "the estimator needs "
                                                                      "data; leave it out for the run's own")),
             k_se: float = typer.Option(D.K_SE, "--k-se", callback=_bound(0, strict=True), help="standard errors by which a refit's summary energy score "
                                                               "must fall to count, and within which two refits tie"),
             n_null: int = typer.Option(D.N_NULL, "--n-null", callback=N_NULL_OK, help="posterior-predictive simulations the null "
                                                                   "starts with"),
             max_null: int = typer.Option(D.MAX_NULL, "--max-null", callback=_bound(D.MIN_ROLLOUTS), help=H_MAX_NULL),
             alpha: float = typer.Option(ALPHA, help=H_ALPHA, callback=ALPHA_OK),
             workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=AT_LEAST_1_WORKER),
             recompute: bool = typer.Option(False, "--recompute", help=H_RECOMPUTE),
             out_dir: Optional[Path] = typer.Option(None, "--out", help="output folder of diagnosis.json and the "
                                                    "refits (default: RUN), to keep two diagnoses of one run apart"),
             as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Is an effect missing, and which? Detect (check's test), propose (the screening ranks the candidates and the
    top ones are refitted), decide (a refit explains the misfit when check accepts it and its summary energy score
    falls)."""
    from softsbi.core.results import to_json
    from softsbi.report.text import DIAGNOSIS_COLUMNS, diagnosis_rows, diagnosis_text
    from softsbi.workflows.diagnose import diagnose_run
    o = Output(as_json)
    names = [e for it in effect or [] for e in it.split(",") if e] or None
    from softsbi.cli.progress import shown
    with shown(o):
        out = diagnose_run(run, effects=names, confirm=confirm, refit_rounds=refit_rounds, refit_sims=refit_sims,
                           k_se=k_se, workers=workers, n_null=n_null, max_null=max_null, alpha=alpha,
                           progress=o.message, recompute=recompute, out_dir=out_dir)
    if as_json:
        o.emit_json(to_json(out))
        return
    o.table(DIAGNOSIS_COLUMNS, diagnosis_rows(out), title="Candidate effects, by the screening's evidence")
    o.line(f"verdict: {out.verdict}")
    for paragraph in diagnosis_text(out):
        o.line(paragraph)


@app.command()
@_guard
def compare(run_a: Path = typer.Argument(..., help="first run (e.g. nominal model)"),
            run_b: Path = typer.Argument(..., help="second run (e.g. with the effect added)"),
            out: Optional[Path] = typer.Option(None, help="output folder (default: RUN_B)"),
            n_eval: int = typer.Option(D.N_NULL, "--n-eval", help=H_N_EVAL + ", per run", callback=N_NULL_OK),
            max_null: int = typer.Option(D.MAX_NULL, "--max-null", callback=_bound(D.MIN_ROLLOUTS), help=H_MAX_NULL + " (each run's check)"),
            alpha: float = typer.Option(ALPHA, help=H_ALPHA + " (each run's check)", callback=ALPHA_OK),
            workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=AT_LEAST_1_WORKER),
            recompute: bool = typer.Option(False, "--recompute", help=H_RECOMPUTE),
            as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Two runs side by side: error per time step and region, before vs after."""
    from softsbi.core.results import to_json
    from softsbi.report.text import compare_summary
    from softsbi.workflows.compare import compare_runs
    o = Output(as_json)
    from softsbi.cli.progress import shown
    with shown(o):
        res = compare_runs(run_a, run_b, out or run_b, n_eval=n_eval, workers=workers, alpha=alpha,
                           max_null=max_null, recompute=recompute, message=o.message)
    if as_json:
        o.emit_json(to_json(res))
        return
    o.table(["", str(run_a), str(run_b), "change"],
            [[row.what, f"{row.a * 100:.2f} cm", f"{row.b * 100:.2f} cm", f"{row.change * 100:+.0f}%"]
             for row in res.rows], title="Posterior-predictive error")
    o.line(compare_summary(res))
    o.line(f"wrote {res.png} and {Path(res.png).with_name('compare.json')}")


@app.command()
@_guard
def view(run: Path = typer.Argument(..., help="run directory of a finished point-cloud fit"),
         n_eval: int = typer.Option(D.VIEW_N_EVAL, "--n-eval", callback=_bound(1), help="posterior-predictive rollouts drawn (faded) against the "
                                                          "measurement"),
         gif: bool = typer.Option(True, help="write RUN/view.gif: measured vs simulated clouds over time"),
         rrd: Optional[bool] = typer.Option(None, "--rrd/--no-rrd",
                                            help="write RUN/view.rrd for the rerun viewer (`rerun RUN/view.rrd`), "
                                                 "which needs `pip install \"softsbi\\[view]\"`; default: when "
                                                 "it is installed"),
         workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=AT_LEAST_1_WORKER),
         as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """See the measured cloud move against posterior rollouts: an animation and a rerun recording."""
    from softsbi.workflows.view import write_view
    o = Output(as_json)
    from softsbi.cli.progress import shown
    with shown(o):
        res = write_view(run, n_eval=n_eval, workers=workers, gif=gif, rrd=rrd)
    if as_json:
        o.emit_json(res)
        return
    for key in ("gif", "rrd"):
        if res.get(key):
            o.line(f"wrote {res[key]}" + ("  (open with `rerun " + str(res[key]) + "`)" if key == "rrd" else ""))
    if res.get("rrd_missing"):
        o.line('not written: view.rrd (the 3-D rerun recording needs the extra: pip install "softsbi[view]")')


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
                    backend: str = typer.Option(D.BACKEND, help="with --simulate: simulator plugin"),
                    rollouts: int = typer.Option(D.IMAGE_ROLLOUTS, help="with --simulate: rendered rollouts",
                                                 callback=_bound(1)),
                    image_size: int = typer.Option(D.IMAGE_SIZE, help="with --simulate: square camera size (px)",
                                                   callback=_bound(1)),
                    mask_robot: bool = typer.Option(True, help="transporter: leave the robot out of the "
                                                               "reconstruction loss"),
                    opt: list[str] = typer.Option(None, "--opt", help="extractor option name=value (repeatable)"),
                    seed: int = typer.Option(D.SEED, help=H_SEED, callback=SEED_OK),
                    as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Train a keypoint extractor on annotated images or on rendered rollouts; report its test error."""
    from softsbi.workflows.extractor import ExtractorProgress, train_extractor as train

    class Bars(ExtractorProgress):
        def __init__(self, p: Any):
            self.p = p

        def message(self, text: str) -> None:
            o.line(text)

        def task(self, description: str, total: int | None):
            t = self.p.add_task(description, total=total)

            def update(done: int, total: int | None = None, loss: float | None = None) -> None:
                label = description if loss is None else f"{description} (loss {loss:.4g})"
                self.p.update(t, completed=done, total=total, description=label)
            return update

    o = Output(as_json)
    with o.progress() as p:
        summary = train(kind, out, data=data, simulate=simulate, backend=backend, rollouts=rollouts,
                        image_size=image_size, mask_robot=mask_robot, options=_parse_kv(opt, "--opt"), seed=seed,
                        progress=Bars(p))
    if as_json:
        o.emit_json(summary)
        return
    tr = summary["train"]
    o.line(f"trained {kind}: {tr.get('epochs')} epochs, {tr.get('seconds', 0):.0f} s -> {out} "
           f"(summary {out.with_suffix('.json')})")


@app.command("compare-backends")
@_guard
def compare_backends_cmd(scenario: str = typer.Option(D.SCENARIO, help="scenario name or file (`softsbi scenarios` "
                                                                   "lists them)"),
                         theta: list[str] = typer.Option(None, "--theta",
                                                         help="name=value (repeatable); unset = the shared prior midpoint "
                                                              "(engine-only knobs: each backend's own)"),
                         backends: str = typer.Option(",".join(D.COMPARED_BACKENDS), help="comma-separated simulators"),
                         backend_opt: list[str] = typer.Option(None, "--backend-opt",
                                                               help="backend:option=value, e.g. pybullet-massspring:grid=7"),
                         match: Match = typer.Option(Match.physical, help="match the engines by 'physical' "
                                                                          "parameter values or by 'unit' prior "
                                                                          "positions in [0, 1]"),
                         out: Path = typer.Option(Path("compare"), help="output folder (compare.json + compare.png)"),
                         as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Roll the same scenario out on two engines at the same physical parameters (default: the shared prior
    midpoint); per-frame Chamfer between them says how far the engines disagree."""
    from softsbi.workflows.compare_backends import compare_backends
    from softsbi.scenarios.builtin import make_scenario

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
    o.line("shared physical parameters: " + (", ".join(rep["shared_params"]) or "(none)"))
    for key, m in rep["mean_chamfer_m"].items():
        mx = rep["max_chamfer_m"][key]
        o.line(f"Chamfer {key}: " + (f"mean {m * 100:.2f} cm, max {mx * 100:.2f} cm over {len(rep['times'])} frames"
                                     if m is not None else "n/a (a rollout failed)"))
    o.line(f"wrote {out / 'compare.json'} and {out / 'compare.png'}")


@app.command("scenarios")
@_guard
def scenarios_cmd(as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """List the scenarios: the built-in scenario files and those plugins add (softsbi_scenarios hook).
    Any scenario file path works wherever a scenario name does."""
    from softsbi.scenarios import list_scenarios
    rows = list_scenarios()
    o = Output(as_json)
    if as_json:
        o.emit_json(rows)
        return
    o.table(["name", "source", "description"], [[r["name"], r["source"], r["description"]] for r in rows],
            title="scenarios")


import_app = typer.Typer(help="Convert recordings from other layouts into recording directories.",
                         no_args_is_help=True)
app.add_typer(import_app, name="import")


@import_app.command("diffcloud")
@_guard
def import_diffcloud_cmd(src: Path = typer.Argument(..., help="a DiffCloud recording folder (lift_tan, fold_navy2) "
                                                              "or a folder of them (diffcloud_lift, diffcloud_fold)"),
                         dst: Path = typer.Argument(..., help="destination: the recording directory, or for a "
                                                              "folder of recordings their parent"),
                         scenario: Optional[str] = typer.Option(None, help="scenario name or file of the "
                                                                           "recordings (needed for tasks other "
                                                                           "than lift, e.g. examples/fold.yaml)"),
                         as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Convert DiffCloud recordings (lift, fold) into recording directories (recording.yaml + clouds/)."""
    from softsbi.workflows.measurement import import_diffcloud
    written = import_diffcloud(src, dst, scenario)
    o = Output(as_json)
    if as_json:
        o.emit_json({"recordings": [str(p) for p in written]})
        return
    for p in written:
        o.line(f"wrote {p}")


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the command is, so that it stops as after Ctrl-C: finished work kept, one line."""


def _terminate(signum: int, frame: Any) -> None:
    raise Terminated()


def main() -> None:
    """Console-script entry point (SIGTERM stops a command as Ctrl-C does: one line, exit code 143)."""
    import signal
    signal.signal(signal.SIGTERM, _terminate)
    app()


if __name__ == "__main__":
    main()
