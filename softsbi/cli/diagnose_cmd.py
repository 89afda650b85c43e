"""``softsbi diagnose``: is an effect missing from a fit's model, and which."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import H_ALPHA, H_JSON, H_MAX_NULL, H_RECOMPUTE, H_WORKERS, names, setting
from softsbi.cli.output import Output
from softsbi.core.defaults import DiagnoseSettings


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
             confirm: int = setting(DiagnoseSettings, "confirm", "refit the top N named candidates (trained ones by "
                                    "their amortised score, then the screening's) and at most one pair when none "
                                    "explains the misfit alone; 0 = no refit"),
             refit_rounds: Optional[int] = setting(DiagnoseSettings, "refit_rounds",
                                                   "rounds of a refit (default: the run's)"),
             refit_sims: Optional[int] = setting(DiagnoseSettings, "refit_sims",
                                                 "simulations per round of a refit (default: the run's)"),
             k_se: float = setting(DiagnoseSettings, "k_se", "standard errors by which a refit's summary energy score "
                                                             "must fall to count, and within which two refits tie"),
             n_null: int = setting(DiagnoseSettings, "n_null", "posterior-predictive simulations the null starts with"),
             max_null: int = setting(DiagnoseSettings, "max_null", H_MAX_NULL),
             alpha: float = setting(DiagnoseSettings, "alpha", H_ALPHA),
             workers: Optional[int] = setting(DiagnoseSettings, "workers", H_WORKERS),
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
        settings = DiagnoseSettings(confirm=confirm, refit_rounds=refit_rounds, refit_sims=refit_sims, k_se=k_se,
                                    workers=workers, n_null=n_null, max_null=max_null, alpha=alpha)
        out = diagnose_run(run, effects=names(effect) or None, settings=settings, progress=o.message,
                           recompute=recompute, out_dir=out_dir)
    if not json_done(o, to_json(out)):
        print_diagnosis(o, out)
