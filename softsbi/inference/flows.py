"""Normalising-flow posterior estimator (``flow``) from the ``zuko`` library.

Source: neural posterior estimation (NPE; Papamakarios & Murray 2016, Greenberg et al. 2019)
with a conditional normalising flow as the density estimator: neural spline flows (NSF;
Durkan et al., NeurIPS 2019) or masked autoregressive flows (MAF; Papamakarios et al.,
NeurIPS 2017), as implemented by ``zuko`` (Rozet et al., https://github.com/probabilists/zuko).
The SBI benchmark's NPE (Lueckmann et al., AISTATS 2021) used an NSF with 5 transforms,
50 hidden units and 10 bins; those are the defaults here, and the training defaults are sbi's
(batch 200, Adam 5e-4, 10 % validation, stop after 20 epochs without improvement, gradient
norm clipped at 5).

What it is conditioned on: the same inputs as the ``mdnn`` estimator -- states
``(N, T, 1+K, 3)`` become BayesSim summary statistics
(:func:`~softsbi.inference.summaries.bayessim_summaries`); flat feature vectors ``(N, F)``
(SBI-benchmark tasks) are used as they are. Inputs and ``theta_unit`` are standardised with
the training statistics; an optional MLP embedding net (``embedding`` widths) is trained
jointly with the flow.

In ``softsbi fit`` the run store keeps each round's flow as the estimator's state
(:meth:`FlowEstimator.state_dict`), so fits, truncated proposals (whose region is the flow's
highest-density region, found from its ``sample`` and ``log_prob``), ``open_run``, ``check``,
``diagnose`` and ``calibrate`` work with it as with any estimator.

``zuko`` is an optional extra (``pip install "softsbi[flows]"``); it is imported when the
estimator is constructed (:class:`~softsbi.core.errors.DependencyMissing` names the install
command otherwise, so ``softsbi fit`` says so before simulating). Registered through the ``softsbi_estimators`` hook as ``flow``.
"""
from __future__ import annotations

import copy
import time
from typing import Any, Callable, ClassVar, Mapping

import numpy as np
import torch
from torch import nn

from softsbi.core.distributions import Distribution
from softsbi.core.errors import DataError, DependencyMissing, ParameterError, ShapeError
from softsbi.core.interfaces import PosteriorEstimator
from softsbi.inference.neural_mdn import CONSTANT_FEATURE_RTOL, MAX_VAL_FRACTION, TARGET_STD_FLOOR, merge_config
from softsbi.inference.summaries import bayessim_summaries
from softsbi.inference.training import (fit_early_stopping, minibatches, threads_option, torch_threads,
                                        train_val_split)
from softsbi.plugins.hookspecs import hookimpl

__all__ = ["FlowEstimator", "FlowPosterior", "FlowNetwork", "zuko_available", "softsbi_estimators"]

STATE_FORMAT = "softsbi.flow/1"
MIN_SAMPLES = 10
#: rows per batch when a posterior draws or evaluates its density (bounds memory)
BATCH = 16384
FLOW_TYPES = ("nsf", "maf")

def zuko_available() -> bool:
    """Whether ``zuko`` can be imported."""
    try:
        import zuko  # noqa: F401 - optional: zuko
    except ImportError:
        return False
    return True


def _require_zuko():
    try:
        import zuko  # optional: zuko
    except ImportError as exc:
        raise DependencyMissing('estimator \'flow\' needs the zuko package: pip install "softsbi[flows]"') from exc
    return zuko


class FlowNetwork(nn.Module):
    """``embedding net -> conditional flow`` over standardised parameters.

    Args:
        context_dim: input features ``F`` (standardised).
        dim: parameter dimension ``D``.
        flow: ``"nsf"`` or ``"maf"`` (zuko's ``NSF`` / ``MAF``).
        transforms: number of autoregressive transforms.
        hidden: widths of each transform's conditioner (MADE) network.
        bins: spline bins (NSF only).
        embedding: widths of the MLP embedding net (empty: identity).
    """

    def __init__(self, context_dim: int, dim: int, flow: str = "nsf", transforms: int = 5,
                 hidden: tuple[int, ...] = (50, 50), bins: int = 10, embedding: tuple[int, ...] = ()):
        super().__init__()
        zuko = _require_zuko()
        layers: list[nn.Module] = []
        last = int(context_dim)
        for h in embedding:
            layers += [nn.Linear(last, int(h)), nn.ReLU()]
            last = int(h)
        self.embedding = nn.Sequential(*layers)
        kw: dict[str, Any] = {"transforms": int(transforms), "hidden_features": tuple(int(h) for h in hidden)}
        if flow == "nsf":
            self.flow = zuko.flows.NSF(features=int(dim), context=last, bins=int(bins), **kw)
        else:
            self.flow = zuko.flows.MAF(features=int(dim), context=last, **kw)

    def log_prob(self, u: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """``log q(u_i | z_i)`` ``(B,)`` for standardised ``u (B, D)`` and inputs ``z (B, F)``."""
        return self.flow(self.embedding(z)).log_prob(u)

    def at(self, z: torch.Tensor) -> Any:
        """The flow ``p(u | z)`` at one input ``z (1, F)``: a zuko ``NormalizingFlow`` (``sample(shape)``,
        ``log_prob(u (B, D))``) over standardised ``u``.

        Every conditioner's input layer gets the context's share folded into its bias,
        ``W [u; c] + b = W_u u + (W_c c + b)``: the same density, but no draw carries the ``F`` context
        features through it (an autoregressive flow runs its conditioners ``D`` times per draw, so with
        BayesSim summaries, ``F`` ~ 10^3, this makes sampling several times faster). A transform that is not
        a masked autoregressive one (``D = 1``) keeps the context as it is.
        """
        # optional: zuko
        from zuko.distributions import NormalizingFlow
        from zuko.nn import MaskedLinear  # optional: zuko
        from zuko.transforms import ComposedTransform  # optional: zuko

        c = self.embedding(z)[0]
        parts = []
        for t in self.flow.transform.transforms:
            first = getattr(t, "hyper", [None])[0]
            if not isinstance(first, MaskedLinear):
                parts.append(t(c))
                continue
            w = first.mask * first.weight  # columns: the D features, then the context (zuko's layout)
            d = w.shape[1] - c.shape[-1]
            lin = torch.nn.utils.skip_init(nn.Linear, d, w.shape[0])  # no draw from torch's generator
            lin.weight, lin.bias = nn.Parameter(w[:, :d]), nn.Parameter(first.bias + w[:, d:] @ c)
            folded = copy.copy(t)
            folded._modules = dict(t._modules)  # a copy of the module table: the estimator's own stays intact
            folded.hyper = nn.Sequential(lin, *list(t.hyper)[1:])
            parts.append(folded(None))
        return NormalizingFlow(ComposedTransform(*parts), self.flow.base(None))


class FlowPosterior(Distribution):
    """The flow's posterior ``q(theta_unit | x_o)`` at one observation, over unbounded unit-cube
    coordinates (like :class:`~softsbi.core.distributions.MixtureOfGaussians`: restrict draws to
    ``[0, 1]^D`` for the prior's support).

    It offers ``dim``, :meth:`sample` and :meth:`log_prob` (exact) and Monte-Carlo :meth:`mean` /
    :meth:`cov`.
    """

    def __init__(self, estimator: "FlowEstimator", z: np.ndarray):
        self._est = estimator
        self._z = np.asarray(z, np.float32).reshape(1, -1)
        self.dim = int(estimator._u_mean.shape[0])
        self._flow: Any = None

    def _at(self) -> Any:
        """The network's flow at this observation (:meth:`FlowNetwork.at`), built once."""
        if self._flow is None:
            with torch.no_grad():
                self._flow = self._est._net.at(torch.as_tensor(self._z))
        return self._flow

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` draws ``(n, D)`` (float64, unit-cube coordinates); seeded by ``rng``."""
        est = self._est
        out = []
        with torch_threads(est._threads()), torch.no_grad(), torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(rng.integers(2**62)))  # zuko draws from torch's global generator
            flow = self._at()
            for i in range(0, int(n), BATCH):
                out.append(flow.sample((min(BATCH, int(n) - i),)).double().numpy())
        s = np.concatenate(out) if out else np.zeros((0, self.dim))
        return s * est._u_std.astype(np.float64) + est._u_mean.astype(np.float64)

    def log_prob(self, u: np.ndarray) -> np.ndarray:
        """Log density ``(n,)`` (nats, unit-cube coordinates) at ``u (n, D)``."""
        est = self._est
        u = np.atleast_2d(np.asarray(u, np.float64))
        if u.shape[1] != self.dim:
            raise ShapeError(f"u must have shape (n, {self.dim}), got {u.shape}")
        us = ((u - est._u_mean) / est._u_std).astype(np.float32)
        out = []
        with torch_threads(est._threads()), torch.no_grad():
            flow = self._at()
            for i in range(0, len(us), BATCH):
                out.append(flow.log_prob(torch.as_tensor(us[i:i + BATCH])).double().numpy())
        lp = np.concatenate(out) if out else np.zeros(0)
        return lp - float(np.log(est._u_std.astype(np.float64)).sum())

    def mean(self, n: int = 20000, seed: int = 0) -> np.ndarray:
        """Monte-Carlo mean ``(D,)`` from ``n`` draws."""
        return self.sample(n, np.random.default_rng(seed)).mean(0)

    def cov(self, n: int = 20000, seed: int = 0) -> np.ndarray:
        """Monte-Carlo covariance ``(D, D)`` from ``n`` draws."""
        return np.atleast_2d(np.cov(self.sample(n, np.random.default_rng(seed)).T))



class FlowEstimator(PosteriorEstimator):
    """NPE with a conditional normalising flow (zuko NSF or MAF) as the density estimator.

    Shapes: ``fit(theta_unit (N, D), x (N, T, 1+K, 3) | (N, F))``; ``posterior_at(x_o)`` for one
    observation of the training event shape (``(T, 1+K, 3)`` or ``(F,)``, optionally with a
    leading 1) -> :class:`FlowPosterior` over ``D`` unit-cube coordinates.

    Config options (defaults: the SBI benchmark's NSF and sbi's training settings):
        flow: ``"nsf"`` (default) or ``"maf"``. transforms: 5. hidden: conditioner widths, (50, 50).
        bins: spline bins (NSF), 10. embedding: MLP embedding widths, () (identity).
        lr: Adam learning rate, 5e-4. batch_size: 200. val_fraction: 0.1. patience: 20.
        max_epochs: 2000. min_epochs: 1. grad_clip: 5.0. max_seconds: wall-clock budget, None.
        num_threads: torch threads (restored afterwards), default 1.

    Raises:
        ParameterError: unknown or bad option. DependencyMissing: ``zuko`` not installed.
        ShapeError, DataError: bad inputs (see :meth:`fit`).
    """

    name: ClassVar[str] = "flow"
    sequential: ClassVar[bool] = True
    DEFAULTS: ClassVar[dict[str, Any]] = {
        "flow": "nsf", "transforms": 5, "hidden": (50, 50), "bins": 10, "embedding": (),
        "lr": 5e-4, "batch_size": 200, "val_fraction": 0.1, "patience": 20, "max_epochs": 2000,
        "min_epochs": 1, "grad_clip": 5.0, "max_seconds": None, "num_threads": 1}

    def __init__(self, **config: Any):
        _require_zuko()
        cfg = merge_config(self.name, self.DEFAULTS, config)
        cfg["hidden"] = tuple(int(h) for h in cfg["hidden"])
        cfg["embedding"] = tuple(int(h) for h in cfg["embedding"])
        if cfg["flow"] not in FLOW_TYPES:
            raise ParameterError(f"flow must be one of {list(FLOW_TYPES)} (got {cfg['flow']!r})")
        if not 0.0 < float(cfg["val_fraction"]) < MAX_VAL_FRACTION:
            raise ParameterError(f"val_fraction must be in (0, {MAX_VAL_FRACTION}), got {cfg['val_fraction']}")
        if int(cfg["transforms"]) < 1:
            raise ParameterError(f"transforms must be an integer >= 1 (got {cfg['transforms']})")
        super().__init__(**cfg)
        self._net: FlowNetwork | None = None
        self._x_shape: tuple[int, ...] | None = None
        self._in_mean = self._in_std = None
        self._u_mean = self._u_std = None
        self.fit_info: dict[str, Any] = {}

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """All config options with their default values."""
        return dict(cls.DEFAULTS)

    def _threads(self) -> int:
        return threads_option(self.config.get("num_threads"))

    @staticmethod
    def summary_statistics(x: np.ndarray) -> np.ndarray:
        """``(N, F)`` float32 inputs of the flow: BayesSim summaries of states ``(N, T, 1+K, 3)``
        (as ``mdnn``), flat vectors ``(N, F)`` as they are.

        Raises:
            ShapeError: ``x`` is neither.
        """
        x = np.asarray(x, np.float64)
        if x.ndim == 4 and x.shape[-1] == 3 and x.shape[2] >= 2:
            return bayessim_summaries(x).astype(np.float32)
        if x.ndim == 2 and x.shape[1] >= 1:
            return x.astype(np.float32)
        raise ShapeError(f"x must have shape (N, T, 1+K, 3) (states, K >= 1) or (N, F) (flat feature vectors), "
                         f"got {x.shape}")

    def _build(self, F: int, D: int) -> FlowNetwork:
        c = self.config
        return FlowNetwork(F, D, c["flow"], int(c["transforms"]), c["hidden"], int(c["bins"]), c["embedding"])

    def fit(self, theta_unit: np.ndarray, x: np.ndarray, *, seed: int = 0,
            progress: Callable[[int, int, float], None] | None = None,
            groups: np.ndarray | None = None) -> dict[str, Any]:
        """Train ``q(theta_unit | x)`` by maximum likelihood (NPE's first-round loss) with early stopping on
        a held-out split (:func:`~softsbi.inference.training.fit_early_stopping`; best weights kept; with
        ``groups`` ``(N,)``, samples of one simulation, whole groups are held out).

        Args:
            theta_unit: ``(N, D)`` (or ``(N,)``) parameters in the unit cube.
            x: ``(N, T, 1+K, 3)`` states in metres, or ``(N, F)`` flat feature vectors.
            seed: seeds the weight init, the split and the batch order (same seed, same estimator).
            progress: ``progress(epoch, max_epochs, train_loss)`` after every epoch.

        Returns:
            ``{"epochs", "best_epoch", "train_loss", "val_loss", "seconds", "n_train", "n_val"}``; losses
            are mean negative log-likelihoods in nats, unit-cube coordinates.

        Raises:
            DependencyMissing: ``zuko`` not installed. ShapeError: bad shapes or mismatched N.
            DataError: non-finite values, fewer than 10 simulations. RuntimeError: diverged in epoch 1.
        """
        _require_zuko()
        t0 = time.perf_counter()
        z = self.summary_statistics(x)
        u = np.asarray(theta_unit, np.float64)
        u = u[:, None] if u.ndim == 1 else u
        if u.ndim != 2 or len(u) != len(z):
            raise ShapeError(f"theta_unit must be (N, D) with the N of x; got theta_unit {u.shape}, x {np.shape(x)}")
        if not (np.isfinite(u).all() and np.isfinite(z).all()):
            raise DataError("theta_unit or x has non-finite values (NaN/inf); drop failed simulations before fitting")
        if len(u) < MIN_SAMPLES:
            raise DataError(f"need at least {MIN_SAMPLES} simulations to fit an estimator, got {len(u)}")
        c = self.config
        rng = np.random.default_rng(seed)
        tr, va = train_val_split(len(u), float(c["val_fraction"]), rng, min_train=2, groups=groups)
        zm, zsd = z[tr].mean(0), z[tr].std(0)
        zsd = np.where(zsd > CONSTANT_FEATURE_RTOL * max(float(zsd.max()), 1e-30), zsd, 1.0)
        um, usd = u[tr].mean(0), u[tr].std(0)
        usd = np.where(usd > 1e-9, np.maximum(usd, TARGET_STD_FLOOR * float(usd.max())), 1.0)
        self._in_mean, self._in_std = zm.astype(np.float32), zsd.astype(np.float32)
        self._u_mean, self._u_std = um.astype(np.float32), usd.astype(np.float32)
        self._x_shape = tuple(np.shape(x)[1:])
        zs = torch.as_tensor(((z - zm) / zsd).astype(np.float32))
        us = torch.as_tensor(((u - um) / usd).astype(np.float32))
        log_jac = float(np.log(usd).sum())  # NLL shift from standardised to unit-cube coordinates
        with torch_threads(self._threads()):
            torch.manual_seed(seed)
            net = self._build(zs.shape[1], us.shape[1])
            z_tr, u_tr, z_va, u_va = zs[tr], us[tr], zs[va], us[va]

            def nll(b: np.ndarray) -> torch.Tensor:
                idx = torch.as_tensor(b)
                return -net.log_prob(u_tr[idx], z_tr[idx]).mean()

            def validate() -> float:
                with torch.no_grad():
                    return float(-net.log_prob(u_va, z_va).mean()) + log_jac

            info = fit_early_stopping(
                net, nll, lambda: minibatches(len(tr), int(c["batch_size"]), rng),
                validate=validate, max_epochs=int(c["max_epochs"]), patience=int(c["patience"]),
                min_epochs=int(c["min_epochs"]), lr=float(c["lr"]),
                grad_clip=float(c["grad_clip"]) if c["grad_clip"] else None, loss_offset=log_jac,
                max_seconds=None if c["max_seconds"] is None else float(c["max_seconds"]), progress=progress, t0=t0)
        if info["best_epoch"] == 0:
            raise RuntimeError(f"estimator 'flow' training diverged (non-finite loss) in the first epoch; try a "
                               f"smaller lr (now {c['lr']})")
        net.eval()
        self._net = net
        self.fit_info = {"epochs": info["epochs"], "best_epoch": info["best_epoch"],
                         "train_loss": info["train_loss"], "val_loss": info["val_loss"],
                         "seconds": time.perf_counter() - t0, "n_train": int(len(tr)), "n_val": int(len(va))}
        return dict(self.fit_info)

    def posterior_at(self, x_obs: np.ndarray) -> FlowPosterior:  # type: ignore[override]
        """The posterior ``q(theta_unit | x_o)`` at ``x_o = x_obs`` (training event shape, optionally with a
        leading 1), as a :class:`FlowPosterior` (``sample``, ``log_prob``).

        Raises:
            RuntimeError: not fitted. ShapeError: wrong shape. DataError: non-finite values.
        """
        if self._net is None:
            raise RuntimeError("estimator 'flow' is not fitted: call fit(theta_unit, x) (or load_state_dict) "
                               "before posterior_at()")
        x = np.asarray(x_obs, np.float64)
        if x.shape == (1,) + tuple(self._x_shape):
            x = x[0]
        if x.shape != tuple(self._x_shape):
            raise ShapeError(f"x_obs must have shape {self._x_shape} (the training event shape), got {x.shape}")
        if not np.isfinite(x).all():
            raise DataError("the observation contains non-finite values (NaN/inf)")
        z = (self.summary_statistics(x[None]) - self._in_mean) / self._in_std
        return FlowPosterior(self, z)

    def state_dict(self) -> dict[str, Any]:
        """Plain dict (NumPy arrays, numbers, strings, lists) restoring the fitted estimator.

        Raises:
            RuntimeError: not fitted.
        """
        if self._net is None:
            raise RuntimeError("estimator 'flow' is not fitted; nothing to save")
        cfg = {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.config.items()}
        return {"format": STATE_FORMAT, "estimator": self.name, "config": cfg, "x_shape": list(self._x_shape),
                "in_mean": np.array(self._in_mean), "in_std": np.array(self._in_std),
                "u_mean": np.array(self._u_mean), "u_std": np.array(self._u_std),
                "params": {k: v.detach().cpu().numpy().copy() for k, v in self._net.state_dict().items()},
                "fit_info": dict(self.fit_info)}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore from :meth:`state_dict` (config included).

        Raises:
            DataError: ``state`` is not a ``flow`` estimator state. DependencyMissing: no ``zuko``.
        """
        if state.get("format") != STATE_FORMAT or state.get("estimator") != self.name:
            raise DataError(f"state is not a 'flow' estimator state ({STATE_FORMAT}); got format "
                            f"{state.get('format')!r}, estimator {state.get('estimator')!r}")
        self.__init__(**dict(state["config"]))  # validates the options again
        self._x_shape = tuple(int(s) for s in state["x_shape"])
        self._in_mean = np.asarray(state["in_mean"], np.float32)
        self._in_std = np.asarray(state["in_std"], np.float32)
        self._u_mean = np.asarray(state["u_mean"], np.float32)
        self._u_std = np.asarray(state["u_std"], np.float32)
        net = self._build(int(self._in_mean.shape[0]), int(self._u_mean.shape[0]))
        net.load_state_dict({k: torch.as_tensor(np.asarray(v)) for k, v in state["params"].items()})
        net.eval()
        self._net = net
        self.fit_info = dict(state.get("fit_info", {}))


@hookimpl
def softsbi_estimators() -> list[type[PosteriorEstimator]]:
    """Estimators of this module (``flow``)."""
    return [FlowEstimator]
