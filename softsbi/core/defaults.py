"""Every default and bound of softsbi's settings, in one place: the workflows, the CLI's options (``softsbi --help``
shows them without importing the workflows), the executors and the report all read them from here.
``tests/cli/test_cli_defaults.py`` ties every CLI default to its library one, and check's and diagnose's flags,
defaults and bounds to :class:`CheckSettings` and :class:`DiagnoseSettings`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Mapping

from softsbi.core.errors import SoftsbiError

#: default family-wise level of the verdicts (check's misspecification test and diagnose's tests): the false-alarm
#: rate a user tolerates, the conventional 5%, chosen and not fitted. The posterior-predictive test is conservative
#: (the measurement was fitted, so it sits nearer the posterior predictive's centre than a fresh draw; Bayarri &
#: Berger 2000), so its false-alarm rate is at most this level; docs/benchmarks.md gives the rate on controls.
ALPHA = 0.05

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
#: replicate recordings ``task train`` simulates per model to calibrate ``check`` of its fits
#: (:mod:`~softsbi.workflows.criticism.check_null`), each refitted, checked on ``N_NULL`` rollouts and screened
#: (about 60 finite differences on the lift: 91 simulations a replicate). 40 resolve p = 1/41 = 0.024, half the
#: 0.05 level, so that a recording beyond all but one replicate rejects; 100 would cost 2.5 times as much for a
#: finer p-value the verdict does not need (the lift task: 17 x 3640 replicate simulations, not 17 x 9100)
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


# -- the settings of check and diagnose, each with its default and its bound in one place ------------------------

@dataclass(frozen=True)
class Bound:
    """The values a numeric setting accepts: at least ``low`` (more than it when ``strict``), below ``below`` when
    given, and why. The CLI refuses a flag outside it when the flags are parsed and the workflow when it is called,
    both with :meth:`problem`'s words, so the two cannot disagree."""

    flag: str
    low: float
    why: str = ""
    strict: bool = False
    below: float | None = None

    def limit(self) -> str:
        """The accepted range in words, e.g. ``> 0 and < 1``."""
        return (f"> {self.low:g}" if self.strict else f">= {self.low:g}") + (
            "" if self.below is None else f" and < {self.below:g}")

    def problem(self, value: float | None) -> str | None:
        """None when ``value`` is accepted (None, an unset optional setting, is), else ``must be >= 5 (got 2): why``."""
        if value is None:
            return None
        if value < self.low or (self.strict and value <= self.low) or (self.below is not None and value >= self.below):
            return f"must be {self.limit()} (got {value:g})" + (f": {self.why}" if self.why else "")
        return None


#: the bounds shared by check and diagnose
ALPHA_BOUND = Bound("--alpha", 0.0, "a probability", strict=True, below=1.0)
MAX_NULL_BOUND = Bound("--max-null", MIN_ROLLOUTS)
WORKERS_BOUND = Bound("--workers", 1, "one simulation process at least; leave it out for one per core")
SEED_BOUND = Bound("--seed", 0, "seeds are non-negative integers")
NULL_WHY = "the null's first stage and the check's error maps need that many posterior rollouts"


class _Settings:
    """Frozen settings checked against their :data:`BOUNDS` when made."""

    BOUNDS: ClassVar[Mapping[str, Bound]] = {}

    def __post_init__(self) -> None:
        for name, bound in self.BOUNDS.items():
            why = bound.problem(getattr(self, name))
            if why is not None:
                raise SoftsbiError(f"{bound.flag} {why}")


@dataclass(frozen=True, kw_only=True)
class CheckSettings(_Settings):
    """``softsbi check``'s settings (and ``compare``'s check of each run).

    Attributes:
        n_eval: posterior-predictive rollouts of the error maps and the first stage of the misspecification test's
            null. max_null: the cap of the null's adaptive extension (``1 / (max_null + 1)`` is the finest p-value).
        alpha: the level of the verdict. workers: simulation processes (None: one per core). seed: draws and rollouts.

    Raises:
        SoftsbiError: a value outside its :data:`BOUNDS`, naming the flag.
    """

    n_eval: int = N_NULL
    max_null: int = MAX_NULL
    alpha: float = ALPHA
    workers: int | None = None
    seed: int = SEED
    BOUNDS: ClassVar[Mapping[str, Bound]] = {
        "n_eval": Bound("--n-eval", MIN_ROLLOUTS, NULL_WHY), "max_null": MAX_NULL_BOUND, "alpha": ALPHA_BOUND,
        "workers": WORKERS_BOUND, "seed": SEED_BOUND}


@dataclass(frozen=True, kw_only=True)
class DiagnoseSettings(_Settings):
    """``softsbi diagnose``'s settings.

    Attributes:
        n_null, max_null, alpha, workers, seed: the nominal fit's check (:class:`CheckSettings`; ``n_null`` is its
            ``n_eval``) and every refit's.
        k_se: standard errors by which a refit's summary energy score must fall to count, and within which two refits
            tie. confirm: single refits of the top candidates (a pair may follow; 0: none).
        refit_rounds, refit_sims: a refit's rounds and simulations per round (None: the run's own).

    Raises:
        SoftsbiError: a value outside its :data:`BOUNDS`, naming the flag.
    """

    n_null: int = N_NULL
    max_null: int = MAX_NULL
    alpha: float = ALPHA
    workers: int | None = None
    seed: int = SEED
    k_se: float = K_SE
    confirm: int = CONFIRM
    refit_rounds: int | None = None
    refit_sims: int | None = None
    BOUNDS: ClassVar[Mapping[str, Bound]] = {
        "n_null": Bound("--n-null", MIN_ROLLOUTS, NULL_WHY), "max_null": MAX_NULL_BOUND, "alpha": ALPHA_BOUND,
        "workers": WORKERS_BOUND, "seed": SEED_BOUND,
        "k_se": Bound("--k-se", 0.0, "a positive number of standard errors", strict=True),
        "confirm": Bound("--confirm", 0, "0 = no refit"),
        "refit_rounds": Bound("--refit-rounds", 1, "leave it out for the run's own rounds"),
        "refit_sims": Bound("--refit-sims", MIN_SIMS_PER_ROUND, "the estimator needs data; leave it out for the run's "
                                                                 "own")}

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
