"""What ``softsbi demo`` shows at each step (:class:`DemoPrinter`); imported when the demo runs, so that
``softsbi --help`` does not load the workflows."""
from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any, Iterator

from softsbi.cli.diagnose_cmd import print_diagnosis
from softsbi.cli.fit_cmd import print_fit_report
from softsbi.cli.output import Output
from softsbi.cli.progress import ProgressHooks, shown
from softsbi.workflows.demo import DemoCallbacks
from softsbi.workflows.fit.run import FitCallbacks


class DemoPrinter(DemoCallbacks):
    """Prints the demo's steps (results on stdout, progress on stderr)."""

    def __init__(self, o: Output):
        self.o = o

    def step(self, title: str) -> None:
        self.o.rule(title)

    def line(self, text: str) -> None:
        self.o.line(text)

    @contextlib.contextmanager
    def fitting(self) -> Iterator[FitCallbacks]:
        with self.o.progress() as p:
            yield ProgressHooks(self.o, p)

    @contextlib.contextmanager
    def working(self, text: str) -> Iterator[None]:
        self.o.message(text)
        with shown(self.o):
            yield

    def fit_done(self, report: dict[str, Any], run_dir: Path) -> None:
        print_fit_report(self.o, report, run_dir)

    def diagnosis_done(self, diagnosis: Any) -> None:
        print_diagnosis(self.o, diagnosis)

    def comparison_done(self, comparison: Any, effect: str) -> None:
        self.o.table(["", "nominal", f"+ {effect}", "change"],
                     [[row.what, f"{row.a * 100:.2f} cm", f"{row.b * 100:.2f} cm", f"{row.change * 100:+.0f}%"]
                      for row in comparison.rows[:4]])
