"""``softsbi fit``: infer the posterior over physical parameters from a recording, and print its report."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import (H_BACKEND, H_ESTIMATOR, H_JSON, H_N_EVAL, H_PROPOSAL, H_SEED, H_WORKERS,
                                 IMAGE_SIZE_OK, POINTS_OK, ROUNDS_OK, SEED_OK, SIMS_OK, WORKERS_OK, Proposal, bound,
                                 checked, names, parse_bounds, parse_kv)
from softsbi.cli.output import Output
from softsbi.core.errors import SoftsbiError
from softsbi.core import defaults as D


def print_fit_report(o: Output, rep: dict[str, Any], out: Path) -> None:
    """The fit's report (``rep``: ``report.json`` of run directory ``out``, as
    :meth:`~softsbi.core.results.fitreport.FitReport.to_json` writes it) as a table and sentences on stdout
    (:mod:`softsbi.report.fit_text` words them)."""
    from softsbi.report.fit_text import fit_report_lines, posterior_table  # start-up: numpy, scipy
    from softsbi.workflows.fit.prior_widening import widening_sentence  # start-up: numpy
    t = posterior_table(rep)
    o.table(t.columns, t.rows, title=t.title)
    for line in fit_report_lines(rep, out, [widening_sentence(w) for w in rep["widened"]]):
        o.line(line)


def fit(observed: Path = typer.Option(..., help="recording directory (recording.yaml + clouds/: `softsbi import "
                                                 "diffcloud`, `softsbi simulate --out`), a DiffCloud folder "
                                                 "(000.npy ... + <task>_real2sim.yaml), or with an image observer "
                                                 "a folder of frames 000.png ..."),
        out: Path = typer.Option(..., help="run directory (resumes if it holds a run)"),
        backend: str = typer.Option(D.BACKEND, help=H_BACKEND),
        estimator: str = typer.Option(D.ESTIMATOR, help=H_ESTIMATOR),
        rounds: Optional[int] = typer.Option(None, help=f"sequential rounds (paper: 15); default: 1 when the task was "
                                                        f"trained (`softsbi task train`), else {D.ROUNDS}",
                                             callback=ROUNDS_OK),
        sims_per_round: int = typer.Option(D.SIMS_PER_ROUND, help="simulations per round (paper: 100)",
                                           callback=SIMS_OK),
        seed: int = typer.Option(D.SEED, help=H_SEED, callback=SEED_OK),
        points: int = typer.Option(D.N_POINTS, help="K, points per frame", callback=POINTS_OK),
        workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=WORKERS_OK),
        effect: list[str] = typer.Option(None, "--effect", help="effects to add (their parameters are inferred)"),
        bounds: list[str] = typer.Option(None, "--bounds", help="prior bounds name=low:high"),
        fix: list[str] = typer.Option(None, "--fix", help="hold a parameter: name=value"),
        backend_opt: list[str] = typer.Option(None, "--backend-opt", help="backend option name=value"),
        estimator_opt: list[str] = typer.Option(None, "--estimator-opt", help="estimator option name=value"),
        n_eval: int = typer.Option(D.N_EVAL, "--n-eval", help=H_N_EVAL + "; their mean Chamfer is the reported one",
                                   callback=checked(D.EVAL_BOUND)),
        min_height: Optional[float] = typer.Option(
            None, callback=bound(0, "0 = every point visible"), help="sensor model: points closer than this (m) to the table are not seen, in simulation and "
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
        sim_timeout: Optional[float] = typer.Option(None, callback=bound(0, strict=True), help="seconds after which a hung simulation's worker is "
                                                               "killed and the simulation retried (default: none)"),
        retries: int = typer.Option(D.RETRIES, callback=checked(D.RETRIES_BOUND), help="re-runs of a simulation whose worker crashed or hung, before it is "
                                            "stored as failed"),
        observer: str = typer.Option(D.OBSERVER, help="observer plugin: pointcloud (3-D clouds), or heatmap / "
                                                        "transporter (keypoints found in RGB frames by a trained "
                                                        "extractor)"),
        extractor: Optional[Path] = typer.Option(None, help="with --observer heatmap|transporter: the trained "
                                                            "extractor checkpoint (softsbi train-extractor)"),
        scenario: Optional[str] = typer.Option(None, help="scenario (name or file) the frames were recorded in; "
                                                          "default: the recording's own (image observers: lift)"),
        image_size: int = typer.Option(D.IMAGE_SIZE, callback=IMAGE_SIZE_OK, help="image observers: square size (px) of the scenario's built-in "
                                                 "camera; frames are resized to it"),
        proposal: Proposal = typer.Option(Proposal(D.PROPOSAL), help=H_PROPOSAL),
        sensor_draws: int = typer.Option(0, "--sensor-draws", callback=checked(D.SENSOR_DRAWS_BOUND),
                                         help="observe each simulation at N more values of the sensor effects' "
                                              "parameters (--effect time-offset, point-noise, ...): N times more "
                                              "training pairs along them at no simulation cost (truncated "
                                              "proposals)"),
        retry_failed: bool = typer.Option(False, "--retry-failed",
                                          help="on resume, simulate the stored failed simulations again (after "
                                               "fixing what made them fail); later rounds are drawn again"),
        refine: int = typer.Option(0, "--refine", callback=checked(D.REFINE_BOUND), help="polish the best fit with N more simulations by CMA-ES, "
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
    from softsbi.cli.progress import ProgressHooks  # start-up: the fit workflow
    from softsbi.plugins import registry  # start-up: loads every plugin
    from softsbi.workflows.fit.bank import check_bank_path  # start-up: numpy, zarr
    from softsbi.workflows.fit.run import FitConfig, run_fit  # start-up: the fit workflow
    from softsbi.workflows.lock import check_out_apart  # start-up: filelock
    from softsbi.workflows.measurement import load_image_recording, load_recording  # start-up: the recording readers
    if no_sim_bank and sim_bank != D.SIM_BANK:
        raise SoftsbiError(f"--sim-bank {sim_bank} and --no-sim-bank contradict each other: give one of them")
    exe_opts: dict[str, Any] = {"retries": retries}
    if sim_timeout is not None:
        exe_opts["timeout"] = sim_timeout
    if ray_address:
        if executor != "ray":
            raise SoftsbiError(f"--ray-address needs --executor ray (got --executor {executor})")
        exe_opts["address"] = ray_address
    cfg = FitConfig(backend=backend, backend_options=parse_kv(backend_opt, "--backend-opt"),
                    effects=names(effect, "--effect"), estimator=estimator,
                    estimator_options=parse_kv(estimator_opt, "--estimator-opt"),
                    rounds=rounds, sims_per_round=sims_per_round, seed=seed, n_points=points, workers=workers,
                    bounds=parse_bounds(bounds), fixed=parse_kv(fix, "--fix"), n_eval=n_eval,
                    min_height=min_height, frames=frames, executor=executor, executor_options=exe_opts,
                    proposal=Proposal(proposal).value, observer=observer, sensor=sensor, sensor_draws=sensor_draws,
                    refine=refine, widen=widen, sim_bank="off" if no_sim_bank else sim_bank)
    images = bool(getattr(registry().observer(observer), "needs_images", False))
    if images:
        if extractor is None:
            raise SoftsbiError(f"--observer {observer} needs --extractor PATH.pt (train one with `softsbi "
                               f"train-extractor {observer} --out PATH.pt`)")
        cfg.observer_options = {"extractor": str(extractor), "size": image_size}
    elif extractor is not None:
        raise SoftsbiError(f"--extractor is for image observers (heatmap, transporter), not '{observer}'")
    cfg.validate()  # fail fast (e.g. --workers 0) before loading the recording
    check_out_apart(out, "fit", run=out, recording=observed)
    check_bank_path(cfg.sim_bank, {"--out": out, "--observed": observed})
    if executor == "ray":
        from softsbi.executors.ray_executor import _import_ray  # start-up: ray is optional
        _import_ray()  # DependencyMissing naming `pip install softsbi[ray]`
    if images:
        meas = load_image_recording(observed, scenario=scenario, size=image_size)
    else:
        meas = load_recording(observed, n_points=points, seed=seed, scenario=scenario)
    o = Output(as_json)
    with o.progress() as p:
        res = run_fit(out, meas, cfg, callbacks=ProgressHooks(o, p), retry_failed=retry_failed)
    rep = res.report.to_json()
    if not json_done(o, dict(rep, run_dir=str(out))):
        print_fit_report(o, rep, out)
