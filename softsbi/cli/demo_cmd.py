"""``softsbi demo``: the whole real-to-sim story on a built-in case that needs no data files."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import (H_ESTIMATOR, H_JSON, H_PROPOSAL, H_SEED, H_WORKERS, ROUNDS_OK, SEED_OK, SIMS_OK,
                                 WORKERS_OK, Proposal)
from softsbi.cli.output import Output
from softsbi.core import defaults as D


def demo(out: Path = typer.Option(Path("softsbi-demo"), help="output folder"),
         quick: bool = typer.Option(False, "--quick", help="only fit hidden parameters (no hidden effect)"),
         backend: str = typer.Option(D.BACKEND, help="simulator plugin that simulates, fits and diagnoses the demo "
                                                     "(one that applies wind, e.g. newton-cloth; --quick: any)"),
         rounds: int = typer.Option(D.DEMO_ROUNDS, help="sequential rounds per fit", callback=ROUNDS_OK),
         sims_per_round: int = typer.Option(D.DEMO_SIMS, help="simulations per round", callback=SIMS_OK),
         estimator: str = typer.Option(D.ESTIMATOR, help=H_ESTIMATOR),
         seed: int = typer.Option(D.SEED, help=H_SEED, callback=SEED_OK),
         workers: Optional[int] = typer.Option(None, help=H_WORKERS, callback=WORKERS_OK),
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
    from softsbi.cli.demo_printer import DemoPrinter  # start-up: the demo workflow
    from softsbi.workflows.demo import run_demo  # start-up: the demo workflow
    o = Output(as_json)
    doc = run_demo(out, quick=quick, backend=backend, rounds=rounds, sims_per_round=sims_per_round, estimator=estimator,
                   seed=seed, workers=workers, proposal=Proposal(proposal).value, ui=DemoPrinter(o))
    json_done(o, doc)  # the steps were printed as they ran
