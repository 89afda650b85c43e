"""Neural posterior estimators: feature network -> MLP -> mixture density network.

Sources:
    * BayesSim (Ramos, Possas, Fox, RSS 2019), Sec. 3-4: ``q(theta | x)`` is a mixture
      density network on summary statistics of the trajectory (:class:`MDNNEstimator`).
    * BayesSim-RKHS (Antonova et al., "A Bayesian Treatment of Real-to-Sim for Deformable
      Object Manipulation", RA-L 2022), Sec. IV: a trainable kernel mean embedding
      (RKHS-net) of each frame's unordered point cloud feeds the MDN (:class:`RKHSEstimator`).

Both subclass :class:`~softsbi.inference.neural_mdn.NeuralMDNEstimator` (re-exported here), which handles
validation, input/target standardisation, the train/validation split with early stopping, determinism, and
the (numpy) state dict. New estimators reuse it by overriding the hooks
:meth:`~softsbi.inference.neural_mdn.NeuralMDNEstimator.summary_statistics` (fixed NumPy summary statistics
of an observation), :meth:`~softsbi.inference.neural_mdn.NeuralMDNEstimator.input_stats` (standardisation
statistics) and :meth:`~softsbi.inference.neural_mdn.NeuralMDNEstimator.embedding_net` (trainable embedding
network).

Notation: ``theta_unit`` are the simulator parameters ``theta`` mapped to the unit cube by
:meth:`~softsbi.core.types.ParamSpace.to_unit`; the estimators learn ``q(theta_unit | x)``.

Registered through the ``softsbi_estimators`` hook as ``rkhs`` and ``mdnn``.
"""
from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from softsbi.core.errors import ParameterError
from softsbi.core.interfaces import PosteriorEstimator
from softsbi.plugins.hookspecs import hookimpl
from softsbi.inference.mdn import MDNNetwork
from softsbi.inference.neural_mdn import NeuralMDNEstimator
from softsbi.inference.recalibration import marginal_affine
from softsbi.inference.rkhs import RKHSFrameFeatures, point_moments
from softsbi.inference.summaries import bayessim_summaries, local_thickness

# NeuralMDNEstimator, MDNNetwork, RKHSFrameFeatures, point_moments and marginal_affine live in their own modules
# (neural_mdn, mdn, rkhs, recalibration) and stay importable from here
__all__ = ["NeuralMDNEstimator", "RKHSEstimator", "MDNNEstimator", "MDNNetwork", "RKHSFrameFeatures",
           "point_moments", "marginal_affine", "softsbi_estimators"]


class RKHSEstimator(NeuralMDNEstimator):
    """BayesSim-RKHS (Antonova et al. 2022, Sec. IV): RKHS-net mean embedding per frame -> MLP -> MDN.

    Each frame's K points (unordered) are embedded by one shared trainable random-Fourier-
    feature layer and averaged (kernel mean embedding), concatenated with that frame's
    gripper position, flattened over the T frames and fed to the MLP/MDN.

    Inputs are standardised with training statistics: every frame is centred on the mean
    training point-cloud centroid of that frame, and all coordinates (points and gripper)
    are divided by one isotropic scale (the RMS spread of the training points), so the
    kernel stays isotropic in metric space and ``rkhs_sigma = 1`` is about the object size.

    Defaults that differ from :class:`NeuralMDNEstimator`'s: a recalibrated deep ensemble of 5 independent
    networks (``ensemble=5, recalibrate=True``; Lakshminarayanan et al. 2017), each trained end to end on random
    8-point subsets of every frame (:data:`SUBSETS`: ``ensemble_shared="none", point_subset=8, lr=3e-3,
    patience=8``; an unbiased estimate of the kernel mean embedding per step; every point at validation and
    prediction), then recalibrated on the validation split: each parameter's marginal by a scale and a shift
    (``recal_marginals=True``, maximum likelihood, kept only where a likelihood-ratio test rejects the trained
    marginal), then every component's covariance by the scale whose validation coverage lies closest to nominal
    (``recal_rule="closest"``). *Why:* on the lift task's 12 trained models (docs/benchmarks.md,
    posterior-calibration) the previous default, a shared-trunk ensemble (:data:`SHARED_TRUNK`: the other members'
    heads trained on member 0's frozen trunk) with one covariance scale, was over-confident in some marginals and
    too wide in others (TARP rejected 10 of 12, SBC 10 of 12); independent members, per-marginal recalibration and
    the closest scale are the ensemble and recalibration of Hermans et al. 2022. :data:`END_TO_END`
    (``ensemble_shared=none, point_subset=0, lr=0.001, patience=15``) trains 5 independent networks on every
    point; ``ensemble=1, recalibrate=False`` with those is the single network of Antonova et al. 2022.

    Extra config options (besides :class:`NeuralMDNEstimator`'s):
        rkhs_features: number of frequencies ``M`` per layer (output ``2M``), default 32.
        rkhs_sigma: initial bandwidth in standardised units, default 0.5.
        rkhs_learn: train frequencies and bandwidth (paper: yes), default True.
        point_subset: points per frame that one end-to-end training step embeds (a uniform random subset,
            drawn anew every step; see :meth:`training_view`), default None (every point; 0 too).
        batch_norm: batch-normalise the flattened embedding before the MLP, default False (it trained in
            fewer epochs but generalised worse).
        frame_moments: append each frame's first and raw second point moments (:func:`point_moments`, 9
            numbers: centroid and spread) to its embedding, default False (the posterior-mean rollout came no
            closer to the truth with them).
        frame_thickness: append each frame's :func:`~softsbi.inference.summaries.local_thickness` (log10 mm,
            computed from every point) to its embedding, default False. Switched on by a fit whose model has an
            effect that asks for it (``Effect.estimator_options``: point noise), because the random-Fourier-
            feature embedding cannot see centimetre noise: without it the posterior of the noise's standard
            deviation stayed the prior.

    ``posterior_at`` accepts any number of points K' >= 1 per frame (same T).
    """

    name: ClassVar[str] = "rkhs"
    #: independent members trained on 8-point subsets (part of the default; docs/benchmarks.md,
    #: posterior-calibration)
    SUBSETS: ClassVar[dict[str, Any]] = {"ensemble_shared": "none", "point_subset": 8, "lr": 3e-3, "patience": 8}
    #: the shared-trunk ensemble's training: the members' heads on member 0's frozen trunk (the previous default;
    #: docs/benchmarks.md, estimators-speed)
    SHARED_TRUNK: ClassVar[dict[str, Any]] = {**SUBSETS, "ensemble_shared": "trunk"}
    #: every network trained end to end on every point, the base's learning rate and patience: the previous
    #: default's training (with ``ensemble=5, recalibrate=True``) and the baselines' (nn-bulk, bayeszoom-rkhs)
    END_TO_END: ClassVar[dict[str, Any]] = {"ensemble_shared": "none", "point_subset": None, "lr": 1e-3, "patience": 15}
    #: ``ensemble=5, recalibrate=True, recal_marginals=True`` with :data:`SUBSETS`: the calibrated default
    #: (docs/benchmarks.md, posterior-calibration)
    EXTRA_DEFAULTS: ClassVar[dict[str, Any]] = {"ensemble": 5, "recalibrate": True, "recal_marginals": True,
                                                "rkhs_features": 32, "rkhs_sigma": 0.5, "rkhs_learn": True,
                                                "batch_norm": False, "frame_moments": False, "frame_thickness": False,
                                                **SUBSETS}

    def __init__(self, **config: Any):
        super().__init__(**config)
        k = self.config.get("point_subset")
        if isinstance(k, str) and k.lower() == "none" or k == 0:
            k = self.config["point_subset"] = None
        if k is not None and (isinstance(k, (bool, str)) or int(k) != k or int(k) < 1):
            raise ParameterError(f"point_subset must be an integer >= 1 (points per frame in a training step), or "
                                 f"0 / None for every point; got {k!r}")

    def training_view(self, zb: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """``zb (B, T, 1+K, 3)`` with each frame's K points replaced by ``k = point_subset`` of them (the
        gripper row stays): per frame ``t`` one uniform random subset of the point rows, drawn without
        replacement anew for every gradient step and shared by the simulations of the batch (one
        ``(T, k)`` index draw: cheap, where a draw per simulation and frame is not).

        The mean of the random Fourier features over a uniform random subset is an unbiased estimate of
        their mean over all K points, so each gradient step sees an unbiased, noisier kernel mean
        embedding at ``k / K`` of the cost (a stochastic embedding; this use of subsampling is this
        project's own). Validation and prediction
        embed every point. ``point_subset`` None or ``>= K``: ``zb`` unchanged."""
        k = self.config.get("point_subset")
        B, T, R, d = zb.shape
        h = self._head_rows()
        if not k or int(k) >= R - h:
            return zb
        pick = torch.rand(T, R - h, generator=generator).argsort(-1)[:, :int(k)] + h  # (T, k) point rows
        head = torch.arange(h, dtype=pick.dtype).expand(T, h)
        rows = torch.cat([head, pick], -1)  # gripper row (and thickness row) first
        return zb[:, torch.arange(T)[:, None], rows]

    def _head_rows(self) -> int:
        """Rows of the summary statistics before the points: the gripper, and the thickness row with
        ``frame_thickness``."""
        return 2 if self.config.get("frame_thickness") else 1

    #: the thickness row's value: ``log10(thickness / THICKNESS_UNIT_M)``, about -1 to 1 for 0.1-10 mm
    THICKNESS_UNIT_M: ClassVar[float] = 1e-3

    def summary_statistics(self, x: np.ndarray) -> np.ndarray:
        """The states themselves ``(N, T, 1+K, 3)`` float32; with ``frame_thickness`` a row inserted after the
        gripper row, ``(N, T, 2+K, 3)``, whose first entry is ``log10`` of the frame's
        :func:`~softsbi.inference.summaries.local_thickness` in mm (computed from every point, so the
        training's point subsets do not change it; the other two entries are 0)."""
        z = np.asarray(x, dtype=np.float32)
        if not self.config.get("frame_thickness"):
            return z
        th = local_thickness(np.asarray(x, np.float64)[:, :, 1:, :])  # (N, T) m
        row = np.zeros(z.shape[:2] + (1, 3), np.float32)
        row[..., 0, 0] = np.log10(np.maximum(th, 1e-7) / self.THICKNESS_UNIT_M)
        return np.concatenate([z[:, :, :1], row, z[:, :, 1:]], axis=2)

    def _standardise(self, z: np.ndarray) -> np.ndarray:
        zs = super()._standardise(z)
        if self.config.get("frame_thickness"):
            zs[:, :, 1, :] = z[:, :, 1, :]  # already on a fixed scale (log10 mm), not the points' standardisation
        return zs

    def input_stats(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = z[:, :, self._head_rows():, :].astype(np.float64)  # (N, T, K, 3)
        centre = pts.mean(axis=(0, 2))  # (T, 3)
        scale = float(np.sqrt(((pts - centre[None, :, None, :]) ** 2).sum(-1).mean() / 3.0))
        scale = scale if scale > 1e-9 else 1.0
        mean = np.broadcast_to(centre[:, None, :], z.shape[1:2] + (1, 3))
        std = np.full((1, 1, 1), scale)
        return mean.astype(np.float32), std.astype(np.float32)

    def embedding_net(self, z_example: np.ndarray) -> nn.Module:
        """:class:`RKHSFrameFeatures` for ``z_example (n, T, 1+K, 3)``: output ``(n, T * (2M + 3))``."""
        c = self.config
        return RKHSFrameFeatures(int(c["rkhs_features"]), float(c["rkhs_sigma"]), bool(c["rkhs_learn"]),
                                 bool(c["batch_norm"]), n_frames=z_example.shape[1],
                                 moments=bool(c.get("frame_moments", False)),
                                 thickness=bool(c.get("frame_thickness", False)))

    def check_x_obs_shape(self, shape: tuple[int, ...]) -> bool:
        T, _, d = self._x_shape  # type: ignore[misc]
        return len(shape) == 3 and shape[0] == T and shape[1] >= 2 and shape[2] == d

    def _expected(self) -> str:
        T, R, d = self._x_shape  # type: ignore[misc]
        return f"{T}, 1+K, {d}) with K >= 1 (trained with K={R - 1}"


class MDNNEstimator(NeuralMDNEstimator):
    """BayesSim MDN (Ramos et al. 2019, Sec. 3-4): summary statistics -> MLP -> MDN.

    Features are :func:`~softsbi.inference.summaries.bayessim_summaries` of the flattened
    state (cross-correlations of state differences with gripper displacements, mean and
    variance of the state differences), standardised per feature. The cloth points are an
    unordered set, so these statistics mix unrelated points; this baseline is expected to
    do worse than ``rkhs`` (the point of Antonova et al. 2022). Requires the same ``K`` at
    fit and ``posterior_at``.
    """

    name: ClassVar[str] = "mdnn"

    def summary_statistics(self, x: np.ndarray) -> np.ndarray:
        """BayesSim summaries ``(N, F)`` float32 of ``x (N, T, 1+K, 3)`` (Ramos et al. 2019, Sec. 4)."""
        return bayessim_summaries(x).astype(np.float32)


@hookimpl
def softsbi_estimators() -> list[type[PosteriorEstimator]]:
    """Estimators of this module (``rkhs``, ``mdnn``)."""
    return [RKHSEstimator, MDNNEstimator]
