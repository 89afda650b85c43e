"""Every seed stream and derived seed of softsbi, in one place.

A draw is seeded by a sequence, ``numpy.random.default_rng([seed, stream, ...])``: ``seed`` is the user's
(``--seed``), and the stream keeps the draws of one purpose apart from every other's, so that adding draws of one
kind never moves another's. A fit's rounds use the small streams ``r = 0, 1, ...`` (their round index); the named
streams below are far from them and distinct from each other (``tests/core/test_seeds.py``).
"""
from __future__ import annotations

#: the features of a sensor's view of a rollout (``[seed, SENSOR_VIEW_STREAM]``: its depth-camera draws)
SENSOR_VIEW_STREAM = 23
#: the covariance-scale recalibration's draws of a neural estimator
RECAL_STREAM = 4242
#: the synthetic image data set of a keypoint extractor
SYNTH_STREAM = 4343
#: the training view (point subsets) of an ensemble member's embedding net
VIEW_STREAM = 5150
#: the amortised posterior predictive's draws and rollouts (a candidate's evidence)
EVIDENCE_STREAM = 6060
#: a task's held-out prior simulations (its training report)
TEST_STREAM = 7070
#: a second set of a task's held-out prior simulations, judged once after a choice made on the first
#: (the posterior-calibration suite's fresh test)
FRESH_TEST_STREAM = 7171
#: the replicate recordings that calibrate ``check`` of a trained task
NULL_STREAM = 8080
#: the posterior-predictive evaluation after the last round ``R``: stream ``EVAL_STREAM + R``
EVAL_STREAM = 10_000
#: the seed of rollout ``i`` of a posterior predictive beyond a fit's stored evaluation (check's adaptive null)
EXTRA_ROLLOUT_SEED = 10_000
#: the seed of the surface samples of posterior-predictive rollout ``i``: ``SURFACE_SEED + i``
SURFACE_SEED = 1000

#: the named streams, by name (their values must differ)
STREAMS = {"SENSOR_VIEW_STREAM": SENSOR_VIEW_STREAM, "RECAL_STREAM": RECAL_STREAM, "SYNTH_STREAM": SYNTH_STREAM,
           "VIEW_STREAM": VIEW_STREAM, "EVIDENCE_STREAM": EVIDENCE_STREAM, "TEST_STREAM": TEST_STREAM,
           "FRESH_TEST_STREAM": FRESH_TEST_STREAM,
           "NULL_STREAM": NULL_STREAM, "EVAL_STREAM": EVAL_STREAM}


def surface_seed(sample: int) -> int:
    """The seed of the surface points sampled on posterior-predictive rollout ``sample`` (its summaries): the same
    in a fit's evaluation, check, its null and the figures, so a rollout's summaries are computed once alike."""
    return SURFACE_SEED + int(sample)


def eval_stream(rounds: int) -> int:
    """The stream of a fit's posterior-predictive evaluation after ``rounds`` rounds."""
    return EVAL_STREAM + int(rounds)
