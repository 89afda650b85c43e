"""``softsbi import ...``: convert recordings from other layouts into recording directories."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import H_JSON
from softsbi.cli.output import Output


def diffcloud(src: Path = typer.Argument(..., help="a DiffCloud recording folder (lift_tan, fold_navy2) "
                                                   "or a folder of them (diffcloud_lift, diffcloud_fold)"),
              dst: Path = typer.Argument(..., help="destination: the recording directory, or for a "
                                                   "folder of recordings their parent"),
              scenario: Optional[str] = typer.Option(None, help="scenario name or file of the "
                                                                "recordings (needed for tasks other "
                                                                "than lift, e.g. examples/fold.yaml)"),
              as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Convert DiffCloud recordings (lift, fold) into recording directories (recording.yaml + clouds/)."""
    from softsbi.workflows.measurement import import_diffcloud  # start-up: the recording readers
    written = import_diffcloud(src, dst, scenario)
    o = Output(as_json)
    if json_done(o, {"recordings": [str(p) for p in written]}):
        return
    for p in written:
        o.line(f"wrote {p}")
