"""The default level of softsbi's statistical verdicts, shared by every layer that decides or draws one.

``softsbi.workflows.criticism.stats`` (check's misspecification test, diagnose's tests) decides at it and
``softsbi.report`` draws a stored check that lacks its ``misspecified`` field at it; both import it from
here, so the two cannot disagree.
"""
from __future__ import annotations

#: default family-wise level of the verdicts (check's misspecification test and diagnose's tests): the false-alarm
#: rate a user tolerates, the conventional 5%, chosen and not fitted. The posterior-predictive test is conservative
#: (the measurement was fitted, so it sits nearer the posterior predictive's centre than a fresh draw; Bayarri &
#: Berger 2000), so its false-alarm rate is at most this level; docs/benchmarks.md gives the rate on controls.
ALPHA = 0.05
