"""The defaults of the workflows' settings, in one place: :class:`~softsbi.workflows.fit.run.FitConfig` and the
workflow functions take their defaults from here, and so do the CLI's options (``softsbi --help`` shows them
without importing the workflows). ``tests/cli/test_cli_defaults.py`` ties every CLI default to its library one.
"""
from __future__ import annotations

#: simulator, posterior estimator, observer and executor plugins of a fit
BACKEND = "mujoco-flex"
ESTIMATOR = "rkhs"
OBSERVER = "pointcloud"
EXECUTOR = "local"
#: proposal scheme of later rounds and sensor model of the metric (:class:`~softsbi.workflows.fit.run.FitConfig`)
PROPOSAL = "truncated"
SENSOR = "height"
#: random seed of every draw and simulation
SEED = 0
#: sequential rounds and simulations per round (the simulation budget is their product; the paper: 15 x 100)
ROUNDS = 4
SIMS_PER_ROUND = 150
#: K, points per frame of the point-cloud observer's state
N_POINTS = 64
#: the simulation bank a fit's first round reads and fills: "default" (the user's cache folder), "off", or a folder
SIM_BANK = "default"
#: posterior-predictive rollouts of a fit's reported Chamfer, of ``check`` and of ``compare``
N_EVAL = 30
#: posterior-predictive simulations a misspecification test's null starts with, and the cap of its adaptive
#: extension (``1 / (cap + 1)`` is the finest p-value a verdict can print)
N_NULL = 30
MAX_NULL = 200
#: posterior rollouts ``softsbi view`` draws against the measurement
VIEW_N_EVAL = 5
#: ``diagnose``: single refits of the top named candidates (a pair may follow), and the standard errors by which a
#: refit's summary energy score must fall to count, and within which two refits tie (2: a one-sided z-test at about
#: 2.3% for an improvement, a two-sided one at about 5% for a tie; the standard errors are the scores' Monte-Carlo ones)
CONFIRM = 2
K_SE = 2.0
#: the demo's budget per fit (3 x 100: the demo, its diagnosis and its refit run in about 3.5 minutes on 2 cores
#: and name the hidden wind)
DEMO_ROUNDS = 3
DEMO_SIMS = 100
#: prior simulations a stored task's model is trained on (``softsbi task train --prior-sims``): a default fit's
#: budget (4 x 150) and more, since they are simulated once per task, not per recording
TASK_PRIOR_SIMS = 1000
#: calibration: fresh test simulations and posterior draws per test simulation
N_TEST = 200
N_DRAWS = 1000
#: replicate recordings ``task train`` simulates to calibrate ``check`` of the nominal model's fits
#: (:mod:`~softsbi.workflows.criticism.check_null`): 100 resolve p = 1/101, below a 0.05 level halved by Bonferroni
CHECK_REPLICATES = 100
#: scenario of ``softsbi simulate`` and ``compare-backends``, and the engines the latter compares
SCENARIO = "lift"
COMPARED_BACKENDS = ("mujoco-flex", "pybullet-massspring")
#: ``train-extractor --simulate``: rendered rollouts and square camera size (px); also the image observers'
IMAGE_ROLLOUTS = 40
IMAGE_SIZE = 128

#: the smallest values the settings accept (the CLI refuses smaller ones when it parses the flags, the workflows
#: when they are called): a round needs simulations to train on, a check a few rollouts for its error maps and the
#: first stage of its null, a calibration test simulations for its coverage curve
MIN_SIMS_PER_ROUND = 10
MIN_ROLLOUTS = 5
MIN_TEST = 20
#: calibration's rank-histogram bins, and the fewest posterior draws per test simulation: one per bin, so that
#: every bin of the SBC histogram holds a possible rank and the HPD levels of the coverage curve and of TARP are
#: resolved to ``1 / N_BINS`` (with 1 draw every rank and level is 0 or 1)
N_BINS = 10
MIN_DRAWS = N_BINS
