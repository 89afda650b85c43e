"""The fitted half of a neural MDN estimator: standardised observations -> an ensemble of mixture density
networks -> the posterior ``q(theta_unit | x)`` in unit-cube coordinates, and the (numpy) state dict.

:class:`MDNPosterior` is the base of :class:`~softsbi.inference.neural_mdn.NeuralMDNEstimator`, which adds the
training (fit, ensembles, recalibration) and the hooks :meth:`summary_statistics`, ``_build`` and
``defaults`` that this half calls.
"""
from __future__ import annotations

import warnings
from typing import Any, ClassVar, Mapping

import numpy as np
import torch

from softsbi.core.distributions import MixtureOfGaussians
from softsbi.core.errors import DataError, ShapeError
from softsbi.core.interfaces import PosteriorEstimator
from softsbi.inference.mdn import MDNNetwork, MDNParams, mdn_log_prob
from softsbi.inference.recalibration import marginal_affine
from softsbi.inference.training import predict_batched, threads_option, torch_threads

__all__ = ["MDNPosterior", "STATE_FORMAT"]

#: the ``format`` entry of :meth:`MDNPosterior.state_dict`
STATE_FORMAT = "softsbi.neural-mdn/1"


class MDNPosterior(PosteriorEstimator):
    """A fitted (or loaded) ensemble of MDNs on standardised summary statistics: posteriors and persistence.

    State (set by the subclass's ``fit`` or by :meth:`load_state_dict`): the members ``_nets`` (``_net`` the
    first), the input standardisation ``_in_mean``/``_in_std``, the target standardisation
    ``_u_mean``/``_u_std`` (unit cube), the recalibration ``_cov_scale`` and ``_marginal``, the training
    shapes ``_x_shape`` (one observation) and ``_z_shape`` (its summary statistics), and ``fit_info``.
    """

    #: Number of dimensions of ONE observation: 3 for states ``(T, 1+K, 3)``; 1 for flat
    #: feature vectors ``(F,)`` (benchmark tasks; see ``check_x_shape``).
    x_event_ndim: ClassVar[int] = 3
    _net: MDNNetwork | None
    _nets: list[MDNNetwork]
    _x_shape: tuple[int, ...] | None
    _z_shape: tuple[int, ...] | None

    def summary_statistics(self, x: np.ndarray) -> np.ndarray:
        """Fixed (non-trainable) summary statistics of observations, ``(N, T, 1+K, 3) -> (N, ...)``
        float32 (the trainable part is the subclass's ``embedding_net``). Default: the observation itself."""
        return np.asarray(x, dtype=np.float32)

    def check_x_obs_shape(self, shape: tuple[int, ...]) -> bool:
        """Whether one observation of shape ``(T, 1+K, 3)`` is acceptable after fit
        (default: exactly the training shape)."""
        return tuple(shape) == self._x_shape

    def _threads(self) -> int:
        return threads_option(self.config.get("num_threads"))

    def _standardise(self, z: np.ndarray) -> np.ndarray:
        return ((z - self._in_mean) / self._in_std).astype(np.float32)

    def _predict(self, zs: np.ndarray, chunk: int = 64) -> MDNParams:
        """Mixture parameters in unit-cube coordinates for standardised inputs (no grad)."""
        assert self._net is not None
        parts = []
        nets = self._nets or [self._net]
        for net in nets:
            outs = predict_batched(lambda z, net=net: net(torch.as_tensor(z)), zs, batch_size=chunk, module=net)
            parts.append(MDNParams(torch.cat([o.log_weights for o in outs]) - float(np.log(len(nets))),
                                   torch.cat([o.means for o in outs]), torch.cat([o.scale_tril for o in outs])))
        p = parts[0] if len(parts) == 1 else MDNParams(torch.cat([q.logits for q in parts], 1),
                                                       torch.cat([q.means for q in parts], 1),
                                                       torch.cat([q.scale_tril for q in parts], 1))
        p = p.affine(torch.as_tensor(self._u_mean), torch.as_tensor(self._u_std))
        if getattr(self, "_marginal", None) is not None:
            p = marginal_affine(p, *self._marginal)
        scale = float(getattr(self, "_cov_scale", 1.0))
        return p if scale == 1.0 else MDNParams(p.logits, p.means, p.scale_tril * scale)

    def _require_fitted(self) -> None:
        """Raise RuntimeError (naming the fix) unless fitted or loaded."""
        if self._net is None:
            raise RuntimeError(f"estimator '{self.name}' is not fitted: call fit(theta_unit, x) (or "
                               f"load_state_dict) before posterior_at()")

    def _prepare_obs(self, x_obs: np.ndarray) -> np.ndarray:
        """Standardised summary statistics of observations ``(n, T, 1+K, 3)`` (raises as :meth:`posterior_at`)."""
        self._require_fitted()
        x = np.asarray(x_obs, dtype=np.float64)
        if x.ndim != 1 + self.x_event_ndim or not self.check_x_obs_shape(tuple(x.shape[1:])):
            raise ShapeError(f"observations must have shape (n, {self._expected()}), got {x.shape}")
        if not np.isfinite(x).all():
            raise DataError("the observation contains non-finite values (NaN/inf)")
        return self._standardise(self.summary_statistics(x))

    def _expected(self) -> str:
        T, R, d = self._x_shape  # type: ignore[misc]
        return f"{T}, {R}, {d}"

    def posterior_at(self, x_obs: np.ndarray) -> MixtureOfGaussians:
        """The posterior ``q(theta_unit | x_o)`` at the observation ``x_o = x_obs``, unit-cube coordinates.

        Args:
            x_obs: ``(T, 1+K, 3)`` (or ``(1, T, 1+K, 3)``) in metres, same T as in fit.

        Returns:
            :class:`MixtureOfGaussians` with ``C = n_components`` components over ``D`` dims.

        Raises:
            RuntimeError: not fitted. ShapeError: wrong shape (the message names the expected
            one). DataError: non-finite values.
        """
        self._require_fitted()
        x = np.asarray(x_obs, dtype=np.float64)
        if x.ndim == self.x_event_ndim + 1 and x.shape[0] == 1:
            x = x[0]
        if x.ndim != self.x_event_ndim or not self.check_x_obs_shape(x.shape):
            raise ShapeError(f"x_obs must have shape ({self._expected()}) (T, 1+K, 3), got {x.shape}")
        return self.posteriors_at(x[None])[0]

    def posteriors_at(self, x: np.ndarray) -> list[MixtureOfGaussians]:
        """Batched :meth:`posterior_at`: ``x (n, T, 1+K, 3)`` -> list of ``n`` mixtures.

        Raises:
            RuntimeError, ShapeError, DataError: as :meth:`posterior_at`.
        """
        zs = self._prepare_obs(x)
        with torch_threads(self._threads()):
            return self._predict(zs).to_mixtures()

    def conditionals(self, x: np.ndarray) -> list[MixtureOfGaussians]:
        """Deprecated alias of :meth:`posteriors_at`.

        Warns:
            DeprecationWarning: always.
        """
        warnings.warn("conditionals() is deprecated; use posteriors_at()", DeprecationWarning, stacklevel=2)
        return self.posteriors_at(x)

    def log_prob(self, theta_unit: np.ndarray, x: np.ndarray) -> np.ndarray:
        """``log q(theta_unit_i | x_i)`` ``(n,)`` for ``theta_unit (n, D)``, ``x (n, T, 1+K, 3)``
        (e.g. held-out NLL, nats in unit-cube coordinates).

        Raises:
            RuntimeError, ShapeError, DataError: as :meth:`posterior_at`.
        """
        zs = self._prepare_obs(x)
        u = np.atleast_2d(np.asarray(theta_unit, dtype=np.float64))
        p = self._predict(zs)
        return mdn_log_prob(MDNParams(p.logits.double(), p.means.double(), p.scale_tril.double()),
                            torch.as_tensor(u)).numpy()

    def state_dict(self) -> dict[str, Any]:
        """Plain dict (NumPy arrays, numbers, strings, lists) restoring the fitted estimator.

        Raises:
            RuntimeError: not fitted.
        """
        if self._net is None:
            raise RuntimeError(f"estimator '{self.name}' is not fitted; nothing to save")
        cfg = {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.config.items()}
        return {
            "format": STATE_FORMAT, "estimator": self.name, "config": cfg,
            "x_shape": list(self._x_shape), "z_shape": list(self._z_shape),
            "dim": int(self._u_mean.shape[0]),
            "in_mean": np.array(self._in_mean), "in_std": np.array(self._in_std),
            "u_mean": np.array(self._u_mean), "u_std": np.array(self._u_std),
            "params": {k: v.detach().cpu().numpy().copy() for k, v in self._net.state_dict().items()},
            "ensemble_params": [{k: v.detach().cpu().numpy().copy() for k, v in net.state_dict().items()}
                                for net in self._nets[1:]],
            "fit_info": dict(self.fit_info), "cov_scale": float(getattr(self, "_cov_scale", 1.0)),
            **({"marginal_scale": np.array(self._marginal[0]), "marginal_shift": np.array(self._marginal[1])}
               if getattr(self, "_marginal", None) is not None else {}),
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore from :meth:`state_dict` (config included).

        Raises:
            DataError: ``state`` is not a state of this estimator class (format or name).
        """
        if state.get("format") != STATE_FORMAT or state.get("estimator") != self.name:
            raise DataError(f"state is not a '{self.name}' estimator state ({STATE_FORMAT}); got format "
                            f"{state.get('format')!r}, estimator {state.get('estimator')!r}")
        self.config = {**self.defaults(), **dict(state["config"])}
        self.config["hidden"] = tuple(int(h) for h in self.config["hidden"])
        self._x_shape = tuple(int(s) for s in state["x_shape"])
        self._z_shape = tuple(int(s) for s in state["z_shape"])
        self._in_mean = np.asarray(state["in_mean"], np.float32)
        self._in_std = np.asarray(state["in_std"], np.float32)
        self._u_mean = np.asarray(state["u_mean"], np.float32)
        self._u_std = np.asarray(state["u_std"], np.float32)
        z_example = np.zeros((2,) + self._z_shape, np.float32)
        nets = []
        for params in [state["params"]] + list(state.get("ensemble_params") or []):
            net = self._build(z_example, int(state["dim"]))
            net.load_state_dict({k: torch.as_tensor(np.asarray(v)) for k, v in params.items()})
            net.eval()
            nets.append(net)
        self._nets = nets
        self._net = nets[0]
        self._cov_scale = float(state.get("cov_scale", 1.0))
        self._marginal = ((np.asarray(state["marginal_scale"], float), np.asarray(state["marginal_shift"], float))
                          if "marginal_scale" in state else None)
        self.fit_info = dict(state.get("fit_info", {}))
