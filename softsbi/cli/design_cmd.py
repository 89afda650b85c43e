"""``softsbi design``: which motion to record next, so that the candidates a diagnosis left undecided can be
decided."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import H_JSON, H_RECOMPUTE, H_WORKERS, WORKERS_OK, names
from softsbi.cli.output import Output


def design(run: Path = typer.Argument(..., help="run directory of a finished fit (its diagnosis.json, if any, says "
                                        "which candidates are undecided)"),
           scenario: list[str] = typer.Option(None, "--scenario", help="a further motion to weigh (a scenario name "
                                              "or file; repeat it), beside the built-in ones the simulator runs"),
           effect: list[str] = typer.Option(None, "--effect", help="candidates to weigh instead of the undecided "
                                            "ones (repeat it)"),
           out: Optional[Path] = typer.Option(None, help="folder of design.json (default: the run directory)"),
           workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=WORKERS_OK),
           recompute: bool = typer.Option(False, "--recompute", help=H_RECOMPUTE),
           as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """The motion to record next: each motion's predicted posterior width of the undecided candidates."""
    from softsbi.cli.progress import shown  # start-up: the workflows' progress
    from softsbi.core.results import to_json  # start-up: numpy
    from softsbi.report.design_text import design_columns, design_rows, design_text  # start-up: numpy
    from softsbi.workflows.criticism.design import design_run  # start-up: the criticism workflows
    effects = names(effect, "--effect") or None  # an empty name refused before anything is read
    o = Output(as_json)
    with shown(o):
        d = design_run(run, scenario or (), effects, workers=workers, out_dir=out, recompute=recompute,
                       progress=o.message)
    if json_done(o, to_json(d)):
        return
    if d.undecided:
        o.table(design_columns(d), design_rows(d),
                title="Predicted 90% interval width over the prior's after one recording of each motion")
    for paragraph in design_text(d):
        o.line(paragraph)
