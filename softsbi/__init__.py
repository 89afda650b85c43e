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

Every name but :class:`SoftsbiError` is imported on first use, so ``import softsbi`` (e.g. by a plugin for
``hookimpl`` and the base classes, or by ``softsbi --help``) stays light.
"""
from softsbi.core.errors import SoftsbiError

#: public API name -> module that defines it (imported on first access)
_LAZY = {**{n: "softsbi.core.interfaces" for n in ("Effect", "Executor", "Observer", "PosteriorEstimator", "Simulator")},
         **{n: "softsbi.core.types" for n in ("Observation", "Param", "ParamSpace", "Recording", "Rollout", "Scenario")},
         "hookimpl": "softsbi.plugins.hookspecs",
         "fit": "softsbi.workflows.api", "open_run": "softsbi.workflows.api", "simulate": "softsbi.workflows.api",
         "load_scenario": "softsbi.workflows.api", "FitConfig": "softsbi.workflows.api",
         "FitResult": "softsbi.workflows.api", "Run": "softsbi.workflows.api",
         "load_recording": "softsbi.workflows.measurement", "simulate_recording": "softsbi.workflows.measurement",
         "import_diffcloud": "softsbi.workflows.measurement", "train_task": "softsbi.workflows.tasks.training",
         "calibrate_run": "softsbi.workflows.api", "check": "softsbi.workflows.api",
         "diagnose": "softsbi.workflows.api", "compare": "softsbi.workflows.api",
         "to_datatree": "softsbi.workflows.datatree"}


def __getattr__(name: str):
    if name == "__version__":
        try:
            from importlib.metadata import version  # start-up: only when the version is asked for
            return version("softsbi")
        except Exception:  # noqa: BLE001 - running from a source tree
            return "0.0.0"
    if name in _LAZY:
        import importlib  # start-up: the API's modules load when first used (PEP 562)
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'softsbi' has no attribute {name!r}")


__all__ = ["SoftsbiError", "__version__", *_LAZY]
