"""The neural posterior estimator core: summary statistics -> embedding net -> MLP -> mixture density network.

:class:`NeuralMDNEstimator` handles validation, input/target standardisation, the train/validation split
with early stopping (the shared loop of :mod:`softsbi.inference.training`), determinism, and the (numpy)
state dict; its ensembles train in :mod:`softsbi.inference.ensembles` and are recalibrated by
:mod:`softsbi.inference.recalibration`. The estimators of :mod:`softsbi.inference.estimators` (``rkhs``,
``mdnn``) and :mod:`softsbi.inference.baselines` are its subclasses.

Notation: ``theta_unit`` are the simulator parameters ``theta`` mapped to the unit cube by
:meth:`~softsbi.core.types.ParamSpace.to_unit`; the estimators learn ``q(theta_unit | x)``.
"""
from __future__ import annotations

import time
import warnings
from typing import Any, Callable, ClassVar, Mapping

import numpy as np
import torch
from torch import nn

from softsbi.core.errors import DataError, ParameterError, ShapeError
from softsbi.core.seeds import RECAL_STREAM
from softsbi.plugins.manager import check_option_values
from softsbi.inference.ensembles import train_members
from softsbi.inference.mdn import ACTIVATIONS, MDNNetwork, MDNParams
from softsbi.inference.mdn_posterior import STATE_FORMAT, MDNPosterior
from softsbi.inference.recalibration import SCALE_RULES, choose_cov_scale, fit_marginals
from softsbi.inference.training import threads_option, torch_threads, train_val_split

__all__ = ["NeuralMDNEstimator", "merge_config", "check_training_pair", "threads_option", "MIN_SAMPLES", "STATE_FORMAT",
           "TARGET_STD_FLOOR", "CONSTANT_FEATURE_RTOL", "MAX_VAL_FRACTION"]

#: the fewest simulations an estimator fits on
MIN_SAMPLES = 10
#: a parameter's training standard deviation is floored at this fraction of the largest one (unit cube), so a
#: parameter the proposal barely varies is not standardised by a near-zero scale
TARGET_STD_FLOOR = 1e-3
#: an input element whose training standard deviation is below this fraction of the largest is constant (std 1)
CONSTANT_FEATURE_RTOL = 1e-7
#: the validation fraction must lie in (0, MAX_VAL_FRACTION): the rest trains
MAX_VAL_FRACTION = 0.9
#: spaces the torch seeds of the ensemble members' initialisations
MEMBER_SEED_STRIDE = 1_000_003


def merge_config(estimator: str, defaults: Mapping[str, Any], config: Mapping[str, Any],
                 kind: str = "estimator") -> dict[str, Any]:
    """``defaults`` updated by ``config`` (the options of an estimator, extractor... named ``estimator``).

    Raises:
        ParameterError: a key of ``config`` is not an option (names the closest one and lists all), or a value
            is text where the default is a number or a flag (:func:`~softsbi.plugins.manager.check_option_values`).
    """
    check_option_values(defaults, config, f"{kind} '{estimator}'")
    return {**defaults, **config}


def check_training_pair(theta_unit: np.ndarray, features: np.ndarray, x_shape: tuple[int, ...]) -> np.ndarray:
    """Validate parameters against precomputed features of the simulations.

    Args:
        theta_unit: ``(N, D)`` (or ``(N,)``) parameters in the unit cube.
        features: ``(N, ...)`` features computed from ``x``.
        x_shape: shape of the raw ``x``, for the error message.

    Returns:
        ``theta_unit`` as a float64 ``(N, D)`` array.

    Raises:
        ShapeError: ``theta_unit`` is not ``(N, D)`` with the N of ``x``.
        DataError: non-finite values, or fewer than :data:`MIN_SAMPLES` simulations.
    """
    u = np.asarray(theta_unit, np.float64)
    u = u[:, None] if u.ndim == 1 else u
    if u.ndim != 2 or len(u) != len(features):
        raise ShapeError(f"theta_unit must be (N, D) with the N of x; got theta_unit {u.shape}, x {tuple(x_shape)}")
    if not (np.isfinite(u).all() and np.isfinite(features).all()):
        raise DataError("theta_unit or x has non-finite values (NaN/inf); drop failed simulations before fitting")
    if len(u) < MIN_SAMPLES:
        raise DataError(f"need at least {MIN_SAMPLES} simulations to fit an estimator, got {len(u)}")
    return u


class NeuralMDNEstimator(MDNPosterior):
    """Base class: ``q(theta_unit | x)`` as an MDN on learned/fixed features (BayesSim, Ramos et al. 2019).

    Pipeline: ``x (N, T, 1+K, 3)`` -> :meth:`summary_statistics` (fixed, NumPy) -> standardise
    with training statistics (:meth:`input_stats`) -> :meth:`embedding_net` (trainable) -> MLP ->
    :class:`~softsbi.inference.mdn.MDNHead`. Targets ``theta_unit`` are standardised with their
    training mean/std, and the mixture is mapped back to unit-cube coordinates.

    Config options (keyword arguments; unknown names raise :class:`ParameterError`):
        hidden: MLP widths, default ``(256, 256)``; the paper's ``(1024, 1024, 1024)``
            is reachable but slow on CPU.
        n_components: mixture components, default 4 (the paper's posteriors).
        activation: MLP nonlinearity, default ``"relu"``.
        lr: Adam learning rate, default ``1e-3`` (paper: 1e-6 on GPU for many more steps).
        weight_decay: Adam L2 penalty, default ``1e-5``.
        max_epochs: default 300. patience: epochs without validation improvement before
            stopping, default 15. min_epochs: default 10.
        batch_size: default 64. val_fraction: held-out fraction, default 0.15.
        grad_clip: gradient-norm clip, default 10.0 (None disables).
        min_scale: Cholesky-diagonal floor in standardised units, default 1e-3.
        max_seconds: wall-clock budget per fit (None: no budget); training stops early
            and keeps the best weights.
        ensemble: number ``M`` of networks (a deep ensemble, :mod:`softsbi.inference.ensembles`), default 1.
            The members share one train/validation split and differ in initialisation and batch order; the
            posterior is the equal-weight mixture of the members' mixtures (``M * n_components`` components).
            Training time grows ~M-fold; ``max_seconds`` is split evenly between the members (stacked: bounds
            them all).
        stack_members: train the ensemble members as one ``vmap``-ed network
            (:func:`~softsbi.inference.ensembles.fit_stacked`), default False: the same members up to float
            rounding; it pays where per-step overhead dominates (small networks, a GPU), not on a CPU.
            Networks with batch normalisation never stack.
        recalibrate: after training, scale every component's covariance by the factor ``s`` in
            :data:`RECAL_SCALES` chosen on the held-out validation simulations by ``recal_rule`` against the
            nominal coverage plus ``recal_margin`` binomial standard errors at the levels :data:`RECAL_LEVELS`
            (post-hoc recalibration, :func:`~softsbi.inference.recalibration.choose_cov_scale`), default False.
            ``fit_info["recalibration"]`` holds ``s``, the validation coverage at every scale and the coverage
            error before/after.
        recal_rule: how ``recalibrate`` chooses ``s``: ``"closest"`` (default), of the scales whose validation
            coverage curve lies within ``recal_tolerance_se`` binomial standard errors of the closest to the target,
            the one nearest to 1; ``"at-least"``, the smallest scale that reaches it at every level (the earlier
            rule: it over-covered the middle levels, docs/explanation.md).
        recal_tolerance_se: the closest rule's tolerance, default 1 (the one-standard-error rule: a validation
            split of a few cases leaves the trained posterior's scale); 0 picks the closest scale.
        recal_marginals: with ``recalibrate``, first recalibrate each parameter's marginal on the validation
            split (:meth:`_recalibrate_marginals`: a per-parameter scale and shift of the posterior about its
            mean, fitted by maximum likelihood of the held-out truths under the box-restricted marginals), then
            choose the joint covariance scale on the recalibrated posterior. Default False (it left the joint
            coverage under-confident where the joint scale alone did not). The marginals it leaves too wide or too narrow are named by ``softsbi calibrate``.
            ``fit_info["recalibration"]["marginals"]`` holds the scales and shifts.
        recal_margin: ``m`` of ``recalibrate``: the validation coverage at level ``g`` must reach
            ``g + m * sqrt(g (1 - g) / n_val)`` (``m`` binomial standard errors above nominal). Default 0
            (nominal; ``m = 1`` over-widened the default ensemble).
        embedding_epochs: train the embedding net end to end for this many epochs only, then freeze it:
            its features of the training and validation simulations are computed once and the MLP and
            head train on until early stopping (the embedding's share of an epoch is then never paid
            again). Default None: the embedding trains in every epoch. Needs a network without batch
            normalisation (else ignored); trains through the stacked path of ``stack_members``.
        ensemble_shared: what the ensemble members ``1..M-1`` share with member 0, default ``"none"``
            (independent networks); ``"embedding"`` (the embedding net) or ``"trunk"`` (it and the first MLP
            layer): member 0 trains end to end, the others only their heads on its frozen features
            (:func:`~softsbi.inference.ensembles.fit_shared_heads`). Does not combine with ``stack_members``
            or ``embedding_epochs``; needs a network without batch normalisation.
        num_threads: torch threads during fit/posterior_at (restored afterwards), default 1 (robust on a
            shared machine, where OpenMP spin-waiting slows several threads down; raise it on an idle
            many-core one).

    The calibration and training time of these options are measured in docs/benchmarks.md (calibration,
    estimators-speed).

    Subclass hooks: :meth:`summary_statistics`, :meth:`input_stats`, :meth:`embedding_net`,
    :meth:`check_x_obs_shape`, and :meth:`check_x_shape` with ``x_event_ndim`` for inputs that
    are not ``(N, T, 1+K, 3)`` states. Subclasses written against the old hook names
    ``preprocess`` / ``build_features`` still work: defining one of them (and not the new name)
    aliases it to the new hook, with a :class:`DeprecationWarning` at class creation.
    """

    name: ClassVar[str] = "neural-mdn"
    sequential: ClassVar[bool] = True
    #: Base defaults; subclasses extend with ``EXTRA_DEFAULTS``.
    BASE_DEFAULTS: ClassVar[dict[str, Any]] = {
        "hidden": (256, 256), "n_components": 4, "activation": "relu", "lr": 1e-3, "weight_decay": 1e-5,
        "max_epochs": 300, "patience": 15, "min_epochs": 10, "batch_size": 64, "val_fraction": 0.15,
        "grad_clip": 10.0, "min_scale": 1e-3, "max_seconds": None, "num_threads": 1, "ensemble": 1,
        "recalibrate": False, "recal_margin": 0.0, "recal_marginals": False, "recal_rule": "closest",
        "recal_tolerance_se": 1.0,
        "embedding_epochs": None,
        "stack_members": False,
        "ensemble_shared": "none",
    }
    EXTRA_DEFAULTS: ClassVar[dict[str, Any]] = {}
    #: values of the ``ensemble_shared`` option
    SHARED_CHOICES: ClassVar[tuple[str, ...]] = ("none", "embedding", "trunk")
    #: old hook name -> new hook name (deprecated aliases, see :meth:`__init_subclass__`)
    RENAMED_HOOKS: ClassVar[dict[str, str]] = {"preprocess": "summary_statistics", "build_features": "embedding_net"}

    def __init_subclass__(cls, **kwargs: Any):
        """Map a subclass's old-named hooks (``preprocess``, ``build_features``) onto the new names.

        Warns:
            DeprecationWarning: the subclass defines an old hook name.
        """
        super().__init_subclass__(**kwargs)
        for old, new in NeuralMDNEstimator.RENAMED_HOOKS.items():
            if old in cls.__dict__ and new not in cls.__dict__:
                warnings.warn(f"{cls.__name__}.{old} is deprecated: rename the hook to {new}",
                              DeprecationWarning, stacklevel=2)
                setattr(cls, new, cls.__dict__[old])

    def __init__(self, **config: Any):
        cfg = merge_config(self.name, self.defaults(), config)
        cfg["hidden"] = tuple(int(h) for h in cfg["hidden"])
        if cfg["activation"] not in ACTIVATIONS:
            raise ParameterError(f"activation '{cfg['activation']}' not in {sorted(ACTIVATIONS)}")
        if not 0.0 < float(cfg["val_fraction"]) < MAX_VAL_FRACTION:
            raise ParameterError(f"val_fraction must be in (0, {MAX_VAL_FRACTION}), got {cfg['val_fraction']}")
        super().__init__(**cfg)
        if int(cfg["ensemble"]) < 1:
            raise ParameterError(f"ensemble must be an integer >= 1 (got {cfg['ensemble']}); 1 = a single network")
        if cfg["recal_rule"] not in SCALE_RULES:
            raise ParameterError(f"recal_rule must be one of {', '.join(SCALE_RULES)} (got {cfg['recal_rule']!r})")
        if cfg["ensemble_shared"] not in self.SHARED_CHOICES:
            raise ParameterError(f"ensemble_shared must be one of {', '.join(self.SHARED_CHOICES)} (got "
                                 f"{cfg['ensemble_shared']!r}); 'none' = independent networks")
        self._net: MDNNetwork | None = None
        self._nets: list[MDNNetwork] = []
        self._cov_scale = 1.0
        self._marginal: tuple[np.ndarray, np.ndarray] | None = None  # per-parameter (scale, shift), recal_marginals
        self._x_shape: tuple[int, ...] | None = None  # (T, 1+K, 3) seen in fit
        self._z_shape: tuple[int, ...] | None = None  # preprocessed per-sample shape
        self._in_mean = self._in_std = None
        self._u_mean = self._u_std = None
        self.fit_info: dict[str, Any] = {}

    # ------------------------------------------------------------------ hooks
    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """All config options with their default values."""
        out: dict[str, Any] = {}
        for klass in reversed(cls.__mro__):
            out.update(klass.__dict__.get("BASE_DEFAULTS", {}))
            out.update(klass.__dict__.get("EXTRA_DEFAULTS", {}))
        return out

    def input_stats(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Standardisation ``(mean, std)`` broadcastable to ``z.shape[1:]`` from training data ``z``.

        Default: per-element mean/std over samples; (near-)constant elements get std 1.
        """
        mean = z.mean(axis=0)
        std = z.std(axis=0)
        tiny = CONSTANT_FEATURE_RTOL * max(float(std.max()), 1e-30)
        std = np.where(std > tiny, std, 1.0)
        return mean.astype(np.float32), std.astype(np.float32)

    def embedding_net(self, z_example: np.ndarray) -> nn.Module:
        """The trainable embedding net for standardised summary statistics shaped like
        ``z_example (n, ...)``, returning ``(n, F)`` features for the MLP. Default: flatten."""
        return nn.Flatten()

    def training_view(self, zb: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """The standardised training batch ``zb (B, ...)`` as the embedding net sees it in one end-to-end
        gradient step (validation and prediction always see the whole input). Default: ``zb`` itself;
        :class:`RKHSEstimator` subsamples the points (its ``point_subset`` option). ``generator`` is the
        only source of randomness, so training stays reproducible."""
        return zb

    def _build(self, z_example: np.ndarray, D: int) -> MDNNetwork:
        features = self.embedding_net(z_example)
        with torch.no_grad():
            feat_dim = int(features(torch.as_tensor(z_example[:2])).shape[1])
        c = self.config
        return MDNNetwork(features, feat_dim, c["hidden"], D, int(c["n_components"]), c["activation"],
                          float(c["min_scale"]))

    def check_x_shape(self, x: np.ndarray) -> None:
        """Hook: raise :class:`ShapeError` unless the training inputs ``x`` have this
        estimator's layout. Default: ``(N, T, 1+K, 3)`` with ``K >= 1``; estimators on flat
        feature vectors set ``x_event_ndim = 1`` and override this."""
        if x.ndim != 4 or x.shape[-1] != 3 or x.shape[2] < 2:
            raise ShapeError(f"x must have shape (N, T, 1+K, 3) with K >= 1 (gripper row then K points), "
                             f"got {x.shape}")

    def _validate(self, theta_unit: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(theta_unit (N, D), x)`` as float64 after the checks of :meth:`fit` (raises as it documents)."""
        u = np.asarray(theta_unit, dtype=np.float64)
        x = np.asarray(x, dtype=np.float64)
        if u.ndim == 1:
            u = u[:, None]
        if u.ndim != 2:
            raise ShapeError(f"theta_unit must have shape (N, D), got {u.shape}")
        self.check_x_shape(x)
        if len(u) != len(x):
            raise ShapeError(f"theta_unit and x must have the same number of simulations N: theta_unit has "
                             f"{len(u)}, x has {len(x)}")
        for name, a in (("theta_unit", u), ("x", x)):
            bad = ~np.isfinite(a.reshape(len(a), -1)).all(axis=1)
            if bad.any():
                rows = np.nonzero(bad)[0]
                raise DataError(f"{name} has non-finite values (NaN/inf) in {len(rows)} simulation(s), rows "
                                f"{rows[:10].tolist()}{'...' if len(rows) > 10 else ''}; drop failed simulations "
                                f"before fitting")
        if len(u) < MIN_SAMPLES:
            raise DataError(f"need at least {MIN_SAMPLES} simulations to fit an estimator, got {len(u)}")
        return u, x

    # ------------------------------------------------------------------ API
    def fit(self, theta_unit: np.ndarray, x: np.ndarray, *, seed: int = 0,
            progress: Callable[[int, int, float], None] | None = None,
            groups: np.ndarray | None = None) -> dict[str, Any]:
        """Train ``q(theta_unit | x)`` by maximum likelihood (MDN negative log-likelihood; BayesSim,
        Ramos et al. 2019, Sec. 3-4) with early stopping (:func:`~softsbi.inference.training.fit_early_stopping`).

        Args:
            theta_unit: ``(N, D)`` (or ``(N,)``) parameters in the unit cube
                (:meth:`~softsbi.core.types.ParamSpace.to_unit`).
            x: ``(N, T, 1+K, 3)`` states in metres (gripper row, then K unordered points).
            seed: seeds the weight init, the train/validation split and the batch order.
            progress: ``progress(epoch, max_epochs, train_loss)`` after every epoch.
            groups: optional ``(N,)`` labels of samples from one simulation (``FitConfig.sensor_draws``): the
                validation split, which early stopping and ``recalibrate`` judge on, holds out whole groups
                (:func:`~softsbi.inference.training.train_val_split`).

        Returns:
            ``{"epochs", "best_epoch", "train_loss", "val_loss", "last_train_loss", "seconds", "n_train",
            "n_val"}``; losses are mean NLL per simulation in nats, in unit-cube coordinates
            (``val_loss`` at the best epoch, whose weights are kept). With ``ensemble > 1`` also
            ``"ensemble"``, ``"member_val_loss"``, ``"member_best_epoch"``, ``"stacked"``,
            ``"ensemble_shared"`` and, for a shared ensemble, ``"heads_cpu_seconds"`` (process CPU time
            of training the heads); with ``recalibrate`` ``"recalibration"``.

        Raises:
            ShapeError: wrong array ranks/shapes or mismatched N.
            DataError: non-finite values, or fewer than 10 simulations.
            RuntimeError: the loss is non-finite in the first epoch (diverged).
            ParameterError: ``ensemble_shared`` with ``stack_members`` / ``embedding_epochs`` or batch norm.
        """
        t0 = time.perf_counter()
        u, x = self._validate(theta_unit, x)
        c = self.config
        D = u.shape[1]
        K = int(c["ensemble"])
        nets: list[MDNNetwork] = []
        with torch_threads(self._threads()):
            z = self.summary_statistics(x)
            self._x_shape = tuple(x.shape[1:])
            self._z_shape = tuple(z.shape[1:])
            # member 0 reproduces the single network; the others get their own initialisation and batch
            # order (deep ensembles, Lakshminarayanan et al. 2017); one train/validation split and
            # standardisation, drawn by member 0's generator, shared by all members
            rngs = [np.random.default_rng(seed if k == 0 else [seed, k]) for k in range(K)]
            tr_idx, val_idx = train_val_split(len(u), float(c["val_fraction"]), rngs[0], min_train=2,
                                              groups=groups)
            self._in_mean, self._in_std = self.input_stats(z[tr_idx])
            zs = self._standardise(z)
            um = u[tr_idx].mean(0)
            us = u[tr_idx].std(0)
            us = np.where(us > 1e-9, np.maximum(us, TARGET_STD_FLOOR * float(us.max())), 1.0)
            self._u_mean, self._u_std = um.astype(np.float32), us.astype(np.float32)
            us_log = float(np.log(self._u_std.astype(np.float64)).sum())  # NLL shift to unit-cube units
            uz = ((u - um) / us).astype(np.float32)
            z_tr, u_tr = torch.as_tensor(zs[tr_idx]), torch.as_tensor(uz[tr_idx])
            z_va, u_va = torch.as_tensor(zs[val_idx]), torch.as_tensor(uz[val_idx])
            for k in range(K):
                torch.manual_seed(seed if k == 0 else seed + MEMBER_SEED_STRIDE * k)
                nets.append(self._build(zs[tr_idx[:2]], D))
            shared = str(c["ensemble_shared"]) if K > 1 else "none"
            if shared != "none" and (c["stack_members"] or c["embedding_epochs"] is not None):
                raise ParameterError(f"ensemble_shared='{shared}' trains member 0 alone and the other members' heads "
                                     f"on its features; it does not combine with stack_members or embedding_epochs "
                                     f"(add ensemble_shared=none)")
            if shared != "none" and not self._stackable(nets[0]):
                raise ParameterError(f"ensemble_shared='{shared}' needs a network without batch normalisation "
                                     f"(set batch_norm=false, or ensemble_shared=none)")
            stacked = (K > 1 and bool(c["stack_members"]) or c["embedding_epochs"] is not None) \
                and self._stackable(nets[0])
            members, epochs, heads_cpu_seconds = train_members(
                c, self.training_view, nets, shared, stacked, z_tr, u_tr, z_va, u_va, rngs, us_log, seed, t0,
                progress)
            for m in members:
                m.update(n_train=int(len(tr_idx)), n_val=int(len(val_idx)))
            if any(m["best_epoch"] == 0 for m in members):
                raise RuntimeError(f"estimator '{self.name}' training diverged (non-finite loss) in the first "
                                   f"epoch; try a smaller lr (now {c['lr']})")
        self._nets = nets
        self._net = nets[0]
        self._cov_scale = 1.0
        self._marginal = None
        recal = None
        if c["recalibrate"]:
            with torch_threads(self._threads()):
                recal = self._recalibrate(zs[val_idx], u[val_idx], seed)
        m0 = members[0]
        self.fit_info = {"epochs": int(epochs), "best_epoch": m0["best_epoch"],
                         "train_loss": m0["train_loss"], "val_loss": float(np.mean([m["val_loss"] for m in members])),
                         "last_train_loss": m0["last_train_loss"],
                         "seconds": time.perf_counter() - t0, "n_train": m0["n_train"], "n_val": m0["n_val"]}
        if recal is not None:
            self.fit_info["recalibration"] = recal
        if K > 1:
            self.fit_info["ensemble"] = K
            self.fit_info["member_val_loss"] = [float(m["val_loss"]) for m in members]
            self.fit_info["member_best_epoch"] = [int(m["best_epoch"]) for m in members]
            self.fit_info["stacked"] = bool(stacked)
            self.fit_info["ensemble_shared"] = shared
            if shared != "none":
                self.fit_info["heads_cpu_seconds"] = heads_cpu_seconds
        return dict(self.fit_info)

    @staticmethod
    def _stackable(net: nn.Module) -> bool:
        """Whether an ensemble of ``net``-shaped members can train as one vmapped network (no batch
        normalisation, whose running statistics ``torch.func.vmap`` cannot update in place)."""
        return not any(isinstance(m, nn.modules.batchnorm._BatchNorm) for m in net.modules())

    #: covariance scale factors tried by ``recalibrate`` (1 = the trained posterior)
    RECAL_SCALES: ClassVar[tuple[float, ...]] = (0.8, 0.9, 1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.65, 1.8, 2.0, 2.25,
                                                 2.5, 2.75, 3.0)
    #: credibility levels at which ``recalibrate`` requires the nominal coverage
    RECAL_LEVELS: ClassVar[tuple[float, ...]] = (0.3, 0.5, 0.7, 0.9)

    def _recalibrate(self, zs_val: np.ndarray, u_val: np.ndarray, seed: int) -> dict[str, Any]:
        """Choose the covariance scale on the validation rows ``zs_val`` (standardised) with truths ``u_val``
        (:func:`~softsbi.inference.recalibration.choose_cov_scale` over :data:`RECAL_SCALES` at
        :data:`RECAL_LEVELS` with the ``recal_margin`` option), after the marginals with ``recal_marginals``.
        Sets ``self._cov_scale``; returns the choice's record."""
        base = self._predict(zs_val)
        marginals = None
        if self.config.get("recal_marginals", False):
            marginals = self._recalibrate_marginals(base, u_val)
            base = self._predict(zs_val)  # with the marginals recalibrated: the joint scale is chosen on top
        out = choose_cov_scale(base, u_val, self.RECAL_SCALES, self.RECAL_LEVELS,
                               float(self.config.get("recal_margin", 0.0)), np.random.default_rng([seed, RECAL_STREAM]),
                               rule=str(self.config.get("recal_rule", "closest")),
                               tolerance_se=float(self.config.get("recal_tolerance_se", 1.0)))
        self._cov_scale = out["cov_scale"]
        return {**out, **({"marginals": marginals} if marginals is not None else {})}

    #: range of the per-parameter scale of ``recal_marginals`` (the largest joint scale of :data:`RECAL_SCALES`, 3,
    #: either way) and the largest shift (posterior standard deviations): rails against a validation split too
    #: small to say more, not tuned
    MARGINAL_SCALE_RANGE: ClassVar[tuple[float, float]] = (1 / 3, 3.0)
    MARGINAL_SHIFT_MAX: ClassVar[float] = 1.0

    def _recalibrate_marginals(self, base: MDNParams, u_val: np.ndarray) -> dict[str, Any]:
        """Per-parameter recalibration (``recal_marginals``) of the validation rows' mixtures ``base (n, C, D)``
        (unit coordinates) against their truths ``u_val (n, D)``: :func:`~softsbi.inference.recalibration.fit_marginals`
        within :data:`MARGINAL_SCALE_RANGE` and :data:`MARGINAL_SHIFT_MAX`. Sets ``self._marginal``; returns
        ``{"scale", "shift", "val_nll_before", "val_nll_after", "lr_pvalue"}`` (each ``(D,)``)."""
        out = fit_marginals(base, u_val, self.MARGINAL_SCALE_RANGE, self.MARGINAL_SHIFT_MAX)
        self._marginal = (np.array(out["scale"]), np.array(out["shift"]))
        return out


