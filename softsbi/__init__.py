"""softsbi: Bayesian real-to-sim for deformable objects.

Implements BayesSim-RKHS (Antonova et al. 2022, "A Bayesian Treatment of Real-to-Sim for
Deformable Object Manipulation") on top of BayesSim (Ramos et al. 2019), with simulator
backends, observers and estimators as pluggy plugins (entry-point group ``softsbi``).
"""
from .core.errors import SoftsbiError
from .core.interfaces import Effect, Executor, Observer, PosteriorEstimator, Simulator
from .core.types import Observation, Param, ParamSpace, Rollout, Scenario
from .plugins.hookspecs import hookimpl

try:
    from importlib.metadata import version as _v
    __version__ = _v("softsbi")
except Exception:  # noqa: BLE001 - running from a source tree
    __version__ = "0.0.0"

__all__ = ["hookimpl", "Simulator", "Effect", "Observer", "PosteriorEstimator", "Executor", "Param",
           "ParamSpace", "Scenario", "Rollout", "Observation", "SoftsbiError", "__version__"]
