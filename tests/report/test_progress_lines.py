"""The lines a command prints while it simulates (softsbi.cli.progress: bars on a terminal, one line per phase in a
pipe) and the line a resumed fit begins with (softsbi.workflows.fit.resume.resume_message), driven by hand: counts
given to the progress hooks, a run store written by hand; no fit, no simulation."""
from __future__ import annotations

import io
import re

import numpy as np

from softsbi.core.distributions import gaussian
from softsbi.core.store import RoundRecord, RunStore
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


def test_a_round_ends_with_its_counts_the_chamfer_summary_of_its_rollouts_and_its_posterior_mean():
    """The round's summary (``report.json``'s ``per_round`` row before it is cut down) carries the Chamfer summary of
    its rollouts as a ChamferStats; rollouts that were not scored (every field None) add no Chamfer."""
    from rich.console import Console
    from softsbi.cli.output import Output
    from softsbi.cli.progress import ProgressHooks
    from softsbi.workflows.fit.report_file import ChamferStats, chamfer_stats
    o = Output()
    buf = io.StringIO()
    o.err = Console(file=buf, force_terminal=False, width=200, highlight=False, markup=False)
    stats = chamfer_stats(np.array([[0.01, 0.03], [0.02, 0.04], [np.nan, 0.0]]), np.array([STATUS_OK, STATUS_OK, 1]))
    assert (stats.mean_m, stats.n, stats.failed, stats.one_sided_mean_m) == (0.025, 2, 1, None)
    with o.progress() as p:
        hooks = ProgressHooks(o, p)
        for chamfer in (stats, ChamferStats()):
            hooks.round_end(0, {"usable": 2, "failed": 1, "chamfer_proposal": chamfer, "posterior_mean": {"a": 0.5}})
    assert buf.getvalue().splitlines() == [
        "round 1: 2 usable, 1 failed, Chamfer of this round's rollouts 2.50 cm; posterior mean a=0.5",
        "round 1: 2 usable, 1 failed; posterior mean a=0.5"]


def test_a_round_record_reads_a_round_s_attributes_and_the_defaults_of_those_it_lacks(tmp_path):
    """RunStore.round_record: the training info, failures and bank hits of a finished round; a round only begun has
    no info and no bank hits yet."""
    s = _store(tmp_path, failed=2, stored_next=0)
    s.add_bank_hits(0, 3)
    done, begun = s.round_record(0), s.round_record(1)
    assert (done.complete, done.info, done.bank_hits, sorted(done.failures.values())) == (
        True, {"epochs": 3}, 3, ["diverged", "diverged"])
    assert (begun.complete, begun.info, begun.bank_hits, begun.proposal) == (False, {}, 0, "posterior of round 1")


def test_a_round_record_names_the_stored_task_and_the_training_size_of_its_info():
    """RoundRecord.task and .n_train_total: the training info's ``task`` (as text) and ``n_train_total`` (as an
    int); None and 0 for a round whose info lacks them (not finished, or no stored task)."""
    served = RoundRecord(info={"task": "ab12cd", "trained_here": False, "n_train_total": 60.0, "epochs": 3})
    assert (served.task, served.n_train_total) == ("ab12cd", 60) and isinstance(served.n_train_total, int)
    assert (RoundRecord().task, RoundRecord().n_train_total) == (None, 0)
    assert RoundRecord(info={"n_train_total": None}).n_train_total == 0


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
