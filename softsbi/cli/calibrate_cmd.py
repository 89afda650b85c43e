"""``softsbi calibrate``: simulation-based calibration of a fit's posterior estimator."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import H_JSON, H_WORKERS, WORKERS_OK, checked
from softsbi.cli.output import Output
from softsbi.core import defaults as D


def print_calibration(o: Output, out: Any) -> None:
    """``calibrate``'s table and one line per diagnostic the verdict reads (``out``: a
    :class:`~softsbi.core.results.fitreport.CalibrationResult`; :mod:`softsbi.report.fit_text` words them)."""
    from softsbi.report.fit_text import calibration_lines, calibration_table  # start-up: numpy, scipy
    t = calibration_table(out)
    o.table(t.columns, t.rows, title=t.title)
    for line in calibration_lines(out):
        o.line(line)


def calibrate(run: Path = typer.Argument(..., help="run directory of a finished fit"),
              n_test: int = typer.Option(D.N_TEST, "--n-test", callback=checked(D.N_TEST_BOUND),
                                         help="fresh test simulations from the run's proposals (stored in the run; a "
                                              "re-run resumes, a larger number adds to them)"),
              n_draws: int = typer.Option(D.N_DRAWS, "--n-draws", help="posterior draws per test simulation",
                                          callback=checked(D.N_DRAWS_BOUND)),
              workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=WORKERS_OK),
              as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Simulation-based calibration of the run's posterior estimator: expected coverage, SBC ranks, TARP."""
    from softsbi.cli.progress import shown  # start-up: the workflows' progress
    from softsbi.workflows.tasks.calibrate import calibrate_run  # start-up: the calibration workflow
    o = Output(as_json)
    with shown(o):
        out = calibrate_run(run, n_test=n_test, n_draws=n_draws, workers=workers, message=o.message)
    if json_done(o, out.to_json()):
        return
    print_calibration(o, out)
    o.line(f"verdict: {out.verdict}")
    o.line(f"wrote {run / 'calibration.json'} and {run / 'calibration.png'}")
