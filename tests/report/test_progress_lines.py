"""The lines a command prints while it simulates (softsbi.cli.progress: bars on a terminal, one line per phase in a
pipe) and the line a resumed fit begins with (softsbi.workflows.fit.resume.resume_message), driven by hand: counts
given to the progress hooks, a run store written by hand; no fit, no simulation."""
from __future__ import annotations

import io
import re

import numpy as np

from softsbi.core.distributions import gaussian
from softsbi.core.store import RunStore
from softsbi.core.types import STATUS_OK


def _progress(terminal: bool) -> str:
    """What the CLI prints on stderr for round 1 of 2 (20 simulations, all read from the bank) and a phase of 10
    posterior-predictive rollouts of which 7 were read from the bank."""
    from rich.console import Console
    from softsbi.cli.output import Output
    from softsbi.cli.progress import PhaseReporter, ProgressHooks
    from softsbi.workflows.reporting import phase, reporting
    o = Output()
    buf = io.StringIO()
    o.err = Console(file=buf, force_terminal=terminal, width=200, highlight=False, markup=False)
    with o.progress() as p:
        hooks = ProgressHooks(o, p)
        hooks.round_start(0, 2, 20, 20)
        hooks.read_from_bank(0, 20, 20)
        with reporting(PhaseReporter(o, p)), phase("posterior-predictive rollouts", 10) as advance:
            for done in range(1, 11):
                advance(done, min(done, 7))
    return buf.getvalue()


def test_in_a_pipe_each_phase_is_a_line_when_it_begins_and_ends_and_says_what_the_bank_gave():
    """"N of M to run" (simulated or read from the bank), then "N of M read from the bank"; never "to simulate"."""
    assert re.sub(r"done in \d+ s", "done in N s", _progress(False)).splitlines() == [
        "round 1/2 simulations: 20 of 20 to run",
        "round 1/2 simulations: 20 of 20 read from the bank",
        "posterior-predictive rollouts: 10 simulations ...",
        "posterior-predictive rollouts: 7 of 10 read from the bank",
        "posterior-predictive rollouts: done in N s"]


def test_on_a_terminal_the_bars_come_with_the_lines_of_what_the_bank_gave():
    text = _progress(True)
    assert "round 1/2 simulations: 20 of 20 read from the bank\n" in text
    assert "posterior-predictive rollouts: 7 of 10 read from the bank\n" in text
    assert "to simulate" not in text


def _store(tmp_path, failed: int = 0, stored_next: int | None = None) -> RunStore:
    """A run store written by hand: round 1 complete (12 simulations, ``failed`` of them failed), round 2 begun with
    ``stored_next`` of its 12 stored (None: not begun)."""
    s = RunStore.create(tmp_path / "run.zarr", {"backend": "toy-gauss", "seed": 1})
    s.write_observed(np.ones((3, 5, 3)), np.zeros((3, 3)), np.arange(3) * 0.1)
    th = np.random.default_rng(0).random((12, 2))
    s.begin_round(0, th, th, np.arange(12), (3, 5, 3), "prior")
    for i in range(12):
        ok = i >= failed
        s.write_simulation(0, i, np.ones((3, 5, 3)) if ok else None, np.ones(3) if ok else None,
                           STATUS_OK if ok else 1, "" if ok else "diverged")
    s.finish_round(0, gaussian([0.5, 0.5], np.eye(2) * 0.01), {"epochs": 3})
    if stored_next is not None:
        s.begin_round(1, th, th, np.arange(12, 24), (3, 5, 3), "posterior of round 1")
        for i in range(stored_next):
            s.write_simulation(1, i, np.ones((3, 5, 3)), np.ones(3), STATUS_OK)
    return s


def test_a_resumed_fit_names_the_partly_stored_round_the_failed_simulations_and_the_time_spent(tmp_path):
    """Rounds count from one; the partly stored round with what of it is stored; stored failures with the option
    that simulates them again."""
    from softsbi.workflows.fit.resume import resume_message
    s = _store(tmp_path / "a", failed=2, stored_next=4)
    assert resume_message(s, 125.4) == (
        f"resuming run in {s.path} after round 1; round 2: 4 of 12 simulations already stored; 2 stored simulations "
        f"failed (after fixing what made them fail, --retry-failed simulates them again); 125 s spent before")
    s = _store(tmp_path / "b")
    assert resume_message(s, 3.0) == f"resuming run in {s.path} after round 1; 3 s spent before"
