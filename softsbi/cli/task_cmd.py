"""``softsbi task``: train a task once, list, show and delete the stored tasks (:mod:`softsbi.workflows.fit.task_store`)."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import (H_BACKEND, H_ESTIMATOR, H_JSON, H_SEED, H_WORKERS, POINTS_OK, SEED_OK, WORKERS_OK,
                                 bound, checked, names, parse_bounds, parse_kv)
from softsbi.cli.output import Output
from softsbi.core.errors import SoftsbiError
from softsbi.core import defaults as D

H_BANK = "simulation bank holding the stored tasks ('default': the user's cache folder; or a folder)"


def _store(sim_bank: str) -> Any:
    from softsbi.workflows.fit.task_store import task_store_of  # start-up: numpy, zarr
    store = task_store_of(sim_bank)
    if store is None:
        raise SoftsbiError("stored tasks live in the simulation bank, which is off (SOFTSBI_SIM_BANK=off): unset it "
                           "or give --sim-bank DIR")
    for path, what in ((store.path.parent, "the simulation bank"), (store.path, "the stored tasks' folder")):
        if path.exists() and not path.is_dir():
            raise SoftsbiError(f"{path} is a file, not {what}: give --sim-bank the folder the fits and `softsbi task "
                               f"train` store their tasks in")
    return store


def _backend(identity: dict[str, Any]) -> str:
    """The task's backend with its options, e.g. ``newton-cloth (grid=8)`` (two tasks that differ only in them
    are told apart). ``identity``: a stored task's (:func:`~softsbi.workflows.fit.task_store.task_identity`, which
    holds every key an entry of its format has)."""
    opts = ", ".join(f"{k}={v}" for k, v in sorted(identity["backend_options"].items()))
    return f"{identity['backend']}" + (f" ({opts})" if opts else "")


def _row(t: Any) -> list[Any]:
    idy = t.identity  # a damaged entry's: None when it cannot be read
    head = [t.digest[:12], t.model, *(("?", "?") if idy is None else (_backend(idy), idy["scenario"]["name"]))]
    if _damaged(t):
        return [*head, "?", f"DAMAGED, never used: {t.problem}", "`softsbi task delete` removes it"]
    r = t.report
    return [*head, t.n_prior, _no_report(t) if r is None else r.verdict,
            "" if r is None else f"{r.coverage.at_50:.2f} / {r.coverage.at_90:.2f}"]


def _no_report(t: Any) -> str:
    """Why a stored task has no training report: trained by ``task train --n-test 0``, or stored by a fit."""
    return ("trained without a calibration report (--n-test 0)" if t.by_task_train else
            "no training report (stored by a fit)")


def _doc(t: Any) -> dict[str, Any]:
    if _damaged(t):
        return {"key": t.digest, "model": t.model, "path": str(t.path), "identity": t.identity, "damaged": t.problem}
    return {"key": t.digest, "model": t.model, "n_prior": t.n_prior, "path": str(t.path), "identity": t.identity,
            "info": t.info, "report": None if t.report is None else t.report.to_json(), "damaged": None}


def _damaged(t: Any) -> bool:
    from softsbi.workflows.fit.task_store import DamagedTask  # start-up: numpy, zarr
    return isinstance(t, DamagedTask)


def task_train(observed: Path = typer.Option(..., help="a recording of the task (its scenario and sensor settings; "
                                                      "its measurement is not used)"),
               prior_sims: int = typer.Option(D.TASK_PRIOR_SIMS, "--prior-sims", callback=checked(D.PRIOR_SIMS_BOUND),
                                              help="prior simulations each model is trained on"),
               n_test: int = typer.Option(D.N_TEST, "--n-test", callback=checked(D.TASK_N_TEST_BOUND),
                                          help="held-out prior simulations of each model's training report "
                                               "(coverage, SBC, TARP); 0 = no report"),
               check_null: int = typer.Option(D.CHECK_REPLICATES, "--check-null", callback=checked(D.CHECK_NULL_BOUND),
                                              help="replicate recordings of the nominal model, refitted, checked "
                                                   "and screened, that calibrate check's test of every later fit of "
                                                   "it (diagnose's detection) (at least 19; 0 = none, check's p-value "
                                                   "uncalibrated)"),
               refit_null: int = typer.Option(D.REFIT_REPLICATES, "--refit-null", callback=checked(D.REFIT_NULL_BOUND),
                                              help="replicate recordings of each candidate model, refitted and "
                                                   "checked, that calibrate the omnibus test of diagnose's refit of "
                                                   "it (at least 19; 0 = none, the refit's check uncalibrated)"),
               candidates: Optional[str] = typer.Option(None, "--candidates",
                                                        help="comma-separated candidate effects to train beside the "
                                                             "nominal model; default: every one diagnose refits; "
                                                             "'none': the nominal model only"),
               backend: str = typer.Option(D.BACKEND, help=H_BACKEND),
               estimator: str = typer.Option(D.ESTIMATOR, help=H_ESTIMATOR),
               effect: list[str] = typer.Option(None, "--effect", help="effects of the nominal model"),
               bounds: list[str] = typer.Option(None, "--bounds", help="prior bounds name=low:high"),
               fix: list[str] = typer.Option(None, "--fix", help="hold a parameter: name=value"),
               points: int = typer.Option(D.N_POINTS, help="K, points per frame", callback=POINTS_OK),
               min_height: Optional[float] = typer.Option(None, callback=bound(0), help="as fit's --min-height"),
               frames: Optional[str] = typer.Option(None, help="as fit's --frames"),
               seed: int = typer.Option(D.SEED, help=H_SEED, callback=SEED_OK),
               workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=WORKERS_OK),
               retrain: bool = typer.Option(False, "--retrain", help="train even the models already stored"),
               sim_bank: str = typer.Option(D.SIM_BANK, "--sim-bank", help=H_BANK),
               as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Train a task once: amortised posteriors of the nominal model and of each candidate effect, with a training
    report; every later fit, check and diagnose of the task's recordings uses them."""
    if candidates is not None and candidates.strip() != "none" and not candidates.replace(",", " ").strip():
        raise SoftsbiError(f"--candidates '{candidates}' names no effect: give effect names (comma-separated), or "
                           f"'none' for the nominal model only")  # before the imports and the plugins load
    cands = (None if candidates is None else [] if candidates.strip() == "none" else
             names([candidates], "--candidates"))
    prior_bounds, fixed = parse_bounds(bounds), parse_kv(fix, "--fix")
    from softsbi.cli.progress import shown  # start-up: the workflows' progress
    from softsbi.workflows.fit.bank import check_bank_path  # start-up: numpy, zarr
    from softsbi.workflows.fit.run import FitConfig  # start-up: the fit workflow
    from softsbi.workflows.measurement import load_recording  # start-up: the recording readers
    from softsbi.workflows.tasks.training import calibration_advice, train_task  # start-up: the training workflow
    cfg = FitConfig(backend=backend, effects=names(effect, "--effect"), estimator=estimator, seed=seed,
                    n_points=points, workers=workers, bounds=prior_bounds, fixed=fixed,
                    min_height=min_height, frames=frames, sim_bank=sim_bank)
    cfg.validate()
    check_bank_path(cfg.sim_bank, {"--observed": observed})
    meas = load_recording(observed, n_points=points, seed=seed)
    o = Output(as_json)
    with shown(o):
        tasks = train_task(meas, cfg, prior_sims, cands, n_test=n_test, retrain=retrain, check_null=check_null,
                           message=o.message, refit_null=refit_null)
    if json_done(o, [_doc(t) for t in tasks]):
        return
    o.table(["key", "model", "backend", "scenario", "prior sims", "training report", "coverage 50% / 90%"],
            [_row(t) for t in tasks], title=f"stored tasks in {tasks[0].path.parent}")
    advice = calibration_advice(tasks)
    if advice:
        o.line(advice)


def task_list(sim_bank: str = typer.Option(D.SIM_BANK, "--sim-bank", help=H_BANK),
              as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """List the stored tasks."""
    store = _store(sim_bank)
    tasks = store.entries()
    o = Output(as_json)
    if json_done(o, [_doc(t) for t in tasks]):
        return
    if not tasks:
        o.line(f"no stored task in {store.path}: `softsbi task train` trains one, and every fit stores its first round")
        return
    o.table(["key", "model", "backend", "scenario", "prior sims", "training report", "coverage 50% / 90%"],
            [_row(t) for t in tasks], title=f"stored tasks in {store.path}")


def task_show(key: str = typer.Argument(..., help="the task's key (its first characters suffice)"),
              sim_bank: str = typer.Option(D.SIM_BANK, "--sim-bank", help=H_BANK),
              as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Show one stored task: what determines it and its training report."""
    t = _store(sim_bank).find(key)
    if _damaged(t):
        raise SoftsbiError(f"stored task {t.digest[:12]} in {t.path.parent} is damaged ({t.problem}) and is never "
                           f"used; `softsbi task delete {t.digest[:12]}` removes it and `softsbi task train` trains it "
                           f"again")
    o = Output(as_json)
    if json_done(o, _doc(t)):
        return
    idy = t.identity
    o.line(f"task {t.digest}: model {t.model}, backend {_backend(idy)}, scenario "
           f"{idy['scenario']['name']}, estimator {idy['estimator']}, seed {idy['seed']}, softsbi {idy['softsbi']}; "
           f"{t.n_prior} prior simulations")
    r = t.report
    if r is None:
        o.line(f"{_no_report(t)}: fits of the task start their sequential rounds from it; `softsbi task train` "
               f"with --n-test {D.N_TEST} trains it again with its report")
        return
    con = r.contraction
    rows = [[n, "rejects" if rej else "ok", f"{con[n].width_ratio:.2f}", "yes" if con[n].informed else "no"]
            for n, rej in zip(r.parameters, r.sbc.rejects)]
    o.table(["parameter", "SBC ranks", "90% width / prior (median)", "informed"], rows,
            title=f"training report: {r.n_test} held-out prior simulations")
    o.line(f"expected coverage {r.coverage.at_50:.2f} at 50%, {r.coverage.at_90:.2f} at 90%; verdict: {r.verdict}")
    from softsbi.workflows.tasks.training import calibration_advice  # start-up: the training workflow
    advice = calibration_advice([t])
    if advice:
        o.line(advice)


def task_delete(key: str = typer.Argument(..., help="the task's key (its first characters suffice)"),
                sim_bank: str = typer.Option(D.SIM_BANK, "--sim-bank", help=H_BANK)) -> None:
    """Delete one stored task (its simulations stay in the bank)."""
    t = _store(sim_bank).delete(key)
    what = f"damaged: {t.problem}" if _damaged(t) else f"{t.n_prior} prior simulations"
    Output(False).line(f"deleted task {t.digest[:12]} ({t.model}, {what})")
