"""The paper's other estimators: MDRFF, BayesZoom-RKHS, NN-bulk, GP-bulk (plus a flat-vector MDN).

Sources:
    * BayesSim (Ramos, Possas, Fox, RSS 2019), Sec. 3-4: the MDN on trajectory summaries
      (``mdnn``, in :mod:`.estimators`) and its random-Fourier-feature variant MDRFF
      (``mdrff`` here): fixed random Fourier features of the summaries (Rahimi & Recht 2007)
      with the mixture parameters linear in those features.
    * Antonova et al., "A Bayesian Treatment of Real-to-Sim for Deformable Object
      Manipulation" (RA-L 2022), Sec. V (baselines): BayesZoom-RKHS (an MLP on the RKHS-net
      embedding predicts the posterior mean; the validation L1 error is used as the std of
      a unimodal Gaussian), and the "bulk" baselines trained once on the whole simulation
      budget drawn from the prior: NN-bulk and GP-bulk (GPyTorch regression).

Interpretations where the paper leaves details open (documented choices):
    * ``nn-bulk`` = RKHS-net embedding -> MLP -> one full-covariance Gaussian (an MDN with
      ``C = 1``), trained on prior samples only (``sequential = False``); it isolates what
      rounds and multimodality add over plain amortised regression with uncertainty.
    * ``gp-bulk`` = one exact GP per parameter (constant mean, ARD RBF kernel, Gaussian
      noise) on a low-dimensional input: the BayesSim summaries standardised and reduced by
      PCA (default 8 components). The predictive distribution *including the noise* is the
      posterior, one Gaussian per parameter (diagonal covariance).
    * ``bayeszoom-rkhs`` regresses the mean with a squared loss (a fixed-scale Gaussian NLL,
      so the shared training loop with early stopping is reused); the std of parameter d is
      the mean absolute validation error of d.

How ``run_fit`` treats ``sequential = False`` estimators (see :func:`softsbi.workflows.fit.run.run_fit`):
every round draws its simulations from the prior, the estimator is retrained on all data so
far, and the posterior of a round is ``q`` truncated to the prior box (no proposal
correction is needed); per-round figures are then "bulk with r x sims_per_round
simulations".

Also here: :class:`FlatMDNEstimator`, the ``mdnn`` network on flat feature vectors
``x (N, F)`` (SBI benchmark tasks); not registered as a plugin because ``run_fit`` always
passes states ``(N, T, 1+K, 3)``.
"""
from __future__ import annotations

import time
from typing import Any, Callable, ClassVar, Mapping

import numpy as np
import torch
from torch import nn

from softsbi.core.distributions import MixtureOfGaussians
from softsbi.core.errors import DataError, DependencyMissing, ParameterError, ShapeError
from softsbi.core.interfaces import PosteriorEstimator
from softsbi.plugins.hookspecs import hookimpl
from softsbi.inference.estimators import RKHSEstimator
from softsbi.inference.neural_mdn import NeuralMDNEstimator, check_training_pair, merge_config
from softsbi.inference.sbi_adapter import SbiNPEEstimator
from softsbi.inference.mdn import MDNParams
from softsbi.inference.summaries import bayessim_summaries
from softsbi.inference.training import threads_option, torch_threads, train_val_split

__all__ = ["FlatMDNEstimator", "MDRFFEstimator", "BayesZoomRKHSEstimator", "NNBulkEstimator",
           "GPBulkEstimator", "RandomFourierFeatures", "MeanHead", "softsbi_estimators"]

#: gp-bulk's Gaussian likelihood: the noise variance's lower bound and its start value (standardised targets)
GP_NOISE_MIN = 1e-5
GP_NOISE_INIT = 0.01


# ---------------------------------------------------------------------------------------- flat MDN
class FlatMDNEstimator(NeuralMDNEstimator):
    """MDN (the ``mdnn`` MLP + mixture head) on flat feature vectors ``x (N, F)``.

    For simulators whose output already is a feature vector (SBI benchmark tasks
    two_moons, slcp, gaussian_linear). Inputs are standardised per feature; otherwise
    identical to :class:`~softsbi.inference.estimators.MDNNEstimator` (BayesSim, Ramos et
    al. 2019, Sec. 3-4) with all of :class:`NeuralMDNEstimator`'s options.

    Shapes: ``fit(theta_unit (N, D), x (N, F))``; ``posterior_at(x_obs (F,) or (1, F))``.

    Raises:
        ShapeError: ``x`` is not 2-D (fit) or an observation does not have ``F`` entries.
    """

    name: ClassVar[str] = "mdn-flat"
    x_event_ndim: ClassVar[int] = 1

    def check_x_shape(self, x: np.ndarray) -> None:
        """Raise :class:`ShapeError` unless ``x`` is ``(N, F)`` with ``F >= 1``."""
        if x.ndim != 2 or x.shape[1] < 1:
            raise ShapeError(f"x must have shape (N, F) (flat feature vectors), got {x.shape}")

    def _expected(self) -> str:
        return f"{self._x_shape[0]}"  # type: ignore[index]


# ---------------------------------------------------------------------------------------- MDRFF
class RandomFourierFeatures(nn.Module):
    """Fixed random Fourier features ``[cos(W z / sigma), sin(W z / sigma)]`` (Rahimi & Recht 2007).

    ``W (M, F) ~ N(0, I)`` is a persistent buffer (saved with the state, never trained), so
    the features approximate an RBF kernel of bandwidth ``sigma`` on ``z (B, F)``; output
    ``(B, 2M)``. The usual ``sqrt(1/M)`` factor is left out (it is absorbed by the linear
    layer that follows and would only slow Adam down).
    """

    def __init__(self, in_dim: int, n_features: int, sigma: float):
        super().__init__()
        if n_features < 1 or not sigma > 0:
            raise ParameterError(f"RFF needs n_features >= 1 and sigma > 0 (got {n_features}, {sigma})")
        self.register_buffer("W", torch.randn(int(n_features), int(in_dim)) / float(sigma))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        """``(B, ...)`` (flattened to ``(B, F)``) -> ``(B, 2M)``."""
        proj = z.flatten(1) @ self.W.t()
        return torch.cat([torch.cos(proj), torch.sin(proj)], dim=-1)


class MDRFFEstimator(NeuralMDNEstimator):
    """BayesSim MDRFF (Ramos et al. 2019, Sec. 4): BayesSim summaries -> fixed RFF -> MDN.

    Features: :func:`~softsbi.inference.summaries.bayessim_summaries` of ``x (N, T, 1+K, 3)``
    standardised per feature and scaled by ``1/sqrt(F)`` (so a feature vector has unit RMS
    norm and ``rff_sigma`` is relative to the typical distance between two simulations),
    then ``M`` fixed random Fourier features. With ``hidden = ()`` (default, as in BayesSim)
    the mixture parameters are linear in the features.

    Extra config options:
        rff_features: ``M`` frequencies (output ``2M``), default 256.
        rff_sigma: kernel bandwidth relative to the unit-RMS inputs, default 1.0.
    Defaults changed from the base: ``hidden = ()``, ``weight_decay = 1e-4`` (a linear model
    on 512 features needs the ridge), ``lr = 3e-3``.
    """

    name: ClassVar[str] = "mdrff"
    EXTRA_DEFAULTS: ClassVar[dict[str, Any]] = {"rff_features": 256, "rff_sigma": 1.0, "hidden": (),
                                                "weight_decay": 1e-4, "lr": 3e-3}

    def summary_statistics(self, x: np.ndarray) -> np.ndarray:
        """BayesSim summaries ``(N, F)`` float32 of ``x (N, T, 1+K, 3)`` (Ramos et al. 2019, Sec. 4)."""
        return bayessim_summaries(x).astype(np.float32)

    def input_stats(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-feature mean, and std times ``sqrt(F)`` (unit RMS norm per simulation)."""
        mean, std = super().input_stats(z)
        return mean, (std * np.sqrt(z.shape[1])).astype(np.float32)

    def embedding_net(self, z_example: np.ndarray) -> nn.Module:
        """Fixed :class:`RandomFourierFeatures` of the standardised summaries: ``(n, F) -> (n, 2M)``."""
        c = self.config
        return RandomFourierFeatures(z_example.shape[1], int(c["rff_features"]), float(c["rff_sigma"]))


# ---------------------------------------------------------------------------------------- BayesZoom
class MeanHead(nn.Module):
    """Head predicting a mean ``(B, D)`` and a *fixed* diagonal scale, as a 1-component MDN.

    The scale is a buffer ``(D,)`` (standardised target units): 1 during training, so the
    MDN negative log-likelihood is ``0.5 * squared error + const`` (mean regression); set to
    the validation L1 error after training (BayesZoom, Antonova et al. 2022).
    """

    def __init__(self, in_dim: int, out_dim: int):
        super().__init__()
        self.mean = nn.Linear(in_dim, out_dim)
        self.register_buffer("scale", torch.ones(out_dim))

    def forward(self, h: torch.Tensor) -> MDNParams:
        """``h (B, H)`` -> one-component :class:`MDNParams` (mean ``(B, 1, D)``, diagonal ``scale``)."""
        B = h.shape[0]
        m = self.mean(h)
        L = torch.diag_embed(self.scale.expand(B, -1))
        return MDNParams(torch.zeros(B, 1, dtype=h.dtype), m[:, None, :], L[:, None])


class BayesZoomRKHSEstimator(RKHSEstimator):
    """BayesZoom-RKHS (Antonova et al. 2022, Sec. V): RKHS-net -> 3-layer MLP -> posterior mean;
    std = validation L1 error; a unimodal Gaussian (one-component :class:`MixtureOfGaussians`
    with diagonal covariance).

    Training minimises the squared error of the standardised parameters (early stopping on
    the validation split); afterwards ``std_d = mean_i |theta_unit_id - mean_d(x_i)|`` over the
    validation simulations (unit-cube units), stored in ``fit_info["val_l1"]``.

    Options: those of :class:`~softsbi.inference.estimators.RKHSEstimator`; ``hidden``
    defaults to ``(256, 256, 256)`` (3 layers; the paper's 3x1024 is reachable),
    ``n_components`` is ignored (always 1).
    """

    name: ClassVar[str] = "bayeszoom-rkhs"
    EXTRA_DEFAULTS: ClassVar[dict[str, Any]] = {"hidden": (256, 256, 256), "ensemble": 1, "recalibrate": False,
                                                **RKHSEstimator.END_TO_END}

    def _build(self, z_example: np.ndarray, D: int):
        net = super()._build(z_example, D)
        last = self.config["hidden"][-1] if self.config["hidden"] else net.head.logits.in_features
        net.head = MeanHead(int(last), D)
        return net

    def fit(self, theta_unit: np.ndarray, x: np.ndarray, *, seed: int = 0,
            progress: Callable[[int, int, float], None] | None = None,
            groups: np.ndarray | None = None) -> dict[str, Any]:
        """As :meth:`NeuralMDNEstimator.fit`; adds ``val_l1 (D,)`` (unit-cube units) to the info.

        Raises:
            ShapeError, DataError, RuntimeError: as the base class. ParameterError: ``ensemble > 1``
            (the per-dimension scale is fitted on one network's validation error).
        """
        if int(self.config.get("ensemble", 1)) != 1 or self.config.get("recalibrate"):
            raise ParameterError(f"estimator '{self.name}' supports neither ensemble > 1 nor recalibrate (got "
                                 f"ensemble={self.config['ensemble']}, recalibrate={self.config['recalibrate']}); "
                                 f"use rkhs with these options instead")
        info = super().fit(theta_unit, x, seed=seed, progress=progress, groups=groups)
        u2, x2 = self._validate(theta_unit, x)
        # the base class's split (same seed, same call)
        _, val_idx = train_val_split(len(u2), float(self.config["val_fraction"]), np.random.default_rng(seed),
                                     min_train=2, groups=groups)
        zs = self._standardise(self.summary_statistics(x2[val_idx]))
        assert self._net is not None
        self._net.head.scale.fill_(1.0)
        pred = self._predict(zs).means[:, 0, :].double().numpy()  # unit-cube units
        l1 = np.abs(u2[val_idx] - pred).mean(0)
        l1 = np.maximum(l1, 1e-6)
        with torch.no_grad():
            self._net.head.scale.copy_(torch.as_tensor(l1 / self._u_std, dtype=torch.float32))
        self.fit_info["val_l1"] = l1.tolist()
        info["val_l1"] = l1.tolist()
        return info


# ---------------------------------------------------------------------------------------- NN-bulk
class NNBulkEstimator(RKHSEstimator):
    """NN-bulk (Antonova et al. 2022, Sec. V, bulk baseline): RKHS-net -> MLP -> one
    full-covariance Gaussian, trained once on the whole budget drawn from the prior.

    ``sequential = False``: :func:`~softsbi.workflows.fit.run.run_fit` draws every round from the
    prior. Options: those of :class:`RKHSEstimator`; ``n_components`` defaults to 1.
    """

    name: ClassVar[str] = "nn-bulk"
    sequential: ClassVar[bool] = False
    #: the measured baseline: one network, no recalibration (rkhs's defaults are an ensemble)
    EXTRA_DEFAULTS: ClassVar[dict[str, Any]] = {"n_components": 1, "ensemble": 1, "recalibrate": False,
                                                **RKHSEstimator.END_TO_END}


# ---------------------------------------------------------------------------------------- GP-bulk
GP_STATE_FORMAT = "softsbi.gp-bulk/1"


def _require_gpytorch():
    try:
        import gpytorch
    except ImportError as exc:  # pragma: no cover - gpytorch is a dependency
        raise DependencyMissing("estimator 'gp-bulk' needs GPyTorch: pip install gpytorch") from exc
    return gpytorch


def _make_gp(gpytorch, X: torch.Tensor, y: torch.Tensor):
    class _ExactGP(gpytorch.models.ExactGP):
        def __init__(self, X, y, lik):
            super().__init__(X, y, lik)
            self.mean_module = gpytorch.means.ConstantMean()
            self.covar_module = gpytorch.kernels.ScaleKernel(
                gpytorch.kernels.RBFKernel(ard_num_dims=X.shape[1]))

        def forward(self, z):
            return gpytorch.distributions.MultivariateNormal(self.mean_module(z), self.covar_module(z))

    lik = gpytorch.likelihoods.GaussianLikelihood(noise_constraint=gpytorch.constraints.GreaterThan(GP_NOISE_MIN))
    model = _ExactGP(X, y, lik)
    # start from a small noise and unit lengthscales (inputs are whitened PCA scores, targets
    # standardised): the default noise 0.69 needs hundreds of Adam steps to come down
    lik.noise = GP_NOISE_INIT
    model.covar_module.base_kernel.lengthscale = 1.0
    return model, lik


class GPBulkEstimator(PosteriorEstimator):
    """GP-bulk (Antonova et al. 2022, Sec. V): exact GP regression (GPyTorch) of each
    parameter on a low-dimensional summary, trained once on the whole prior budget.

    Pipeline: ``x (N, T, 1+K, 3)`` -> BayesSim summaries (or ``x (N, F)`` used as is) ->
    per-feature standardisation -> PCA to ``pca_dim`` components (whitened) -> for each
    parameter d an exact GP ``theta_unit_d = f_d(z) + eps``, ``f_d ~ GP(c, s^2 RBF_ARD)``, hyperparameters
    by maximising the exact marginal likelihood (Adam, ``gp_iters`` steps). The posterior is
    the predictive ``N(mean_d(z_obs), var_d(z_obs) + noise_d)`` per parameter: a
    one-component :class:`MixtureOfGaussians` with diagonal covariance (unit-cube units).

    Config options:
        pca_dim: PCA components kept, default 8 (capped at ``min(F, N - 1)``).
        gp_iters: Adam steps on the marginal likelihood, default 100. gp_lr: default 0.05.
        max_train: largest training set (a random subset beyond it; exact GPs are O(N^3)),
            default 3000.
        num_threads: torch threads, default 1.

    ``sequential = False``.

    Raises:
        ParameterError: unknown option. ShapeError / DataError: bad inputs (as the neural
        estimators). DependencyMissing: GPyTorch not installed.
    """

    name: ClassVar[str] = "gp-bulk"
    sequential: ClassVar[bool] = False
    DEFAULTS: ClassVar[dict[str, Any]] = {"pca_dim": 8, "gp_iters": 60, "gp_lr": 0.05, "max_train": 1000,
                                          "num_threads": 1}

    def __init__(self, **config: Any):
        super().__init__(**merge_config(self.name, self.DEFAULTS, config))
        self._state: dict[str, Any] | None = None
        self._models: list[Any] | None = None
        self.fit_info: dict[str, Any] = {}

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        return dict(cls.DEFAULTS)

    # -------------------------------------------------------------- features
    @staticmethod
    def _summaries(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.ndim == 2:
            return x
        if x.ndim == 4:
            return bayessim_summaries(x)
        raise ShapeError(f"x must have shape (N, T, 1+K, 3) or (N, F), got {x.shape}")

    def _features(self, s: np.ndarray) -> np.ndarray:
        st = self._state
        assert st is not None
        return ((s - st["s_mean"]) / st["s_std"]) @ st["pca"] / st["pc_std"]

    # -------------------------------------------------------------- API
    def fit(self, theta_unit: np.ndarray, x: np.ndarray, *, seed: int = 0,
            progress: Callable[[int, int, float], None] | None = None) -> dict[str, Any]:
        """Fit the PCA and one GP per parameter.

        Args:
            theta_unit: ``(N, D)`` unit-cube parameters. x: ``(N, T, 1+K, 3)`` states (m) or ``(N, F)``.
            seed: seeds the subset (if ``N > max_train``) and the optimiser.
            progress: ``progress(step, D * gp_iters, -mll)`` after each optimiser step.

        Returns:
            ``{"seconds", "n_train", "mll" (per parameter, per datum), "lengthscales", "noise"}``.

        Raises:
            ShapeError: bad shapes. DataError: non-finite values or fewer than 10 simulations.
        """
        gpytorch = _require_gpytorch()
        t0 = time.perf_counter()
        s = self._summaries(x)
        u = check_training_pair(theta_unit, s, np.shape(x))
        c = self.config
        rng = np.random.default_rng(seed)
        if len(u) > int(c["max_train"]):
            keep = rng.choice(len(u), int(c["max_train"]), replace=False)
            u, s = u[keep], s[keep]
        N, D = u.shape
        s_mean = s.mean(0)
        s_std = s.std(0)
        s_std = np.where(s_std > 1e-12 * max(float(s_std.max()), 1e-300), s_std, 1.0)
        zc = (s - s_mean) / s_std
        k = int(min(int(c["pca_dim"]), zc.shape[1], N - 1))
        _, sv, vt = np.linalg.svd(zc, full_matrices=False)
        pca = vt[:k].T
        pc_std = np.maximum(sv[:k] / np.sqrt(N), 1e-12)
        u_mean, u_std = u.mean(0), np.maximum(u.std(0), 1e-9)
        self._state = {"s_mean": s_mean, "s_std": s_std, "pca": pca, "pc_std": pc_std,
                       "u_mean": u_mean, "u_std": u_std, "x_event_shape": list(np.shape(x)[1:])}
        Z = self._features(s)
        with torch_threads(threads_option(c.get("num_threads"))):
            torch.manual_seed(seed)
            X = torch.as_tensor(Z, dtype=torch.float64)
            Y = torch.as_tensor((u - u_mean) / u_std, dtype=torch.float64)
            models, params, mlls = [], [], []
            step = 0
            for d in range(D):
                model, lik = _make_gp(gpytorch, X, Y[:, d])
                model.double()
                model.train()
                lik.train()
                opt = torch.optim.Adam(model.parameters(), lr=float(c["gp_lr"]))
                mll = gpytorch.mlls.ExactMarginalLogLikelihood(lik, model)
                loss = torch.tensor(0.0)
                with gpytorch.settings.max_cholesky_size(10_000):
                    for _ in range(int(c["gp_iters"])):
                        opt.zero_grad()
                        loss = -mll(model(X), Y[:, d])
                        loss.backward()
                        opt.step()
                        step += 1
                        if progress is not None:
                            progress(step, D * int(c["gp_iters"]), float(loss.detach()))
                model.eval()
                lik.eval()
                models.append(model)
                mlls.append(-float(loss.detach()))
                params.append({k_: v.detach().numpy().copy() for k_, v in model.state_dict().items()})
        self._models = models
        self._state.update({"params": params, "X": Z, "Y": (u - u_mean) / u_std})
        self.fit_info = {
            "seconds": time.perf_counter() - t0, "n_train": int(N), "mll": mlls,
            "lengthscales": [m.covar_module.base_kernel.lengthscale.detach().numpy().ravel().tolist() for m in models],
            "noise": [float(m.likelihood.noise.detach()) for m in models], "pca_dim": k}
        return dict(self.fit_info)

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predictive mean and variance ``(n, D)`` (unit-cube units, noise included) for
        ``x (n, T, 1+K, 3)`` or ``(n, F)``.

        Raises:
            RuntimeError: not fitted. ShapeError: wrong observation shape.
        """
        gpytorch = _require_gpytorch()
        if self._models is None or self._state is None:
            raise RuntimeError("estimator 'gp-bulk' is not fitted: call fit(theta_unit, x) (or load_state_dict) "
                               "first")
        x = np.asarray(x, np.float64)
        if list(x.shape[1:]) != list(self._state["x_event_shape"]):
            raise ShapeError(f"observations must have shape (n, {', '.join(map(str, self._state['x_event_shape']))}),"
                             f" got {x.shape}")
        if not np.isfinite(x).all():
            raise DataError("the observation contains non-finite values (NaN/inf)")
        Z = torch.as_tensor(self._features(self._summaries(x)), dtype=torch.float64)
        means, vars_ = [], []
        with torch.no_grad(), gpytorch.settings.fast_pred_var(False), gpytorch.settings.max_cholesky_size(10_000):
            for m in self._models:
                p = m.likelihood(m(Z))
                means.append(p.mean.numpy())
                vars_.append(p.variance.numpy())
        st = self._state
        mean = np.stack(means, 1) * st["u_std"] + st["u_mean"]
        var = np.stack(vars_, 1) * st["u_std"] ** 2
        return mean, var

    def posterior_at(self, x_obs: np.ndarray) -> MixtureOfGaussians:
        """The posterior ``q(theta_unit | x_o)`` at ``x_o = x_obs``: the GP predictive, one diagonal
        Gaussian (unit-cube units).

        Args:
            x_obs: one observation ``(T, 1+K, 3)`` or ``(F,)``, optionally with a leading 1.

        Raises:
            RuntimeError: not fitted. ShapeError: wrong shape. DataError: non-finite values.
        """
        if self._state is None:
            raise RuntimeError("estimator 'gp-bulk' is not fitted: call fit(theta_unit, x) (or load_state_dict) "
                               "first")
        x = np.asarray(x_obs, np.float64)
        ev = len(self._state["x_event_shape"])
        if x.ndim == ev:
            x = x[None]
        if x.ndim != ev + 1 or x.shape[0] != 1:
            raise ShapeError(f"x_obs must be one observation of shape ({', '.join(map(str, self._state['x_event_shape']))})"
                             f", got {x.shape}")
        mean, var = self.predict(x)
        return MixtureOfGaussians(np.ones(1), mean, np.diag(np.sqrt(var[0]))[None])

    def state_dict(self) -> dict[str, Any]:
        """NumPy-only state (PCA, standardisation, training inputs, GP hyperparameters)."""
        if self._state is None:
            raise RuntimeError("estimator 'gp-bulk' is not fitted; nothing to save")
        return {"format": GP_STATE_FORMAT, "estimator": self.name, "config": dict(self.config),
                **{k: v for k, v in self._state.items()}, "fit_info": dict(self.fit_info)}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Inverse of :meth:`state_dict`.

        Raises:
            DataError: not a gp-bulk state.
        """
        if state.get("format") != GP_STATE_FORMAT:
            raise DataError(f"state is not a 'gp-bulk' estimator state ({GP_STATE_FORMAT}); got {state.get('format')!r}")
        gpytorch = _require_gpytorch()
        self.config = {**self.DEFAULTS, **dict(state["config"])}
        keys = ("s_mean", "s_std", "pca", "pc_std", "u_mean", "u_std", "X", "Y")
        self._state = {k: np.asarray(state[k], np.float64) for k in keys}
        self._state["x_event_shape"] = [int(v) for v in state["x_event_shape"]]
        self._state["params"] = state["params"]
        X = torch.as_tensor(self._state["X"])
        Y = torch.as_tensor(self._state["Y"])
        models = []
        for d, p in enumerate(state["params"]):
            model, lik = _make_gp(gpytorch, X, Y[:, d])
            model.double()
            model.load_state_dict({k: torch.as_tensor(np.asarray(v)) for k, v in p.items()})
            model.eval()
            lik.eval()
            models.append(model)
        self._models = models
        self.fit_info = dict(state.get("fit_info", {}))


@hookimpl
def softsbi_estimators() -> list[type[PosteriorEstimator]]:
    """Estimators of this module (``mdrff``, ``bayeszoom-rkhs``, ``nn-bulk``, ``gp-bulk``) and,
    when ``sbi`` is importable, ``sbi-npe`` (:mod:`softsbi.inference.sbi_adapter`)."""
    out: list[type[PosteriorEstimator]] = [MDRFFEstimator, BayesZoomRKHSEstimator, NNBulkEstimator, GPBulkEstimator]
    out.append(SbiNPEEstimator)
    return out
