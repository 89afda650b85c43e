"""``softsbi diagnose``: is an effect missing from a fit's model, and which."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import (ALPHA_OK, AT_LEAST_1_WORKER, H_ALPHA, H_JSON, H_MAX_NULL, H_RECOMPUTE, H_WORKERS,
                                 MAX_NULL_OK, N_NULL_OK, bound, names)
from softsbi.cli.output import Output
from softsbi.core.levels import ALPHA
from softsbi.workflows import defaults as D


def print_diagnosis(o: Output, diagnosis: Any) -> None:
    """A :class:`~softsbi.core.results.Diagnosis` as its candidates' table, its verdict and its paragraphs on
    stdout (:mod:`softsbi.report.text` words them)."""
    from softsbi.report.text import diagnosis_columns, diagnosis_rows, diagnosis_text  # start-up: numpy, scipy
    o.table(diagnosis_columns(diagnosis), diagnosis_rows(diagnosis),
            title="Candidate effects, by the screening's evidence")
    o.line(f"verdict: {diagnosis.verdict}")
    for paragraph in diagnosis_text(diagnosis):
        o.line(paragraph)


def diagnose(run: Path = typer.Argument(..., help="run directory of a finished fit (nominal model)"),
             effect: list[str] = typer.Option(None, "--effect", help="candidate effects (default: all installed)"),
             confirm: int = typer.Option(D.CONFIRM, callback=bound(0, "0 = no refit"), help="refit the top N named candidates (trained ones by their "
                                                          "amortised score, then the screening's) and at most one "
                                                          "pair when none explains the misfit alone; 0 = no refit"),
             refit_rounds: Optional[int] = typer.Option(None, help="rounds of a refit (default: the run's)",
                                                        callback=bound(1, "leave it out for the run's own")),
             refit_sims: Optional[int] = typer.Option(None, help="simulations per round of a refit "
                                                                 "(default: the run's)",
                                                      callback=bound(D.MIN_SIMS_PER_ROUND, "the estimator needs "
                                                                      "data; leave it out for the run's own")),
             k_se: float = typer.Option(D.K_SE, "--k-se", callback=bound(0, strict=True), help="standard errors by which a refit's summary energy score "
                                                               "must fall to count, and within which two refits tie"),
             n_null: int = typer.Option(D.N_NULL, "--n-null", callback=N_NULL_OK, help="posterior-predictive simulations the null "
                                                                   "starts with"),
             max_null: int = typer.Option(D.MAX_NULL, "--max-null", callback=MAX_NULL_OK, help=H_MAX_NULL),
             alpha: float = typer.Option(ALPHA, help=H_ALPHA, callback=ALPHA_OK),
             workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=AT_LEAST_1_WORKER),
             recompute: bool = typer.Option(False, "--recompute", help=H_RECOMPUTE),
             out_dir: Optional[Path] = typer.Option(None, "--out", help="output folder of diagnosis.json, the check and "
                                                    "the refits (default: RUN), to keep two diagnoses of one run "
                                                    "apart; RUN is then not written"),
             as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Is an effect missing, and which? Detect (check's test), propose (the screening ranks the candidates and the
    top ones are refitted), decide (a refit explains the misfit when check accepts it and its summary energy score
    falls)."""
    from softsbi.cli.progress import shown  # start-up: the workflows' progress
    from softsbi.core.results import to_json  # start-up: numpy
    from softsbi.workflows.criticism.diagnose import diagnose_run  # start-up: the diagnosis workflow
    o = Output(as_json)
    with shown(o):
        out = diagnose_run(run, effects=names(effect) or None, confirm=confirm, refit_rounds=refit_rounds,
                           refit_sims=refit_sims, k_se=k_se, workers=workers, n_null=n_null, max_null=max_null,
                           alpha=alpha, progress=o.message, recompute=recompute, out_dir=out_dir)
    if not json_done(o, to_json(out)):
        print_diagnosis(o, out)
