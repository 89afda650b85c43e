"""Progress of every phase that simulates, told to whoever shows it.

The library reports and never prints: :func:`~softsbi.workflows.fit.jobs.run_jobs` (the posterior-predictive
rollouts, nulls and finite differences of ``check``, ``diagnose``, ``compare``, ``view``) and the rounds of a
fit run without callbacks of their own (a ``diagnose`` refit) tell the current :class:`Reporter`, which the CLI
installs with :func:`reporting` (bars with counts and time left on a terminal, one line per phase in a pipe).
Without one, nothing is shown. The Python API (:mod:`softsbi.workflows.api`) installs a :class:`LineReporter`
(the CLI's plain mode: one line on stderr when a phase begins and one when it ends) unless called with
``progress=False`` or inside another reporter.
"""
from __future__ import annotations

import contextlib
import sys
import time
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Mapping, Sequence, TextIO

#: the reporter of the current command (None: silent)
_CURRENT: ContextVar["Reporter | None"] = ContextVar("softsbi_progress", default=None)


class Reporter:
    """Shows phases. Subclasses override :meth:`start`, :meth:`advance` and :meth:`end` (each does nothing
    here)."""

    def start(self, label: str, total: int) -> Any:
        """A phase of ``total`` simulations begins; returns a handle for :meth:`advance` and :meth:`end`."""

    def advance(self, handle: Any, done: int) -> None:
        """``done`` of the phase's simulations are finished."""

    def end(self, handle: Any) -> None:
        """The phase is over: all its simulations are done."""

    def stopped(self, handle: Any) -> None:
        """The phase was stopped before its end (Ctrl-C, SIGTERM, an error): nothing is told as done."""

    def read_from_bank(self, handle: Any, hits: int, total: int) -> None:
        """``hits`` of the phase's ``total`` simulations were read from the simulation bank (told once, when they
        are all done, and only when ``hits > 0``)."""

    def message(self, text: str) -> None:
        """A notice for the user (e.g. bank entries under another key, :class:`~softsbi.workflows.fit.bank.BankCount`)."""


class FitCallbacks:
    """Progress callbacks of :func:`~softsbi.workflows.fit.run.run_fit` (the CLI draws progress bars with them); every
    method does nothing by default."""

    def round_start(self, r: int, rounds: int, n_pending: int, n_total: int) -> None:
        """Round ``r`` (0-based; -1 = the final posterior-predictive rollouts; -2 = the best fit's refinement,
        ``FitConfig.refine``) begins."""

    def simulation_done(self, r: int, done: int, total: int) -> None:
        """``done`` of ``total`` simulations of round ``r`` are stored."""

    def training_epoch(self, r: int, epoch: int, max_epochs: int, loss: float) -> None:
        """The estimator finished an epoch on round ``r``'s data."""

    def read_from_bank(self, r: int, hits: int, total: int) -> None:
        """``hits`` of the ``total`` simulations of round ``r`` run in this call were read from the simulation bank
        instead of simulated (told once they are all done, only when ``hits > 0``)."""

    def round_end(self, r: int, summary: dict[str, Any]) -> None:
        """Round ``r`` is complete; ``summary`` as in ``report.json``'s ``per_round`` before it is cut down: ``round``,
        ``simulations``, ``usable``, ``failed``, ``bank_hits``, ``train`` (the training information),
        ``mass_in_box``, ``posterior_mean`` and ``chamfer_proposal``, the
        :class:`~softsbi.workflows.fit.report_file.ChamferStats` of the round's rollouts (every field None when the
        fit does not score them)."""

    def message(self, text: str) -> None:
        """A notice for the user (resuming, retries)."""


@dataclass
class SimulationIssues:
    """The simulations of one batch that failed or that the engine warned about (a backend keeps its engine's warnings
    instead of printing them between the progress lines): counted, and the first :attr:`keep` named with their
    parameters, in one line at the batch's end (:meth:`line`).

    Attributes:
        names: the parameters' names, in the order of a parameter vector given to :meth:`add`.
    """

    names: Sequence[str]
    keep: int = 3
    total: int = 0
    failed: int = 0
    warned: int = 0
    examples: list[str] = field(default_factory=list)

    def add(self, theta: Sequence[float] | Mapping[str, float], ok: bool, reason: str = "", warning: str = "") -> None:
        """Count one simulation at ``theta`` (physical units): ``ok`` or failed for ``reason``; ``warning``: its
        engine's warnings (``""``: none)."""
        self.total += 1
        if ok and not warning:
            return
        self.failed += not ok
        self.warned += ok
        if len(self.examples) < self.keep:
            values = theta.items() if isinstance(theta, Mapping) else zip(self.names, theta)
            at = ", ".join(f"{k}={float(v):.4g}" for k, v in values)
            self.examples.append(f"{at} ({'failed: ' + reason if not ok else 'warned: ' + warning})")

    def line(self, label: str) -> str | None:
        """``"<label>: 2 of 40 simulations failed, 3 ran with engine warnings; the first at a=0.1, b=2 (failed:
        ...); ..."``, or None when every simulation ran clean."""
        if not (self.failed or self.warned):
            return None
        what = [f"{self.failed} failed"] * bool(self.failed) + [f"{self.warned} ran with engine warnings"] * bool(
            self.warned)
        first = "the first" if len(self.examples) == 1 else f"the first {len(self.examples)}"
        return f"{label}: of {self.total} simulations, {', '.join(what)}; {first} at {'; '.join(self.examples)}"


def say(text: str, stream: TextIO | None = None) -> None:
    """One progress line on ``stream`` (default: ``sys.stderr`` at the time of writing)."""
    print(text, file=stream or sys.stderr, flush=True)


class LineReporter(Reporter):
    """One line when a phase begins (``"fit: round 1/4: 150 simulations ..."``) and one when it ends (``"...: done
    in 12 s"``) on ``stream`` (default: ``sys.stderr`` at the time of writing): the CLI's plain mode."""

    def __init__(self, stream: TextIO | None = None):
        self.stream = stream

    def start(self, label: str, total: int) -> Any:
        say(f"{label}: {total} simulations ...", self.stream)
        return label, time.perf_counter()

    def end(self, handle: Any) -> None:
        label, t0 = handle
        say(f"{label}: done in {time.perf_counter() - t0:.0f} s", self.stream)


@contextlib.contextmanager
def shown_unless_shown(progress: bool = True) -> Iterator[None]:
    """Inside the block, phases are shown one line each on stderr (:class:`LineReporter`) when ``progress`` is
    True and no reporter is current yet (a caller that shows progress its own way keeps it)."""
    if not progress or _CURRENT.get() is not None:
        yield
        return
    with reporting(LineReporter()):
        yield


@contextlib.contextmanager
def reporting(reporter: Reporter | None) -> Iterator[None]:
    """Make ``reporter`` the current one inside the block."""
    token = _CURRENT.set(reporter)
    try:
        yield
    finally:
        _CURRENT.reset(token)


def notify(text: str) -> None:
    """Tell the current reporter a notice (nothing without one)."""
    rep = _CURRENT.get()
    if rep is not None:
        rep.message(text)


@contextlib.contextmanager
def phase(label: str, total: int) -> Iterator[Callable[..., None]]:
    """A phase of ``total`` simulations, told to the current reporter; yields ``advance(done, hits=0)``
    (``hits`` of the ``done`` were read from the simulation bank: told with :meth:`Reporter.read_from_bank`
    once all ``total`` are done)."""
    rep = _CURRENT.get()
    if rep is None or total <= 0:
        yield lambda done, hits=0: None
        return
    handle = rep.start(label, total)

    def advance(done: int, hits: int = 0) -> None:
        rep.advance(handle, done)
        if done == total and hits:
            rep.read_from_bank(handle, hits, total)

    try:
        yield advance
    except BaseException:
        rep.stopped(handle)
        raise
    rep.end(handle)


def fit_callbacks(label: str) -> Any:
    """:class:`FitCallbacks` that tell the current reporter each round's simulations (a fit
    run inside another command, e.g. a ``diagnose`` refit, labelled ``label``); None without a reporter."""
    rep = _CURRENT.get()
    if rep is None:
        return None

    class _Rounds(FitCallbacks):
        handle: Any = None

        def round_start(self, r: int, rounds: int, n_pending: int, n_total: int) -> None:
            if self.handle is not None:
                rep.end(self.handle)
            what = f"round {r + 1}/{rounds}" if r >= 0 else "posterior rollouts" if r == -1 else "refinement"
            self.handle = rep.start(f"{label}: {what}", n_total)
            rep.advance(self.handle, n_total - n_pending)

        def simulation_done(self, r: int, done: int, total: int) -> None:
            rep.advance(self.handle, done)

        def read_from_bank(self, r: int, hits: int, total: int) -> None:
            rep.read_from_bank(self.handle, hits, total)

        def message(self, text: str) -> None:
            rep.message(text)

        def round_end(self, r: int, s: dict[str, Any]) -> None:
            if self.handle is not None:
                rep.end(self.handle)
                self.handle = None

    return _Rounds()


def duration_words(seconds: float) -> str:
    """A duration for people, two significant digits at most: ``"40 s"``, ``"12 min"``, ``"2.5 h"``."""
    s = max(float(seconds), 0.0)
    if s < 90:
        return f"{s:.2g} s" if s < 10 else f"{s:.0f} s"
    if s < 90 * 60:
        return f"{s / 60:.0f} min"
    return f"{s / 3600:.2g} h"
