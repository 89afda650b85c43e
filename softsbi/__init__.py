"""softsbi: Bayesian real-to-sim for deformable objects.

Implements BayesSim-RKHS (Antonova et al. 2022, "A Bayesian Treatment of Real-to-Sim for
Deformable Object Manipulation") on top of BayesSim (Ramos et al. 2019), with simulator
backends, observers and estimators as pluggy plugins (entry-point group ``softsbi``).

The Python API (the CLI's workflows, with the same defaults)::

    import softsbi
    rec = softsbi.load_recording("../shared/data/diffcloud_lift/lift_tan")
    softsbi.fit(rec, out="runs/tan")
    post = softsbi.open_run("runs/tan").posterior     # physical units
    post.sample(100), post.mean, post.interval(0.9)

The workflow functions are imported on first use, so ``import softsbi`` (e.g. by a plugin for
``hookimpl`` and the base classes) stays light.
"""
from softsbi.core.errors import SoftsbiError
from softsbi.core.interfaces import Effect, Executor, Observer, PosteriorEstimator, Simulator
from softsbi.core.types import Observation, Param, ParamSpace, Recording, Rollout, Scenario
from softsbi.plugins.hookspecs import hookimpl

try:
    from importlib.metadata import version as _v
    __version__ = _v("softsbi")
except Exception:  # noqa: BLE001 - running from a source tree
    __version__ = "0.0.0"

#: public API name -> module that defines it (imported on first access)
_LAZY = {"fit": "softsbi.workflows.api", "open_run": "softsbi.workflows.api", "simulate": "softsbi.workflows.api",
         "load_scenario": "softsbi.workflows.api", "FitConfig": "softsbi.workflows.api",
         "FitResult": "softsbi.workflows.api", "Run": "softsbi.workflows.api",
         "load_recording": "softsbi.workflows.measurement", "simulate_recording": "softsbi.workflows.measurement",
         "import_diffcloud": "softsbi.workflows.measurement",
         "calibrate_run": "softsbi.workflows.api", "check": "softsbi.workflows.api",
         "diagnose": "softsbi.workflows.api", "compare": "softsbi.workflows.api"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'softsbi' has no attribute {name!r}")


__all__ = ["hookimpl", "Simulator", "Effect", "Observer", "PosteriorEstimator", "Executor", "Param",
           "ParamSpace", "Scenario", "Rollout", "Observation", "Recording", "SoftsbiError", "__version__",
           *_LAZY]
