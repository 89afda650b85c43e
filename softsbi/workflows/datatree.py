"""A run as an ArviZ DataTree (``softsbi.to_datatree``, the optional ``arviz`` extra: arviz-base), so that ArviZ reads
a fit's posterior (``az.summary``, its posterior and posterior-predictive plots)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from softsbi.core.errors import DependencyMissing, ParameterError
from softsbi.workflows.criticism.statistics import FEATURE_NAMES
from softsbi.workflows.criticism.stats import PosteriorPredictive, run_features, run_frames
from softsbi.workflows.fit.runs import RunView, load_run


def to_datatree(run: Any, draws: int = 1000, predictive: int | None = None, workers: int | None = None,
                seed: int = 0) -> Any:
    """A finished fit as an :class:`xarray.DataTree` in ArviZ's layout (arviz-base's ``from_dict``).

    Groups:

    - ``posterior``: ``draws`` draws of the fit's final posterior (chain 1), one variable per inferred parameter in
      its physical unit, with attributes ``units`` and ``description``: what ``az.summary`` and ArviZ's posterior
      plots read;
    - ``posterior_predictive`` and ``observed_data``: the variable ``summaries`` (m), the 14 summaries per frame that
      ``check`` tests (``feature``: mean, spread and quantiles of the cloud, its thickness) over the fit's metric
      frames (``frame``), under the fit's sensor model: ``(chain 1, draw S, frame, feature)`` for ``S`` successful
      posterior-predictive rollouts (the fit's own evaluation samples first, through the run's simulation bank, as
      ``check`` simulates them), ``(frame, feature)`` for the measurement: what ArviZ's posterior-predictive plots
      compare.

    Args:
        run: a run directory, or a run opened by ``softsbi.open_run``.
        draws: posterior draws (> 0).
        predictive: posterior-predictive rollouts to simulate (default: the fit's ``n_eval``; 0: no
            ``posterior_predictive`` group).
        workers: simulation worker processes (default: one per core). seed: the posterior draws' seed.

    Raises:
        DependencyMissing: arviz-base is not installed (the ``arviz`` extra), before anything is read.
        ParameterError: ``draws`` < 1 or ``predictive`` < 0. And :func:`~softsbi.workflows.fit.runs.load_run`'s
        errors (not a run, an unfinished fit, an image fit).
    """
    try:
        from arviz_base import from_dict  # optional: the 'arviz' extra
    except ImportError:
        raise DependencyMissing("to_datatree needs arviz-base (Python 3.11 or later), which is not installed: "
                                'pip install "softsbi[arviz]"') from None
    if int(draws) < 1 or (predictive is not None and int(predictive) < 0):
        raise ParameterError(f"to_datatree(draws={draws}, predictive={predictive}): draws must be at least 1 and "
                             f"predictive at least 0 (0: no posterior_predictive group)")
    view = run if isinstance(run, RunView) else load_run(Path(getattr(run, "path", run)), None, seed)
    space = view.space
    theta = view.posterior().sample(int(draws), seed=seed)
    data: dict[str, dict[str, np.ndarray]] = {"posterior": {n: theta[None, :, k] for k, n in enumerate(space.names)}}
    frames = run_frames(view)
    data["observed_data"] = {"summaries": run_features(view, view.dense).reshape(len(frames), len(FEATURE_NAMES))}
    n = len(view.post_theta) if predictive is None else int(predictive)
    if n:
        pool = PosteriorPredictive(view, workers, seed).ensure(n)
        data["posterior_predictive"] = {"summaries": pool.features.reshape(1, -1, len(frames), len(FEATURE_NAMES))}
    tree = from_dict(data, name=view.path.name, dims={"summaries": ["frame", "feature"]},
                     coords={"frame": frames, "feature": list(FEATURE_NAMES)},
                     attrs={"/": {"run": str(view.path), "backend": view.config.backend,
                                  "effects": ", ".join(view.effects)}})
    for p in space:
        tree["posterior"][p.name].attrs.update(units=p.unit, description=p.description)
    for group in ("observed_data", "posterior_predictive"):
        if group in tree.children:
            tree[group]["summaries"].attrs.update(units="m", description="check's summaries of the clouds per frame")
    return tree
