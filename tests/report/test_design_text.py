"""The motion to record next (softsbi design): which candidates a diagnosis leaves undecided, the ranking and its
words, on fixed, hand-built results; the noise precision it weighs summaries with."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from result_helpers import joint, recording, wind_refit
from softsbi.core.results.design import LINEAR, TRAINED, Design, MotionEffect, undecided_candidates
from softsbi.inference.contraction import INFORMED_MAX_RATIO
from softsbi.report.design_text import design_advice, design_columns, design_rows, design_text
from softsbi.workflows.criticism.design import efficiency_factor, noise_precision

FAMILY = ["wind", "extra-damping", "sticky-patch"]


def design(widths: dict[str, dict[str, float]], own: str = "lift") -> Design:
    cells = tuple(MotionEffect(motion=m, effect=e, width_ratio=w, source=TRAINED if m == own else LINEAR)
                  for m, row in widths.items() for e, w in row.items())
    motions = tuple(sorted(widths, key=lambda m: (-sum(w <= 0.5 for w in widths[m].values()),
                                                  sum(widths[m].values()))))
    first = next(iter(widths.values()))
    return Design(run="runs/lift", motion=own, undecided={e: "not informed by this task" for e in first},
                  cells=cells, motions=motions, simulations=256)


def test_what_a_diagnosis_leaves_undecided():
    named = recording("lift", 10.0, joint(0, 0), (wind_refit(4.0),))
    assert named.verdict == "missing-effect" and undecided_candidates(named, FAMILY) == {}
    blind = replace(named, uninformed={"sticky-patch": 0.93})
    assert undecided_candidates(blind, FAMILY) == {"sticky-patch": "not informed by this task"}
    fits = recording("lift", 4.0, joint(120, 150))
    assert undecided_candidates(replace(fits, uninformed={"sticky-patch": 0.93}), FAMILY) == {}  # nothing to explain
    unexplained = recording("lift", 10.0, joint(0, 0), (wind_refit(9.9, test=joint(0, 0)),))
    assert unexplained.verdict == "misspecified-unexplained"
    assert undecided_candidates(unexplained, FAMILY) == dict.fromkeys(FAMILY, "unexplained")
    assert undecided_candidates(None, FAMILY) == dict.fromkeys(FAMILY, "no diagnosis yet")


def test_the_advice_names_the_motion_that_informs_what_this_one_does_not():
    d = design({"lift": {"extra-damping": 0.91, "sticky-patch": 0.95},
                "wipe": {"extra-damping": 0.62, "sticky-patch": 0.21},
                "fling": {"extra-damping": 0.38, "sticky-patch": 0.88}})
    assert d.informed("wipe") == ("sticky-patch",) and d.informed("lift") == ()
    # one informed candidate each: the smaller summed width first
    assert d.motions == ("wipe", "fling", "lift") and d.best == "wipe"
    assert design_advice(d) == ("Record a wipe: it informs sticky-patch, which the lift does not (a 90% interval "
                                "under 0.5 of the prior's).")
    assert design_columns(d) == ["candidate", "undecided because", "wipe", "fling", "lift (this fit)"]
    assert design_rows(d) == [["extra-damping", "not informed by this task", "0.62", "0.38", "0.91 (trained)"],
                              ["sticky-patch", "not informed by this task", "0.21", "0.88", "0.95 (trained)"],
                              ["informed", "at 0.5 or less", "1 of 2", "1 of 2", "0 of 2"]]
    assert design_text(d)[1].startswith("Each cell is the undecided candidate's predicted 90% interval width")
    assert "2 from trained tasks' reports" in design_text(d)[1] and "4 by the linear estimate" in design_text(d)[1]
    assert design_text(d)[1].endswith("no trained task of this motion scales it, so it is optimistic).")
    assert design_text(replace(d, efficiency=2.9))[1].endswith(
        "scaled by 2.9, the trained task's widths over the bound on the lift, the median over the candidates both "
        "measure).")
    # the efficiency: the median ratio over candidates neither side leaves at the prior's width, at least 1
    assert efficiency_factor({"a": 0.3, "b": 0.6, "c": 0.97}, {"a": 0.1, "b": 0.3, "c": 0.2}) == pytest.approx(2.5)
    assert efficiency_factor({"a": 0.1}, {"a": 0.3}) == 1.0 and efficiency_factor({}, {"a": 0.3}) is None
    none = design({"lift": {"air-drag": 0.9}, "wipe": {"air-drag": 0.8}})
    assert none.best is None and design_advice(none).startswith(
        "No motion weighed informs air-drag beyond what the lift does: record a motion that excites it")
    assert INFORMED_MAX_RATIO == 0.5 and MotionEffect(motion="a", effect="b", width_ratio=0.5, source=LINEAR).informs


def test_a_rigs_advice_is_a_motion_none_of_its_recorded_motions_informs_it_with():
    widths = {"lift": {"extra-damping": 0.91, "sticky-patch": 0.95, "air-drag": 0.9},
              "wipe": {"extra-damping": 0.62, "sticky-patch": 0.21, "air-drag": 0.8},
              "fling": {"extra-damping": 0.38, "sticky-patch": 0.88, "air-drag": 0.3}}
    assert design(widths).best == "fling"  # after the lift alone: it informs two
    rig = replace(design(widths), recorded=("lift", "fling"))
    assert rig.informed_already == ("extra-damping", "air-drag") and rig.best == "wipe"
    assert design_advice(rig) == ("Record a wipe: it informs sticky-patch, which the lift and the fling do not (a 90% "
                                  "interval under 0.5 of the prior's).")
    assert design_columns(rig)[2:] == ["fling (recorded)", "wipe", "lift (recorded)"]
    done = replace(rig, recorded=("lift", "fling", "wipe"))
    assert done.best is None and design_advice(done) == (
        "The lift, the fling and the wipe already inform every undecided candidate: more recordings (`softsbi "
        "diagnose RUN RUN RUN --out DIR`) decide between them.")


def test_the_noise_precision_is_unbiased_and_refuses_too_few_seeds():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(14, 14)) * 0.1
    cov = a @ a.T + np.eye(14) * 1e-2  # one frame's correlated summaries (m^2), the 3 mm floors negligible beside it
    mean = np.mean([noise_precision(rng.multivariate_normal(np.zeros(14), cov, size=32)) for _ in range(400)], axis=0)
    truth = np.linalg.inv(cov)
    assert np.trace(mean) / np.trace(truth) == pytest.approx(1.0, abs=0.06)  # the naive inverse: 31/16 = 1.94
    with pytest.raises(ValueError, match="16 seeds cannot estimate the precision of 14 summaries"):
        noise_precision(rng.normal(size=(16, 14)))
