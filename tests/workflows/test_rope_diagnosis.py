"""A user's rope task with an effect of their own: a rope dragged along +x then -y past a block, a peg on the drag
line snagging it (``snag_effect.py``). The default candidate family leaves out the cloth-only effects (an
anisotropic membrane cannot act on a rope) instead of letting one candidate's refusal stop the screening of all, so
both of check's tests run, the snag is detected on one recording and the control stays clean."""
from __future__ import annotations

from pathlib import Path

import pytest

from softsbi.core.defaults import DiagnoseSettings
from softsbi.workflows.criticism.diagnose import diagnose_run
from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording

pytestmark = pytest.mark.integration

#: the user's rope task, a scenario file (the rope figures' tests read it too)
ROPE_DRAG = Path(__file__).with_name("rope_drag.yaml")
TRUTH = {"young": 1e6, "friction": 0.5, "scale": 0.3, "mass": 0.03}


@pytest.fixture(scope="module", autouse=True)
def snag_plugin():
    """The user's snag effect loaded by path, as a user's own effect file is (``SOFTSBI_PLUGINS``)."""
    from softsbi.plugins.manager import registry
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SOFTSBI_PLUGINS", str(Path(__file__).with_name("snag_effect.py")))
        registry.cache_clear()
        yield
    registry.cache_clear()


@pytest.fixture(scope="module")
def rope_fits(tmp_path_factory):
    """``rope_fits(name) -> run``: the nominal fit (one round of 80) of the rope drag with the snag hidden at 6 N/m
    (``snag``) or without it (``control``), fitted when first asked for."""
    root = tmp_path_factory.mktemp("rope")
    cfg = FitConfig(rounds=1, sims_per_round=80, workers=2, n_eval=30)
    hidden = {"snag": ({"snag_k": 6.0}, ["snag"]), "control": ({}, [])}
    runs = {}

    def fitted(name):
        if name not in runs:
            extra, effects = hidden[name]
            rec = simulate_recording("mujoco-flex", str(ROPE_DRAG), {**TRUTH, **extra}, effects=effects, seed=3)
            run_fit(root / name, rec, cfg, make_plots=False)
            runs[name] = root / name
        return runs[name]
    return fitted


def test_a_rope_task_screens_every_candidate_that_can_act_on_a_rope_runs_both_tests_and_detects_a_snag(
        rope_fits, capsys):
    said: list[str] = []
    d = diagnose_run(rope_fits("snag"), plots=False, progress=said.append,
                     settings=DiagnoseSettings(confirm=0, workers=2))
    assert "aniso-stretch" not in d.candidates and "snag" in d.candidates
    assert any("left out of the candidates: aniso-stretch (cannot act on a rope)" in s for s in said)
    assert all(c.screened for c in d.ranking), [(c.effect, c.error) for c in d.ranking if not c.screened]
    assert d.test.directional is not None and d.test.directional_skipped is None  # both tests ran
    assert d.test.misspecified and d.ranking[0].effect == "snag"  # detected, and the screening points at the snag


@pytest.mark.slow
def test_the_rope_control_stays_clean(rope_fits):
    d = diagnose_run(rope_fits("control"), plots=False, settings=DiagnoseSettings(confirm=0, workers=2))
    assert d.test.directional is not None
    assert d.decision.verdict == "nothing-missing", d.test
