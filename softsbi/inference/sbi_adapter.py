"""``sbi``'s NPE with a mixture-density network behind softsbi's estimator interface (``sbi-npe``).

Source: the ``sbi`` toolbox (Tejero-Cantero et al., JOSS 2020; tested with sbi 0.27), NPE
(Papamakarios & Murray 2016; Greenberg et al. 2019) with ``posterior_nn(model="mdn")``.
Used as a conditional density estimator only: it is trained with the first-round
(maximum-likelihood) loss on whatever data it gets, and softsbi's loop applies its own
proposal correction (:class:`~softsbi.core.distributions.PosteriorChain`), exactly as for
the built-in estimators. That makes it a like-for-like peer of ``mdnn`` for checking
softsbi's MDN against a reference implementation.

Inputs: states ``(N, T, 1+K, 3)`` are turned into BayesSim summaries (as ``mdnn`` does);
flat ``(N, F)`` arrays (benchmark tasks) are used as they are. ``sbi`` z-scores inputs and
parameters itself.

``sbi`` is an optional extra (``pip install softsbi[sbi]``); this module imports it only
when the estimator is used and raises :class:`~softsbi.core.errors.DependencyMissing`
naming the install command otherwise, so ``softsbi plugins`` works without it.
"""
from __future__ import annotations

import contextlib
import io
import time
from typing import Any, Callable, ClassVar, Mapping

import numpy as np
import torch

from softsbi.core.distributions import MixtureOfGaussians
from softsbi.core.errors import DependencyMissing, ShapeError
from softsbi.core.interfaces import PosteriorEstimator
from softsbi.inference.neural_mdn import check_training_pair, merge_config
from softsbi.inference.summaries import bayessim_summaries
from softsbi.inference.training import threads_option, torch_threads

__all__ = ["SbiNPEEstimator", "sbi_available"]


def sbi_available() -> bool:
    """Whether ``sbi`` can be imported."""
    try:
        import sbi  # noqa: F401 - optional: sbi
    except ImportError:
        return False
    return True


def _require_sbi():
    try:
        import sbi  # optional: sbi (and its submodules below)
        from sbi.inference import NPE  # optional: sbi
        from sbi.neural_nets import posterior_nn  # optional: sbi
    except ImportError as exc:
        raise DependencyMissing("estimator 'sbi-npe' needs the sbi package: pip install 'softsbi[sbi]' "
                                "(or pip install sbi after installing the CPU torch wheel)") from exc
    return sbi, NPE, posterior_nn


class SbiNPEEstimator(PosteriorEstimator):
    """NPE from ``sbi`` with an MDN density estimator, as a softsbi :class:`PosteriorEstimator`.

    Shapes: ``fit(theta_unit (N, D), x (N, T, 1+K, 3) | (N, F))``; ``posterior_at(x_obs)`` for one
    observation of the training event shape -> :class:`MixtureOfGaussians` with
    ``num_components`` full-covariance components over ``D`` (unit-cube coordinates).

    Config options (sbi's defaults except where noted):
        num_components: default 4 (the paper's posteriors; sbi's benchmark used 10).
        hidden_features: default 50. max_epochs: default 2**31 - 1 (sbi: until converged).
        stop_after_epochs: patience, default 20. batch_size: default 200 (sbi's 200).
        lr: default 5e-4. val_fraction: default 0.1. num_threads: torch threads, default 1.

    Raises:
        DependencyMissing: ``sbi`` not installed (at fit / load time).
        ParameterError: unknown option. ShapeError, DataError: bad inputs.
    """

    name: ClassVar[str] = "sbi-npe"
    sequential: ClassVar[bool] = True
    DEFAULTS: ClassVar[dict[str, Any]] = {"num_components": 4, "hidden_features": 50, "max_epochs": 2**31 - 1,
                                          "stop_after_epochs": 20, "batch_size": 200, "lr": 5e-4,
                                          "val_fraction": 0.1, "num_threads": 1}

    def __init__(self, **config: Any):
        super().__init__(**merge_config(self.name, self.DEFAULTS, config))
        self._de = None
        self._event_shape: tuple[int, ...] | None = None
        self.fit_info: dict[str, Any] = {}

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        return dict(cls.DEFAULTS)

    @staticmethod
    def _features(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, np.float64)
        if x.ndim == 4:
            return bayessim_summaries(x).astype(np.float32)
        if x.ndim == 2:
            return x.astype(np.float32)
        raise ShapeError(f"x must have shape (N, T, 1+K, 3) or (N, F), got {x.shape}")

    def fit(self, theta_unit: np.ndarray, x: np.ndarray, *, seed: int = 0,
            progress: Callable[[int, int, float], None] | None = None) -> dict[str, Any]:
        """Train sbi's NPE (first-round loss) on ``theta_unit (N, D)`` (unit cube), ``x``; softsbi's loop
        applies the proposal correction, as for the built-in estimators.

        Returns:
            ``{"epochs", "val_loss" (best validation log-prob, negated), "seconds", "n_train"}``.
            ``progress`` is called once at the end (sbi trains in one call).

        Raises:
            DependencyMissing: ``sbi`` not installed. ShapeError, DataError: bad inputs.
        """
        _, NPE, posterior_nn = _require_sbi()
        t0 = time.perf_counter()
        f = self._features(x)
        u = check_training_pair(theta_unit, f, np.shape(x))
        c = self.config
        with torch_threads(threads_option(c.get("num_threads"))):
            torch.manual_seed(seed)
            builder = posterior_nn(model="mdn", num_components=int(c["num_components"]),
                                   hidden_features=int(c["hidden_features"]))
            inf = NPE(prior=None, density_estimator=builder, show_progress_bars=False)
            # prior=None: sbi then only z-scores; we never sample through sbi's posterior
            inf.append_simulations(torch.as_tensor(u, dtype=torch.float32), torch.as_tensor(f))
            with contextlib.redirect_stdout(io.StringIO()):  # sbi prints a convergence line
                de = inf.train(training_batch_size=int(c["batch_size"]), learning_rate=float(c["lr"]),
                               validation_fraction=float(c["val_fraction"]),
                               stop_after_epochs=int(c["stop_after_epochs"]),
                               max_num_epochs=int(c["max_epochs"]), show_train_summary=False)
            de.eval()
        self._de = de
        self._event_shape = tuple(np.shape(x)[1:])
        summ = getattr(inf, "_summary", {})
        epochs = int(summ.get("epochs_trained", [0])[-1]) if summ.get("epochs_trained") else 0
        best = summ.get("best_validation_loss", [np.nan])[-1] if summ.get("best_validation_loss") else np.nan
        self.fit_info = {"epochs": epochs, "val_loss": float(best), "seconds": time.perf_counter() - t0,
                         "n_train": int(len(u))}
        if progress is not None:
            progress(epochs, epochs, float(best))
        return dict(self.fit_info)

    def posterior_at(self, x_obs: np.ndarray) -> MixtureOfGaussians:
        """The posterior ``q(theta_unit | x_o)`` at ``x_o = x_obs``, read off sbi's MDN (its z-scoring
        of ``theta_unit`` undone).

        Raises:
            RuntimeError: not fitted. ShapeError: wrong shape.
        """
        if self._de is None:
            raise RuntimeError("estimator 'sbi-npe' is not fitted: call fit(theta_unit, x) first")
        x = np.asarray(x_obs, np.float64)
        if x.shape == (1,) + tuple(self._event_shape):
            x = x[0]
        if x.shape != tuple(self._event_shape):
            raise ShapeError(f"x_obs must have shape {self._event_shape}, got {x.shape}")
        f = torch.as_tensor(self._features(x[None]))
        de = self._de
        with torch.no_grad():
            mog = de.get_uncorrected_mog(f)
            logits, means, prec = mog.logits[0].double(), mog.means[0].double(), mog.precisions[0].double()
            cov = torch.linalg.inv(prec)
            cov = 0.5 * (cov + cov.transpose(-1, -2))
            shift = getattr(de, "_transform_shift", None)
            scale = getattr(de, "_transform_scale", None)
            if getattr(de, "_prior_transform_module", None) is not None:
                raise RuntimeError("sbi-npe: unexpected prior transform in sbi's MDN (unsupported sbi version)")
            if scale is not None:
                scale, shift = scale.double(), shift.double()
                means = means * scale + shift
                cov = scale[:, None] * cov * scale[None, :]
            L = torch.linalg.cholesky(cov)
            w = torch.softmax(logits, -1)
        return MixtureOfGaussians(w.numpy(), means.numpy(), L.numpy())

    def state_dict(self) -> dict[str, Any]:
        """Not persisted (sbi modules are not plain arrays): returns the config only; a stored
        run's per-round mixtures remain available from the run store."""
        return {"format": "softsbi.sbi-npe/0", "estimator": self.name, "config": dict(self.config)}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.config = {**self.DEFAULTS, **dict(state.get("config", {}))}
