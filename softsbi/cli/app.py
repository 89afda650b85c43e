"""The ``softsbi`` typer app: every command registered in the order ``--help`` lists them, and :func:`main`, the
console script. Each command lives in its own module (``*_cmd.py``) and imports the workflows only when it runs,
so that ``softsbi --help`` stays fast."""
from __future__ import annotations

import signal

import typer

from softsbi import executors
from softsbi.cli.calibrate_cmd import calibrate
from softsbi.cli.catalog_cmd import params, plugins, scenarios
from softsbi.cli.check_cmd import check, compare
from softsbi.cli.command import guard, terminate
from softsbi.cli.demo_cmd import demo
from softsbi.cli.design_cmd import design
from softsbi.cli.diagnose_cmd import diagnose
from softsbi.cli.extractor_cmd import train_extractor
from softsbi.cli.fit_cmd import fit
from softsbi.cli.import_cmd import diffcloud
from softsbi.cli.simulate_cmd import compare_backends, simulate
from softsbi.cli.task_cmd import task_delete, task_list, task_show, task_train
from softsbi.cli.view_cmd import view

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="softsbi: Bayesian real-to-sim for deformable objects (BayesSim-RKHS).")

app.command("plugins")(guard(plugins))
app.command("params")(guard(params))
app.command("simulate")(guard(simulate))
app.command("fit")(guard(fit))
app.command("demo")(guard(demo))
app.command("check")(guard(check))
app.command("calibrate")(guard(calibrate))
app.command("diagnose")(guard(diagnose))
app.command("design")(guard(design))
app.command("compare")(guard(compare))
app.command("view")(guard(view))
app.command("train-extractor")(guard(train_extractor))
app.command("compare-backends")(guard(compare_backends))
app.command("scenarios")(guard(scenarios))

import_app = typer.Typer(help="Convert recordings from other layouts into recording directories.",
                         no_args_is_help=True)
import_app.command("diffcloud")(guard(diffcloud))
app.add_typer(import_app, name="import")

task_app = typer.Typer(help="Stored tasks: what a task learned from its prior, trained once for all its recordings.",
                       no_args_is_help=True)
task_app.command("train")(guard(task_train))
task_app.command("list")(guard(task_list))
task_app.command("show")(guard(task_show))
task_app.command("delete")(guard(task_delete))
app.add_typer(task_app, name="task")


def main() -> None:
    """Console-script entry point (SIGTERM stops a command as Ctrl-C does: one line, exit code 143). SIGINT stops
    it even when the command was started with SIGINT ignored (a background job of a script inherits that). Even one
    worker runs in a process of its own (:data:`softsbi.executors.ISOLATE_ONE_WORKER`)."""
    signal.signal(signal.SIGTERM, terminate)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    executors.ISOLATE_ONE_WORKER = True  # --workers 1: a crashing simulator fails its simulation, not the command
    app()
