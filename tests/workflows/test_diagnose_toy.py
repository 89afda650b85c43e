"""The whole diagnosis on a toy-sized case (the toy plugin, tests/plugins/softsbi_toy): a third-party effect is
named when it is a candidate, and without it the verdict is the third one, not a pair of flexible candidates."""
from __future__ import annotations

import json

import pytest

from softsbi.core.results import Diagnosis, from_json
from softsbi.workflows.criticism.diagnose import diagnose_run, load_diagnosis
from softsbi.workflows.fit.run import FitConfig, run_fit
from softsbi.workflows.measurement import simulate_recording
from softsbi.core.defaults import DiagnoseSettings

pytestmark = pytest.mark.integration

#: flexible candidates (linear in time along x, y, z) and the third-party effect (a hump in time along z)
FLEXIBLE = ["toy-wind", "toy-drift", "toy-rise"]
MAGNET = "toy-magnet"


@pytest.fixture(scope="module", autouse=True)
def shifts():
    """The toy shifts loaded as an effect file is tried (``SOFTSBI_PLUGINS``), for this module only."""
    from softsbi.plugins.manager import registry
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SOFTSBI_PLUGINS", "softsbi_toy.shifts")
        registry.cache_clear()
        yield
    registry.cache_clear()


@pytest.fixture(scope="module")
def magnet_run(tmp_path_factory):
    """A nominal fit of a toy measurement with a hidden magnet (pull 0.45 m at mid-motion; 8 frames with 2 cm of noise
    each, so that the hump is told from a line)."""
    toy = pytest.importorskip("softsbi_toy.plugin")
    rec = simulate_recording("toy-gauss", toy.toy_scenario(8), {"a": 0.3, "b": -0.4, "pull": 0.45}, effects=[MAGNET],
                             n_points=16, n_dense=64, seed=5, backend_options={"sigma": 0.02})
    cfg = FitConfig(backend="toy-gauss", backend_options={"sigma": 0.02}, rounds=2, sims_per_round=80, workers=1, n_points=16, n_dense=64, n_eval=30,
                    estimator_options={"max_epochs": 60, "hidden": [64, 64]})
    out = tmp_path_factory.mktemp("magnet") / "nominal"
    run_fit(out, rec, cfg, make_plots=False)
    return out


def test_an_installed_third_party_effect_is_named_when_hidden(magnet_run):
    d = diagnose_run(magnet_run, effects=FLEXIBLE + [MAGNET], plots=False, settings=DiagnoseSettings(workers=1))
    assert d.test.misspecified
    assert d.verdict == "missing-effect" and d.decision.named == (MAGNET,)
    named = d.refit((MAGNET,))
    assert named.adequate and named.score.value < d.nominal.value
    assert not named.amortised and named.rounds == 2  # no trained task: the refit runs the nominal fit's rounds
    # the data switch the named effect on: its parameter's 90% interval excludes the effect's off value
    assert named.maybe_off == () and [e.may_be_off for e in named.estimates if e.effect == MAGNET] == [False]
    # the same candidate family in every step: each refit's test screens the family less its own effects
    assert set(named.test.family) == set(FLEXIBLE)
    # the stored result is the returned one, and a second call with the same settings reads it back
    stored = from_json(Diagnosis, json.loads((magnet_run / "diagnosis.json").read_text()))
    assert stored == d and load_diagnosis(magnet_run) == d
    assert diagnose_run(magnet_run, effects=FLEXIBLE + [MAGNET], plots=False, settings=DiagnoseSettings(workers=1)) == d
    # a refit budget given as the run's own (2 x 80) is the default's: the stored result is read back, not recomputed
    assert (
        diagnose_run(
            magnet_run, effects=FLEXIBLE + [MAGNET], settings=DiagnoseSettings(workers=1, refit_rounds=2, refit_sims=80)
        )
        == d
    )


@pytest.mark.slow
def test_left_out_the_verdict_is_unexplained_not_a_pair_of_flexible_candidates(magnet_run):
    d = diagnose_run(magnet_run, effects=FLEXIBLE, plots=False, settings=DiagnoseSettings(workers=1))
    assert d.test.misspecified and set(d.test.family) == set(FLEXIBLE)
    assert d.verdict == "misspecified-unexplained" and d.decision.named == ()
    assert all(MAGNET not in r.effects for r in d.refits)
    # a flexible candidate explains a part; the pair built on it is refitted and explains no more
    assert d.decision.partial and any(len(r.effects) == 2 for r in d.refits)
    # the pair starts in the box of its first effect's single refit's posterior, not at the prior
    from softsbi.workflows.fit.runs import load_run
    pair = next(r for r in d.refits if len(r.effects) == 2)
    box = load_run(pair.run).config.start_box
    assert set(load_run(d.refit(pair.effects[:1]).run).space.names) <= set(box)
    assert d.residual is not None and d.residual.frames_flagged


def test_a_failing_plugin_effect_as_the_only_candidate_stays_in_the_table_with_its_reason(magnet_run, monkeypatch):
    """A candidate whose code fails disappeared from the candidate table (the screening's error dropped every row);
    now it is listed, not screened, with the reason, and the verdict rests on the omnibus test."""
    import os
    from pathlib import Path
    from softsbi.plugins.manager import registry
    from softsbi.report.text import diagnosis_rows
    monkeypatch.setenv("SOFTSBI_PLUGINS", os.pathsep.join([os.environ["SOFTSBI_PLUGINS"],
                                                          str(Path(__file__).with_name("broken_effect.py"))]))
    registry.cache_clear()
    try:
        d = diagnose_run(
            magnet_run, effects=["toy-broken"], plots=False, settings=DiagnoseSettings(confirm=0, workers=1)
        )
    finally:
        monkeypatch.undo()
        registry.cache_clear()
    (c,) = d.ranking
    assert c.effect == "toy-broken" and not c.screened
    assert "observe()" in c.error and "Rollout" in c.error  # the plugin hook and the type it must return
    assert diagnosis_rows(d)[0][0] == "toy-broken" and "toy-broken" in diagnosis_rows(d)[0][3]


def test_one_failing_candidate_s_refusal_never_reaches_another_candidate_s_row(magnet_run, monkeypatch):
    """A candidate whose simulations raise (a plugin's observe() of the wrong shape; on a rope, a cloth-only model
    edit) stopped the screening of every candidate, each row then carrying its refusal, and the directional test
    did not run. Now its own row carries it; the others are screened and both tests run."""
    import os
    from pathlib import Path
    from softsbi.plugins.manager import registry
    monkeypatch.setenv("SOFTSBI_PLUGINS", os.pathsep.join([os.environ["SOFTSBI_PLUGINS"],
                                                          str(Path(__file__).with_name("broken_effect.py"))]))
    registry.cache_clear()
    try:
        d = diagnose_run(magnet_run, effects=["toy-broken", MAGNET], plots=False, recompute=True,
                         out_dir=magnet_run.parent / "one-broken", settings=DiagnoseSettings(confirm=0, workers=1))
    finally:
        monkeypatch.undo()
        registry.cache_clear()
    rows = {c.effect: c for c in d.ranking}
    assert not rows["toy-broken"].screened and "observe()" in rows["toy-broken"].error
    assert rows[MAGNET].screened and rows[MAGNET].error is None
    assert d.test.directional is not None and d.test.directional_effect == MAGNET


@pytest.mark.slow
def test_on_a_task_trained_with_its_candidates_each_amortised_refit_is_scored_and_the_best_refitted_first(
        tmp_path, monkeypatch):
    """The task trained once with its candidate models: the diagnosis scores every trained candidate's amortised
    posterior predictive (no training, no screening in between) and spends its one refit on the lowest score. The
    magnet pulls 0.45 of its 0.5 range: at 0.3 this small task's posterior (120 simulations) leaves 0.0055 of its mass
    next to the pull 0 that switches it off, a Savage-Dickey ratio of 0.11, not quite excluding it."""
    from softsbi.workflows.criticism.decide import gain
    from softsbi.workflows.tasks.training import train_task
    toy = pytest.importorskip("softsbi_toy.plugin")
    monkeypatch.setenv("SOFTSBI_SIM_BANK", str(tmp_path / "bank"))
    rec = simulate_recording("toy-gauss", toy.toy_scenario(8), {"a": 0.3, "b": -0.4, "pull": 0.45}, effects=[MAGNET],
                             n_points=16, n_dense=64, seed=5, backend_options={"sigma": 0.02})
    cfg = FitConfig(backend="toy-gauss", backend_options={"sigma": 0.02}, sims_per_round=80, workers=1, n_points=16,
                    n_dense=64, n_eval=30, estimator_options={"max_epochs": 60, "hidden": [64, 64]})
    tasks = train_task(rec, cfg, 120, candidates=["toy-drift", MAGNET], n_test=20, n_draws=50, check_null=0,
                       refit_null=0)
    assert [t.model for t in tasks] == ["nominal", "nominal+toy-drift", f"nominal+{MAGNET}"]
    run_fit(tmp_path / "nominal", rec, cfg, make_plots=False)  # stops at the trained task: one round
    d = diagnose_run(
        tmp_path / "nominal",
        effects=["toy-drift", MAGNET],
        plots=False,
        settings=DiagnoseSettings(confirm=1, workers=1),
    )
    assert d.test.misspecified
    scores = {c.effect: c.amortised for c in d.ranking}
    # the race: the magnet, refitted, is scored on the full 30 rollouts; the drift, decided on the race's first 10
    assert scores[MAGNET].n == 30 and scores["toy-drift"].n == 10
    assert gain(d.nominal, scores[MAGNET]).z > d.k_se and scores[MAGNET].value < scores["toy-drift"].value
    # the one refit goes to the lowest amortised score; on the trained task the refit is that amortised posterior
    # (its score the same rollouts'), and its check confirms it
    assert [r.effects for r in d.refits] == [(MAGNET,)]
    assert d.verdict == "missing-effect" and d.decision.named == (MAGNET,)
    assert d.refits[0].amortised and d.refits[0].score == scores[MAGNET]
    # the stored diagnosis is keyed by the trained candidates' tasks (training one more diagnoses again), and read back
    assert d.key["trained"] == sorted(t.digest for t in tasks[1:])
    assert (
        diagnose_run(
            tmp_path / "nominal",
            effects=["toy-drift", MAGNET],
            plots=False,
            settings=DiagnoseSettings(confirm=1, workers=1),
        )
        == d
    )


def test_a_pair_starts_in_the_box_of_its_singles_posteriors(magnet_run, tmp_path):
    """A pair refit's first round draws from the prior restricted to the box of its singles' posteriors (a truncated
    proposal), not from the whole prior at a single's budget: the box holds the single's 90% intervals, lies in the
    prior, and a fit given it draws its first round inside it."""
    from types import SimpleNamespace
    from dataclasses import replace as dc_replace
    from softsbi.core.errors import SoftsbiError
    from softsbi.core.store import RunStore
    from softsbi.workflows.criticism.evidence import recording_from_run, start_box
    from softsbi.workflows.fit.runs import load_run
    view = load_run(magnet_run)
    box = start_box([SimpleNamespace(run=str(magnet_run))])
    assert set(box) <= set(view.space.names) and box
    for name, (lo, hi) in box.items():
        p = view.space[name]
        q05, q95 = view.posterior().interval(0.9)[name]
        assert p.low <= lo <= q05 <= q95 <= hi <= p.high
    assert start_box([]) == {}
    # a fit given a box (here one parameter's 90% interval: this toy's posterior is wide) draws its first round in it
    names = view.space.names
    box = {names[0]: list(view.posterior().interval(0.9)[names[0]])}
    cfg = dc_replace(view.config, rounds=1, sims_per_round=40, n_eval=10, proposal="truncated", start_box=box,
                     workers=1)
    out = tmp_path / "boxed"
    run_fit(out, recording_from_run(view), cfg, make_plots=False)
    store = RunStore.open(out / "run.zarr")
    theta = store.round_data(0, ("theta",))["theta"]
    for name, (lo, hi) in box.items():
        j = names.index(name)
        assert (theta[:, j] >= lo - 1e-9).all() and (theta[:, j] <= hi + 1e-9).all()
    assert "start box" in str(store.round_attrs(0))
    assert theta[:, 1].min() < -0.8 and theta[:, 1].max() > 0.8  # a parameter not named keeps its prior range
    with pytest.raises(SoftsbiError, match="truncated proposals"):
        dc_replace(cfg, proposal="corrected").validate()
    with pytest.raises(SoftsbiError, match="low < high"):
        dc_replace(cfg, start_box={names[0]: [1.0, 0.0]}).validate()



def test_a_rig_names_the_effect_its_second_motion_informs_and_its_first_does_not(magnet_run, tmp_path):
    """A rig of two motions of one toy patch with one hidden magnet: a two-frame motion, which the magnet (a lift
    mid-motion, zero at both ends) cannot move, and the eight-frame one of ``magnet_run``. The first motion's
    diagnosis finds nothing; across the rig the magnet is named, its gain summed over the motion that informs it."""
    import numpy as np
    from softsbi.core.types import Scenario
    from softsbi.workflows.criticism.joint import diagnose_runs
    from softsbi_toy.plugin import toy_scenario
    from softsbi.workflows.fit.runs import load_run
    short = Scenario(name="lift", times=np.arange(2) * 0.1, gripper=np.zeros((2, 3)), table_z=0.0,
                     object={"kind": "patch"})
    rec = simulate_recording("toy-gauss", short, {"a": 0.3, "b": -0.4, "pull": 0.45}, effects=[MAGNET], n_points=16,
                             n_dense=64, seed=6, backend_options={"sigma": 0.02})
    first = tmp_path / "short"
    run_fit(first, rec, load_run(magnet_run).config, make_plots=False)
    j = diagnose_runs([first, magnet_run], effects=FLEXIBLE + [MAGNET], settings=DiagnoseSettings(workers=1),
                      out_dir=tmp_path / "rig", plots=False)
    assert j.rig and j.scenarios == ("lift", "toy")
    assert j.recordings[0].verdict == "nothing-missing" and j.recordings[1].decision.named == (MAGNET,)
    magnet = j.candidate(MAGNET)
    assert magnet.informs == (False, True) and magnet.fails(j.k_se) == ()
    assert j.verdict == "missing-effect" and j.decision.named == (MAGNET,)
    (pull,) = magnet.combined
    assert pull.name == "pull" and pull.q05 < 0.45 < pull.q95 and pull.q95 - pull.q05 < 0.4
    # the motion to record next, from the first motion's fit: the eight-frame one informs the magnet, the
    # two-frame one leaves it at its prior; the linear estimate against this linear-Gaussian toy's exact posterior
    # (the magnet's 90% interval 0.079 of the prior's, its confounding with a and b included)
    from softsbi.workflows.criticism.design import design_run
    des = design_run(first, scenarios=[toy_scenario(8)], effects=[MAGNET], workers=1, out_dir=tmp_path / "design")
    assert des.motion == "lift" and des.motions == ("toy", "lift") and des.best == "toy"
    assert des.cell("lift", MAGNET).width_ratio > 0.9 and not des.cell("lift", MAGNET).informs
    assert des.cell("toy", MAGNET).informs and 0.05 < des.cell("toy", MAGNET).width_ratio < 0.16
    # from the rig's diagnosis: its motions are the recorded ones (the second one's scenario read from its run)
    rig = design_run(tmp_path / "rig", effects=[MAGNET], workers=1)
    assert rig.run == str(tmp_path / "rig") and (tmp_path / "rig" / "design.json").is_file()
    assert rig.recorded == ("lift", "toy") and set(rig.motions) == {"lift", "toy"} and rig.best is None
    assert rig.informed_already == (MAGNET,)
