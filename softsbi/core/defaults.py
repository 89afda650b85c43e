"""Every default and bound of softsbi's settings, in one place: the workflows, the CLI's options (``softsbi --help``
shows them without importing the workflows), the executors and the report all read them from here.
``tests/cli/test_cli_defaults.py`` ties every CLI default to its library one, and check's and diagnose's flags,
defaults and bounds to :class:`CheckSettings` and :class:`DiagnoseSettings`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Mapping

from softsbi.core.errors import SoftsbiError

#: default family-wise level of the verdicts (check's misspecification test and diagnose's tests): the false-alarm
#: rate a user tolerates, the conventional 5%, chosen and not fitted. The posterior-predictive test is conservative
#: (the measurement was fitted, so it sits nearer the posterior predictive's centre than a fresh draw; Bayarri &
#: Berger 2000), so its false-alarm rate is at most this level; docs/benchmarks.md gives the rate on controls.
ALPHA = 0.05
#: width ratio (a 90% interval's width over the prior's) above which a parameter counts as not informed by the
#: data (:mod:`softsbi.inference.contraction`): one threshold for fits, training reports, the diagnosis and design
INFORMED_MAX_RATIO = 0.5

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
#: re-runs of a simulation whose worker crashed or hung, before it is stored as failed (``fit --retries``)
RETRIES = 2
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
#: refinement of a diagnosis' amortised refit that is adequate and improving but whose effect the data may leave off
#: (``diagnose --refine-refits N``, :func:`~softsbi.workflows.criticism.decide.to_refine`): at most ``REFINE`` of
#: them, each fitted again in ``REFINE_ROUNDS`` sequential rounds of ``REFINE_SIMS`` truncated-proposal simulations
#: after its amortised posterior (round 1, read from the task). Arithmetic on the lift: 2 x 150 = 300 simulations, about 40 s at
#: 7.5 rollouts/s, plus its check (30 rollouts and the screening); two refined refits keep a diagnosis that needs them
#: within about 2 min more, and a control (nothing to refine) pays nothing
REFINE = 2
REFINE_ROUNDS = 2
REFINE_SIMS = 150
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
#: replicate recordings ``task train`` simulates of the nominal model to calibrate ``check`` of its fits (the
#: detection, :mod:`~softsbi.workflows.criticism.check_null`), each refitted, checked on ``N_NULL`` rollouts and
#: screened (about 60 finite differences on the lift: 91 simulations a replicate). 40 resolve p = 1/41 = 0.024, half
#: the 0.05 level, so that a recording beyond all but one replicate rejects; 100 would cost 2.5 times as much for a
#: finer p-value the verdict does not need (the lift: 3,640 replicate simulations, not 9,100)
CHECK_REPLICATES = 40
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
#: the fewest replicate recordings of ``task train --check-null`` that can reject at the default level:
#: ``1 / (n + 1) <= ALPHA``
MIN_CHECK_REPLICATES = math.ceil(1 / ALPHA) - 1
#: replicate recordings ``task train`` simulates per candidate model (``--refit-null``): they calibrate the adequacy
#: check of ``diagnose``'s amortised refit of that candidate by its omnibus test alone, so they are not screened (31
#: simulations a replicate on the lift, not 91). 19 resolve p = 1/20, the level: a refit is inadequate when its
#: statistic is beyond every one of them. The lift task's 16 candidates then cost 16 x 19 x 31 = 9,424 replicate
#: simulations instead of 16 x 40 x 91 = 58,240, and the task 33,464 in all instead of 82,264 (docs/explanation.md,
#: "What a trained task costs")
REFIT_REPLICATES = MIN_CHECK_REPLICATES

#: the largest counts the settings accept (each bound's ``why`` below says why). Each lies far beyond what a use
#: needs and stops a slip (an extra zero, a 1e9) before it is spent: ``check --n-eval 1000000000`` asked numpy for
#: 74.5 GiB, ``diagnose --refit-sims 1000000000`` planned 4.7e4 hours of simulation
MAX_ROLLOUTS = 10_000
MAX_SIMS = 100_000
MAX_ROUNDS = 100
MAX_WORKERS = 1024
MAX_CONFIRM = 100
MAX_CHECK_REPLICATES = 1000
MAX_POINTS = 4096
MAX_IMAGE_SIZE = 4096
MAX_RETRIES = 100
MAX_SENSOR_DRAWS = 100
MAX_SEED = 2**32 - 1
#: why most counts stop where they do: rollouts, null sizes, held-out test simulations, posterior draws per test
#: simulation (10000 draws of 10000 test simulations are already 0.8 GB of log-densities) and rendered rollouts;
#: simulations per round, a task's prior simulations and the best fit's refinement (the paper's rounds hold 100, a
#: default fit's 150)
ROLLOUTS_WHY = f"{MAX_ROLLOUTS} resolve a p-value, a coverage or a rank to 1e-4, finer than any level a verdict reads"
SIMS_WHY = f"{MAX_SIMS} simulations take hours and teach the estimators nothing more"

# -- every numeric setting's bound in one place (check's and diagnose's, and the other commands' flags) ----------

def _text(value: float) -> str:
    return str(value) if isinstance(value, int) else f"{value:g}"


@dataclass(frozen=True)
class Bound:
    """The values a numeric setting accepts: a finite number at least ``low`` (more than it when ``strict``), below
    ``below`` and at most ``high`` when given, or 0 when ``zero`` says what 0 means; and why. The CLI refuses a flag
    outside it when the flags are parsed and the workflow when it is called, both with :meth:`problem`'s words, so
    the two cannot disagree."""

    flag: str
    low: float
    why: str = ""
    strict: bool = False
    below: float | None = None
    high: float | None = None
    zero: str = ""

    def _lower(self) -> str:
        return ((f"0 ({self.zero}) or " if self.zero else "") + (">" if self.strict else ">=") + f" {self.low:g}" +
                ("" if self.below is None else f" and < {self.below:g}"))

    def limit(self) -> str:
        """The accepted range in words, e.g. ``> 0 and < 1``, ``>= 5 and <= 10000``."""
        return self._lower() + ("" if self.high is None else f" and <= {_text(self.high)}")

    def problem(self, value: float | None) -> str | None:
        """None when ``value`` is accepted (None, an unset optional setting, is), else the side it crosses, e.g.
        ``must be >= 5 (got 2): why``, ``must be <= 10000 (got 1000000000): why``; NaN and infinity are refused
        with the whole range."""
        if value is None or (self.zero and value == 0):
            return None
        if value != value or value in (math.inf, -math.inf):
            need = f"a finite number {self.limit()}"
        elif value < self.low or (self.strict and value <= self.low) or (self.below is not None and value >= self.below):
            need = self._lower()
        elif self.high is not None and value > self.high:
            need = f"<= {_text(self.high)}"
        else:
            return None
        return f"must be {need} (got {_text(value)})" + (f": {self.why}" if self.why else "")


#: the bounds shared by check and diagnose
ALPHA_BOUND = Bound("--alpha", 0.0, "a probability", strict=True, below=1.0)
MAX_NULL_BOUND = Bound("--max-null", MIN_ROLLOUTS, ROLLOUTS_WHY, high=MAX_ROLLOUTS)
WORKERS_BOUND = Bound("--workers", 1, f"one simulation process at least, and more than {MAX_WORKERS} outnumber any "
                                      f"machine's cores; leave it out for one per core", high=MAX_WORKERS)
SEED_BOUND = Bound("--seed", 0, "seeds are non-negative 32-bit integers", high=MAX_SEED)
NULL_WHY = f"the null's first stage and the check's error maps need that many posterior rollouts; {ROLLOUTS_WHY}"
#: the bounds of the other commands' counts
ROUNDS_BOUND = Bound("--rounds", 1, "one round at least; the paper runs 15", high=MAX_ROUNDS)
SIMS_BOUND = Bound("--sims-per-round", MIN_SIMS_PER_ROUND, f"the estimator needs data; {SIMS_WHY} (the paper's "
                                                           f"rounds hold 100)", high=MAX_SIMS)
PRIOR_SIMS_BOUND = Bound("--prior-sims", MIN_SIMS_PER_ROUND, f"the estimator needs data; {SIMS_WHY}", high=MAX_SIMS)
EVAL_BOUND = Bound("--n-eval", 1, f"one rollout at least; {ROLLOUTS_WHY}", high=MAX_ROLLOUTS)
POINTS_BOUND = Bound("--points", 1, "one point per frame at least; the estimators' input grows with K, and a "
                                    "DiffCloud frame holds 3500 points", high=MAX_POINTS)
IMAGE_SIZE_BOUND = Bound("--image-size", 1, f"pixels a side of a square frame; a {MAX_IMAGE_SIZE} px RGB frame is "
                                            f"48 MiB", high=MAX_IMAGE_SIZE)
IMAGE_ROLLOUTS_BOUND = Bound("--rollouts", 1, f"one rendered rollout at least; {ROLLOUTS_WHY}", high=MAX_ROLLOUTS)
RETRIES_BOUND = Bound("--retries", 0, f"0 = a crashed simulation is stored as failed; one that crashes {MAX_RETRIES} "
                                      f"times will crash again", high=MAX_RETRIES)
SENSOR_DRAWS_BOUND = Bound("--sensor-draws", 0, f"0 = none; each multiplies the training pairs, {MAX_SENSOR_DRAWS} "
                                                f"times at most", high=MAX_SENSOR_DRAWS)
REFINE_BOUND = Bound("--refine", 0, f"0 = no refinement; {SIMS_WHY}", high=MAX_SIMS)
N_TEST_BOUND = Bound("--n-test", MIN_TEST, f"200 or more resolves the 90% coverage; {ROLLOUTS_WHY}",
                     high=MAX_ROLLOUTS)
TASK_N_TEST_BOUND = Bound("--n-test", MIN_TEST, f"fewer held-out simulations cannot judge the calibration; "
                                                f"{ROLLOUTS_WHY}", high=MAX_ROLLOUTS, zero="no training report")
N_DRAWS_BOUND = Bound("--n-draws", MIN_DRAWS, f"one draw per bin of the {N_BINS}-bin SBC rank histogram, HPD levels "
                                              f"(coverage, TARP) resolved to 1/{N_BINS}; {ROLLOUTS_WHY}",
                      high=MAX_ROLLOUTS)
CHECK_NULL_BOUND = Bound("--check-null", MIN_CHECK_REPLICATES,
                         f"a calibrated p-value from n replicates is at least 1/(n+1), so the level {ALPHA} needs "
                         f"n >= {MIN_CHECK_REPLICATES}; each replicate is refitted, checked and screened (91 "
                         f"simulations on the lift), and {MAX_CHECK_REPLICATES} resolve p to 1/{MAX_CHECK_REPLICATES + 1}",
                         high=MAX_CHECK_REPLICATES, zero="none")
REFIT_NULL_BOUND = Bound("--refit-null", MIN_CHECK_REPLICATES,
                         f"a calibrated p-value from n replicates is at least 1/(n+1), so the level {ALPHA} needs "
                         f"n >= {MIN_CHECK_REPLICATES}; each replicate is refitted and checked (31 simulations on the "
                         f"lift)", high=MAX_CHECK_REPLICATES, zero="none")


class _Settings:
    """Frozen settings checked against their :data:`BOUNDS` when made."""

    BOUNDS: ClassVar[Mapping[str, Bound]] = {}

    def __post_init__(self) -> None:
        for name, bound in self.BOUNDS.items():
            why = bound.problem(getattr(self, name))
            if why is not None:
                raise SoftsbiError(f"{bound.flag} {why}")


@dataclass(frozen=True, kw_only=True)
class _CheckFields(_Settings):
    """The settings check and diagnose share (the check of the nominal fit and of each refit), and their bounds."""

    max_null: int = MAX_NULL
    alpha: float = ALPHA
    workers: int | None = None
    seed: int = SEED
    BOUNDS: ClassVar[Mapping[str, Bound]] = {"max_null": MAX_NULL_BOUND, "alpha": ALPHA_BOUND,
                                             "workers": WORKERS_BOUND, "seed": SEED_BOUND}


@dataclass(frozen=True, kw_only=True)
class CheckSettings(_CheckFields):
    """``softsbi check``'s settings (and ``compare``'s check of each run).

    Attributes:
        n_eval: posterior-predictive rollouts of the error maps and the first stage of the misspecification test's
            null. max_null: the cap of the null's adaptive extension (``1 / (max_null + 1)`` is the finest p-value).
        alpha: the level of the verdict. workers: simulation processes (None: one per core). seed: draws and rollouts.

    Raises:
        SoftsbiError: a value outside its :data:`BOUNDS`, naming the flag.
    """

    n_eval: int = N_NULL
    BOUNDS: ClassVar[Mapping[str, Bound]] = {
        "n_eval": Bound("--n-eval", MIN_ROLLOUTS, NULL_WHY, high=MAX_ROLLOUTS), **_CheckFields.BOUNDS}


@dataclass(frozen=True, kw_only=True)
class DiagnoseSettings(_CheckFields):
    """``softsbi diagnose``'s settings.

    Attributes:
        n_null, max_null, alpha, workers, seed: the nominal fit's check (:class:`CheckSettings`; ``n_null`` is its
            ``n_eval``) and every refit's.
        k_se: standard errors by which a refit's summary energy score must fall to count, and within which two refits
            tie. confirm: single refits of the top candidates (a pair may follow; 0: none).
        refit_rounds, refit_sims: a refit's rounds and simulations per round (None: the run's own).
        refine: amortised refits that may be refined by sequential rounds (:data:`REFINE`; 0: none).

    Raises:
        SoftsbiError: a value outside its :data:`BOUNDS`, naming the flag.
    """

    n_null: int = N_NULL
    k_se: float = K_SE
    confirm: int = CONFIRM
    refit_rounds: int | None = None
    refit_sims: int | None = None
    refine: int = REFINE
    BOUNDS: ClassVar[Mapping[str, Bound]] = {
        "n_null": Bound("--n-null", MIN_ROLLOUTS, NULL_WHY, high=MAX_ROLLOUTS), **_CheckFields.BOUNDS,
        "k_se": Bound("--k-se", 0.0, "a positive number of standard errors", strict=True),
        "confirm": Bound("--confirm", 0, "0 = no refit; each is a whole fit, and a family of effects holds a few "
                                         "dozen candidates", high=MAX_CONFIRM),
        "refit_rounds": Bound("--refit-rounds", 1, "leave it out for the run's own rounds; the paper runs 15",
                              high=MAX_ROUNDS),
        "refit_sims": Bound("--refit-sims", MIN_SIMS_PER_ROUND, f"the estimator needs data; leave it out for the "
                                                                f"run's own; {SIMS_WHY}", high=MAX_SIMS),
        "refine": Bound("--refine-refits", 0, "0 = none; each costs two sequential rounds and a check",
                        high=MAX_CONFIRM)}

    def check(self) -> CheckSettings:
        """The settings of the nominal fit's check (and each refit's)."""
        return CheckSettings(n_eval=self.n_null, max_null=self.max_null, alpha=self.alpha, workers=self.workers,
                             seed=self.seed)


def split_settings(cls: type, values: Mapping[str, object]) -> tuple[object, dict[str, object]]:
    """``values`` (a Python API call's keyword arguments) as ``cls``'s settings object and the rest, which the
    workflow takes itself (e.g. ``recompute``); a name neither knows is then refused by the workflow's signature. A
    ready settings object may be given as ``settings=`` instead of its fields.

    Raises:
        SoftsbiError: a setting outside its bound (:class:`CheckSettings`, :class:`DiagnoseSettings`), or
            ``settings=`` given together with some of its fields.
    """
    names = set(cls.__dataclass_fields__)
    fields = {k: v for k, v in values.items() if k in names}
    rest = {k: v for k, v in values.items() if k not in names and k != "settings"}
    given = values.get("settings")
    if given is not None:
        if fields:
            raise SoftsbiError(f"give either settings={cls.__name__}(...) or its fields ({', '.join(sorted(fields))}), "
                               f"not both")
        return given, rest
    return cls(**fields), rest
