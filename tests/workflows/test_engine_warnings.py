"""An engine's warnings never flood the progress lines: MuJoCo's are kept with the rollout instead of being printed
(and written to MUJOCO_LOG.TXT in the user's folder); every batch of simulations (a fit's round, a phase of check,
diagnose, compare or view) says once, at its end, how many simulations failed or warned, and at which parameters the
first few did."""
import pytest

from softsbi.workflows.reporting import Reporter, reporting

pytestmark = pytest.mark.integration

pytest.importorskip("softsbi_toy.plugin", reason="install tests/plugins/softsbi_toy (pip install -e)")
from toy_helpers import toy_measurement  # noqa: E402

KICK = '''
import numpy as np
from softsbi import Effect, Param, ParamSpace, hookimpl


class Kick(Effect):
    """A force that blows the cloth up above half its parameter's range."""
    name = "file-kick"

    def param_space(self):
        return ParamSpace([Param("kick", 0.0, 1.0, "1")])

    def force(self, x, v, t, theta, ctx):
        f = np.zeros_like(x)
        f[:, 2] = 1e16 if theta["kick"] > 0.5 else 0.0
        return f


@hookimpl
def softsbi_effects():
    return [Kick]
'''


def test_the_line_of_a_batch_counts_failed_and_warned_simulations_and_names_the_first_at_their_parameters():
    from softsbi.workflows.reporting import SimulationIssues
    issues = SimulationIssues(["a", "b"], keep=2)
    issues.add([0.1, 0.2], True)
    assert issues.line("round 1") is None  # a clean batch says nothing
    issues.add([0.91, -0.25], False, "diverged at t=0.1 s")
    issues.add({"a": 0.5, "b": 1.0}, True, warning="huge value in QACC")
    issues.add([0.95, 0.0], False, "diverged at t=0.2 s")
    assert (issues.total, issues.failed, issues.warned) == (4, 2, 1)
    assert issues.line("round 1") == ("round 1: of 4 simulations, 2 failed, 1 ran with engine warnings; the first 2 "
                                      "at a=0.91, b=-0.25 (failed: diverged at t=0.1 s); a=0.5, b=1 (warned: huge "
                                      "value in QACC)")


def test_mujoco_warnings_are_kept_with_the_rollout_not_printed(tmp_path, monkeypatch, capfd):
    pytest.importorskip("mujoco")
    from softsbi.core.types import STATUS_DIVERGED
    from softsbi.plugins import registry
    from softsbi.scenarios.builtin import make_scenario
    (tmp_path / "kick.py").write_text(KICK)
    monkeypatch.setenv("SOFTSBI_PLUGINS", str(tmp_path / "kick.py"))
    monkeypatch.chdir(tmp_path)
    registry.cache_clear()
    try:
        reg = registry()
        sim = reg.simulator("mujoco-flex")(grid=5)
        sc = make_scenario("lift", None)
        mid = reg.param_space(sim, sc, ["file-kick"]).midpoint()
        capfd.readouterr()
        ro = sim.simulate(sc, {**mid, "kick": 0.9}, effects=["file-kick"])
        out, err = capfd.readouterr()
    finally:
        registry.cache_clear()
    assert "WARNING" not in out + err and not (tmp_path / "MUJOCO_LOG.TXT").exists(), out + err
    assert ro.status == STATUS_DIVERGED and "QACC" in ro.info.get("engine_warnings", "")  # INFO_ENGINE_WARNINGS


def test_a_fit_round_and_a_phase_say_once_which_simulations_failed_or_warned(tmp_path, monkeypatch):
    from softsbi.workflows.fit.jobs import JobItem, run_jobs
    from softsbi.workflows.fit.run import FitConfig, run_fit
    from softsbi.workflows.fit.runs import load_run
    monkeypatch.setenv("SOFTSBI_TOY_DIVERGE_ABOVE", "0.6")
    monkeypatch.setenv("SOFTSBI_TOY_WARN_ABOVE", "0.2")
    messages = []

    class Recorder(Reporter):
        def message(self, text):
            messages.append(text)

        def __getattr__(self, name):  # the fit's callbacks: every other hook does nothing
            return lambda *a, **k: None

    cfg = FitConfig(backend="toy-gauss", estimator="mdnn", rounds=1, sims_per_round=30, workers=1, n_points=8,
                    n_eval=5, n_dense=32, seed=1, estimator_options={"max_epochs": 5, "hidden": [16]})
    res = run_fit(tmp_path / "run", toy_measurement(), cfg, callbacks=Recorder(), make_plots=False)
    theta = res.store.round_data(0)["theta"]
    failed, warned = int((theta[:, 0] > 0.6).sum()), int(((theta[:, 0] > 0.2) & (theta[:, 0] <= 0.6)).sum())
    assert failed and warned and res.report.per_round[0].failed == failed
    (line,) = [m for m in messages if m.startswith("round 1: of 30 simulations")]
    assert line.startswith(f"round 1: of 30 simulations, {failed} failed, {warned} ran with engine warnings; the "
                           f"first 3 at a=")
    assert "(failed: toy divergence: a = " in line or "(warned: toy warning: a = " in line
    messages.clear()
    ctx = load_run(tmp_path / "run", 5).sim_context()
    items = [JobItem([a, 0.0], 7) for a in (0.1, 0.3, 0.9, 0.0)]
    with reporting(Recorder()):
        run_jobs(ctx, items, workers=1, label="posterior-predictive rollouts")
    assert messages == ["posterior-predictive rollouts: of 4 simulations, 1 failed, 1 ran with engine warnings; the "
                        "first 2 at a=0.3, b=0 (warned: toy warning: a = 0.300 > 0.2); a=0.9, b=0 (failed: toy "
                        "divergence: a = 0.900 > 0.6)"]
