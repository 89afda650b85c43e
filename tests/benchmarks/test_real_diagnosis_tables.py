"""The real-diagnosis suite's Chamfer table (benchmarks/real_diagnosis.py) on a hand-built task diagnosis: each
recording's posterior-predictive Chamfer under the nominal model and under a weighed candidate, the refits that are
adequate starred, the medians and the median's fall (no fit and no simulation)."""
from __future__ import annotations

import sys
from dataclasses import replace

import pytest

from result_helpers import joint, recording, wind_refit
from toy_helpers import REPO
from softsbi.core.results.joint import JointDiagnosis
from softsbi.workflows.criticism.joint_decide import decide_joint, joint_candidate, nominal_test, ranked

sys.path.insert(0, str(REPO))
from benchmarks.real_diagnosis import chamfer_table


def test_the_chamfer_table_gives_each_recording_under_both_models_and_the_fall_of_the_median():
    nominal_cm, wind_cm = [1.5, 2.0, 1.0, 1.8], [1.2, 1.4, 0.9, 1.0]
    recs = [replace(recording(f"r{i}", 10.0, joint(0, 0)), chamfer_m=c / 100) for i, c in enumerate(nominal_cm)]
    refits = [replace(wind_refit(4.0, test=joint(0, 0) if i == 1 else None), chamfer_m=c / 100)
              for i, c in enumerate(wind_cm)]
    cands = ranked([joint_candidate("wind", recs, refits, 0.05)])
    test = nominal_test(recs, 0.05)
    j = JointDiagnosis(runs=tuple(d.run for d in recs), recordings=tuple(recs), candidates=cands, test=test,
                       decision=decide_joint(test, cands, 2.0), alpha=0.05, k_se=2.0, confirm=2)
    tab, med = chamfer_table("lift", j)
    assert tab["columns"] == ["recording", "nominal", "wind"]
    rows = tab["rows"]
    assert rows[0] == ["r0", 1.5, "1.20*"] and rows[1] == ["r1", 2.0, "1.40"]  # r1's wind refit is misfit
    assert med == pytest.approx({"nominal": 1.65, "wind": 1.1})
    assert rows[-2] == ["median", 1.65, 1.1] and rows[-1] == ["fall of the median", "-", "33%"]


def test_the_duration_scales_read_as_the_arms_mean_speed():
    from softsbi.core.results import Estimate
    from benchmarks.real_diagnosis import duration_note
    recs = [recording(f"r{i}", 10.0, joint(0, 0)) for i in range(3)]
    def note(width):
        refits = [replace(wind_refit(4.0, effect="duration-scale"), estimates=(Estimate(
            name="duration_scale", unit="1", mean=s, q05=s - 0.2, q95=s + 0.2, width_ratio=width,
            effect="duration-scale"),)) for s in (1.5, 2.0, 3.0)]
        cands = ranked([joint_candidate("duration-scale", recs, refits, 0.05)])
        test = nominal_test(recs, 0.05)
        j = JointDiagnosis(runs=tuple(d.run for d in recs), recordings=tuple(recs), candidates=cands, test=test,
                           decision=decide_joint(test, cands, 2.0), alpha=0.05, k_se=2.0, confirm=2)
        return duration_note(REPO.parent / "shared" / "data" / "diffcloud_lift" / "lift_tan2", j)

    # the 0.36 m path over 0.96 s: 0.38 m/s as scripted, 0.13-0.25 m/s at scales 3 and 1.5
    informed = note(0.3)
    assert "path is 0.36 m over the scenario's 0.96 s" in informed and "scales 1.50-3.00 (median 2.00)" in informed
    assert "mean speed 0.13-0.25 m/s" in informed and informed.endswith("0.30 of the prior's wide (median over the lifts).")
    # a posterior as wide as the prior: the speeds are the prior's, and the note says so
    assert note(0.99).endswith("the recordings do not inform it, and these speeds are the prior's.")
