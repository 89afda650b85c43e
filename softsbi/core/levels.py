"""The default level of softsbi's statistical verdicts, shared by every layer that decides or draws one.

``softsbi.workflows.stats`` (check's misspecification test, diagnose's tests) decides at it and
``softsbi.report`` draws a stored check that lacks its ``misspecified`` field at it; both import it from
here, so the two cannot disagree.
"""
from __future__ import annotations

#: default family-wise level of the verdicts (check's misspecification test and diagnose's tests). Chosen as the
#: false-alarm rate a user tolerates (issue 19: at most 5%), not fitted. The posterior-predictive test is
#: conservative (the measurement was fitted; Bayarri & Berger 2000), so the rate it gives is lower: on the
#: statistical benchmark's controls 1 of 90 joint p-values is at or below 0.05 (0.03); the next is 0.26.
#: An earlier rule used 0.01.
ALPHA = 0.05
