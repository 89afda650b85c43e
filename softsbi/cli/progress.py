"""What the long-running commands show while they work: progress bars of the fit and of every phase that
simulates (imported by the commands that need them, so ``softsbi --help`` does not load the workflows)."""
from __future__ import annotations

import contextlib
import time
from typing import Any, Iterator

from softsbi.cli.output import Output
from softsbi.workflows.fit.run import FitCallbacks
from softsbi.workflows.reporting import Reporter, reporting


class PhaseReporter(Reporter):
    """Every phase that simulates on stderr: a bar with counts and time left on a terminal, one line when it begins
    and one when it ends in a pipe."""

    def __init__(self, o: Output, progress: Any):
        self.o, self.p = o, progress

    def start(self, label: str, total: int) -> Any:
        if not self.o.err.is_terminal:
            self.o.message(f"{label}: {total} simulations ...")
        return self.p.add_task(label, total=total), label, time.perf_counter()

    def advance(self, handle: Any, done: int) -> None:
        self.p.update(handle[0], completed=done)

    def end(self, handle: Any) -> None:
        task, label, t0 = handle
        self.p.remove_task(task)
        if not self.o.err.is_terminal:
            self.o.message(f"{label}: done in {time.perf_counter() - t0:.0f} s")

    def stopped(self, handle: Any) -> None:
        self.p.remove_task(handle[0])

    def read_from_bank(self, handle: Any, hits: int, total: int) -> None:
        self.o.message(f"{handle[1]}: {hits} of {total} read from the bank")

    def message(self, text: str) -> None:
        self.o.message(text, style="yellow")


@contextlib.contextmanager
def shown(o: Output) -> Iterator[None]:
    """Show every simulating phase of the command run inside the block (:class:`PhaseReporter`)."""
    with o.progress() as p, reporting(PhaseReporter(o, p)):
        yield


class ProgressHooks(FitCallbacks):
    """Progress of :func:`softsbi.workflows.fit.run.run_fit` on stderr: bars on a terminal, one line per
    round otherwise."""

    def __init__(self, o: Output, progress: Any):
        self.o, self.p = o, progress
        self.sim_task = None
        self.train_task = None
        self.label = ""

    def round_start(self, r: int, rounds: int, n_pending: int, n_total: int) -> None:
        self.label = label = (f"round {r + 1}/{rounds} simulations" if r >= 0 else
                              "posterior rollouts" if r == -1 else "refinement of the best fit (CMA-ES)")
        if self.sim_task is not None:
            self.p.remove_task(self.sim_task)
        self.sim_task = self.p.add_task(label, total=n_total, completed=n_total - n_pending)
        if not self.o.err.is_terminal:  # to run: simulated, or read from the simulation bank (read_from_bank)
            self.o.message(f"{label}: {n_pending} of {n_total} to run")

    def read_from_bank(self, r: int, hits: int, total: int) -> None:
        self.o.message(f"{self.label}: {hits} of {total} read from the bank")

    def simulation_done(self, r: int, done: int, total: int) -> None:
        self.p.update(self.sim_task, completed=done)

    def training_epoch(self, r: int, epoch: int, max_epochs: int, loss: float) -> None:
        if self.train_task is None:
            self.train_task = self.p.add_task(f"round {r + 1} training", total=max_epochs)
        self.p.update(self.train_task, completed=epoch, description=f"round {r + 1} training (loss {loss:.3f})")

    def round_end(self, r: int, s: dict[str, Any]) -> None:
        if self.train_task is not None:
            self.p.remove_task(self.train_task)
            self.train_task = None
        mean_m = s["chamfer_proposal"].mean_m  # ChamferStats of the round's rollouts (None when not scored)
        ch_txt = f", Chamfer of this round's rollouts {mean_m * 100:.2f} cm" if mean_m else ""
        mean = ", ".join(f"{k}={v:.3g}" for k, v in s["posterior_mean"].items())
        self.o.message(f"round {r + 1}: {s['usable']} usable, {s['failed']} failed{ch_txt}; posterior mean {mean}")

    def message(self, text: str) -> None:
        self.o.message(text, style="yellow")
