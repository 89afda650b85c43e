"""``softsbi view``: the measured cloud against posterior rollouts, as an animation and a rerun recording."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import H_JSON, H_WORKERS, WORKERS_OK, checked
from softsbi.cli.output import Output
from softsbi.core import defaults as D


def view(run: Path = typer.Argument(..., help="run directory of a finished point-cloud fit"),
         n_eval: int = typer.Option(D.VIEW_N_EVAL, "--n-eval", callback=checked(D.EVAL_BOUND), help="posterior-predictive rollouts drawn (faded) against the "
                                                          "measurement"),
         gif: bool = typer.Option(True, help="write RUN/view.gif: measured vs simulated clouds over time"),
         rrd: Optional[bool] = typer.Option(None, "--rrd/--no-rrd",
                                            help="write RUN/view.rrd for the rerun viewer (`rerun RUN/view.rrd`), "
                                                 "which needs `pip install \"softsbi\\[view]\"`; default: when "
                                                 "it is installed"),
         workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=WORKERS_OK),
         as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """See the measured cloud move against posterior rollouts: an animation and a rerun recording."""
    from softsbi.cli.progress import shown  # start-up: the workflows' progress
    from softsbi.workflows.view import write_view  # start-up: the view workflow
    o = Output(as_json)
    with shown(o):
        res = write_view(run, n_eval=n_eval, workers=workers, gif=gif, rrd=rrd)
    if json_done(o, res):
        return
    for key in ("gif", "rrd"):
        if res[key]:
            o.line(f"wrote {res[key]}" + ("  (open with `rerun " + str(res[key]) + "`)" if key == "rrd" else ""))
    if res["rrd_missing"]:
        o.line('not written: view.rrd (the 3-D rerun recording needs the extra: pip install "softsbi[view]")')
