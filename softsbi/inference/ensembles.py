"""Deep ensembles of mixture density networks: the ways the members of
:class:`~softsbi.inference.neural_mdn.NeuralMDNEstimator` train.

The posterior of an ensemble is the equal-weight mixture of its members' mixtures (Lakshminarayanan et al.
2017, "Simple and scalable predictive uncertainty estimation using deep ensembles"; proposed against
over-confident SBI posteriors by Hermans et al. 2022, "A trust crisis in simulation-based inference?").
:func:`train_members` trains them in one of three ways, chosen by the estimator's options:

* one after the other (the default, ``ensemble_shared="none"``), each with its own initialisation and batch
  order, by :func:`~softsbi.inference.training.fit_early_stopping`;
* stacked (``stack_members`` / ``embedding_epochs``, :func:`fit_stacked`): all members as one ``vmap``-ed
  network, the same result up to float rounding;
* on a shared representation (``ensemble_shared="embedding"`` / ``"trunk"``, :func:`fit_shared_heads`):
  member 0 trains end to end, the others train only their heads on its frozen features (this project's own
  variant; its measurements are in docs/benchmarks.md, calibration and estimators-speed).
"""
from __future__ import annotations

import time
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch
from softsbi.core.seeds import VIEW_STREAM
from torch import nn
from torch.func import functional_call, stack_module_state, vmap

from softsbi.inference.mdn import MDNHead, MDNNetwork, MDNParams, mdn_log_prob
from softsbi.inference.training import (fit_early_stopping, fit_early_stopping_stacked, minibatches,
                                        predict_batched)

__all__ = ["train_members", "fit_stacked", "fit_shared_heads", "member_batches", "member_results", "val_loss"]

#: ``training_view(zb, generator)``: the standardised training batch as the embedding net sees it in one step
TrainingView = Callable[[torch.Tensor, torch.Generator], torch.Tensor]


def member_batches(n: int, batch_size: int, rngs: Sequence[np.random.Generator]) -> list[np.ndarray]:
    """One epoch's batches for ``E = len(rngs)`` models trained together: batch ``j`` is ``(E, b)``, row ``e``
    member ``e``'s ``j``-th balanced minibatch drawn by its own generator (as when it trains alone)."""
    per = [minibatches(n, batch_size, rng, balanced=True) for rng in rngs]
    return [np.stack([p[j] for p in per]) for j in range(len(per[0]))]


def member_results(info: Mapping[str, Any]) -> tuple[list[dict[str, Any]], int]:
    """Per-member ``{"epochs", "best_epoch", "val_loss", "train_loss", "last_train_loss"}`` of a
    :func:`~softsbi.inference.training.fit_early_stopping_stacked` result, and the sum of their epochs."""
    members = [{"epochs": int(ep), "best_epoch": int(be), "val_loss": float(vl), "train_loss": float(tl),
                "last_train_loss": float(lt)}
               for ep, be, vl, tl, lt in zip(info["member_epochs"], info["best_epoch"], info["val_loss"],
                                              info["train_loss"], info["last_train_loss"])]
    return members, int(sum(info["member_epochs"]))


class _StackedTails(nn.Module):
    """``E`` copies of ``MLP layers -> MDNHead`` with their weights stacked along a leading member axis and
    applied with batched matrix products (``torch.baddbmm``): the ``E`` heads of the shared-embedding
    ensemble train as one small network without the per-member Python, autograd and ``vmap`` overhead.

    Args:
        mlps: per member an ``nn.Sequential`` of ``Linear`` layers and activations (the same layout).
        heads: per member its :class:`~softsbi.inference.mdn.MDNHead`.

    :meth:`forward` maps features ``(E, B, H)`` (member ``e`` sees row ``e``) to the ``E * B`` mixtures,
    member-major; :meth:`write_back` copies the stacked weights into the members' own layers.
    """

    def __init__(self, mlps: Sequence[nn.Sequential], heads: Sequence[MDNHead]):
        super().__init__()
        self._mlps, self._heads = list(mlps), list(heads)
        self.layers = nn.ParameterList()
        self.acts: list[nn.Module] = []
        for j, m in enumerate(mlps[0]):
            if isinstance(m, nn.Linear):
                self.layers.append(nn.Parameter(torch.stack([q[j].weight.detach().t() for q in mlps]).clone()))
                self.layers.append(nn.Parameter(torch.stack([q[j].bias.detach()[None] for q in mlps]).clone()))
            else:
                self.acts.append(m)
        h0 = heads[0]
        self._parts = [n for n in ("logits", "means", "diag", "off") if getattr(h0, n) is not None]
        self._sizes = [getattr(h0, n).out_features for n in self._parts]
        self.head_w = nn.Parameter(torch.stack([torch.cat([getattr(h, n).weight.detach().t() for n in self._parts], 1)
                                                for h in heads]).clone())
        self.head_b = nn.Parameter(torch.stack([torch.cat([getattr(h, n).bias.detach() for n in self._parts])[None]
                                                for h in heads]).clone())

    def forward(self, h: torch.Tensor) -> MDNParams:
        for j, act in enumerate(self.acts):
            h = act(torch.baddbmm(self.layers[2 * j + 1], h, self.layers[2 * j]))
        out = torch.baddbmm(self.head_b, h, self.head_w).flatten(0, 1)  # (E * B, outputs)
        raw = dict(zip(self._parts, torch.split(out, self._sizes, dim=-1)))
        return self._heads[0].assemble(raw["logits"], raw["means"], raw["diag"], raw.get("off"))

    def write_back(self) -> None:
        """Copy member ``e``'s stacked weights into ``mlps[e]`` and ``heads[e]``."""
        with torch.no_grad():
            for e, (mlp, head) in enumerate(zip(self._mlps, self._heads)):
                lin = [m for m in mlp if isinstance(m, nn.Linear)]
                for j, m in enumerate(lin):
                    m.weight.copy_(self.layers[2 * j][e].t())
                    m.bias.copy_(self.layers[2 * j + 1][e, 0])
                w = torch.split(self.head_w[e], self._sizes, dim=1)
                b = torch.split(self.head_b[e, 0], self._sizes)
                for n, wn, bn in zip(self._parts, w, b):
                    getattr(head, n).weight.copy_(wn.t())
                    getattr(head, n).bias.copy_(bn)

def val_loss(net: nn.Module, z_va: torch.Tensor, u_va: torch.Tensor, chunk: int = 64) -> float:
    """Mean NLL (standardised units) of the validation set ``(z_va, u_va)`` under ``net``."""
    sums = predict_batched(lambda z, u: float(-mdn_log_prob(net(z), u).sum()), z_va, u_va,
                           batch_size=chunk, module=net)
    return sum(sums) / len(z_va)


def train_members(config: Mapping[str, Any], training_view: TrainingView, nets: list[MDNNetwork], shared: str,
                  stacked: bool, z_tr: torch.Tensor, u_tr: torch.Tensor, z_va: torch.Tensor, u_va: torch.Tensor,
                  rngs: list[np.random.Generator], us_log: float, seed: int, t0: float,
                  progress: Callable[[int, int, float], None] | None
                  ) -> tuple[list[dict[str, Any]], int, float]:
    """Train the ensemble ``nets`` (``E >= 1`` members, already initialised) on the standardised training split
    ``(z_tr, u_tr)``, early-stopped on ``(z_va, u_va)``.

    Args:
        config: the estimator's options (``batch_size``, ``lr``, ``patience``, ``max_seconds``...).
        training_view: the estimator's :meth:`~softsbi.inference.neural_mdn.NeuralMDNEstimator.training_view`.
        nets: the members; member ``k``'s batches are drawn by ``rngs[k]``.
        shared: ``"none"``, ``"embedding"`` or ``"trunk"`` (the ``ensemble_shared`` option).
        stacked: train all members as one network (:func:`fit_stacked`).
        us_log: the NLL shift from standardised to unit-cube units (nats).
        seed: the fit's seed (the training view's generator).
        t0: ``time.perf_counter()`` at the start of the fit (``max_seconds`` counts from it).
        progress: ``progress(epoch, max_epochs, train_loss)`` after every epoch.

    Returns:
        ``(members, epochs, heads_cpu_seconds)``: per member ``{"epochs", "best_epoch", "val_loss",
        "train_loss", "last_train_loss"}``, the sum of their epochs, and the process CPU time of training the
        shared ensemble's heads (0 otherwise).
    """
    c = config
    K = len(nets)
    if stacked:
        members, epochs = fit_stacked(c, training_view, nets, z_tr, u_tr, z_va, u_va, rngs, us_log, t0, progress,
                                      gen=torch.Generator().manual_seed(
                                          int(np.random.default_rng([seed, VIEW_STREAM]).integers(2**62))))
        return members, epochs, 0.0
    members = []
    epochs = 0
    heads_cpu_seconds = 0.0
    # ensemble_shared != "none": only member 0 trains end to end; the others train their heads
    # on its frozen features afterwards (fit_shared_heads)
    for k, net in enumerate(nets if shared == "none" else nets[:1]):
        gen = torch.Generator().manual_seed(int(np.random.default_rng([seed, k, VIEW_STREAM]).integers(2**62)))

        def nll(b: np.ndarray, net: MDNNetwork = net, gen: torch.Generator = gen) -> torch.Tensor:
            idx = torch.as_tensor(b)
            return -mdn_log_prob(net(training_view(z_tr[idx], gen)), u_tr[idx]).mean()

        info = fit_early_stopping(
            net, nll, lambda n=len(z_tr), rng=rngs[k]: minibatches(n, int(c["batch_size"]), rng, balanced=True),
            validate=lambda net=net: val_loss(net, z_va, u_va) + us_log,
            max_epochs=int(c["max_epochs"]), patience=int(c["patience"]),
            min_epochs=int(c["min_epochs"]), lr=float(c["lr"]), weight_decay=float(c["weight_decay"]),
            grad_clip=float(c["grad_clip"]) if c["grad_clip"] else None,
            loss_offset=us_log, progress=progress,
            max_seconds=None if c["max_seconds"] is None else float(c["max_seconds"]) / K,
            t0=t0 if k == 0 else time.perf_counter())
        epochs += int(info["epochs"])
        members.append({k2: info[k2] for k2 in ("epochs", "best_epoch", "val_loss", "train_loss",
                                                 "last_train_loss")})
    if shared != "none" and members[0]["best_epoch"] > 0:
        t_heads = time.process_time()
        heads, head_epochs = fit_shared_heads(c, nets, shared, z_tr, u_tr, z_va, u_va, rngs[1:], us_log, progress)
        members += heads
        epochs += head_epochs
        heads_cpu_seconds = time.process_time() - t_heads
    return members, epochs, heads_cpu_seconds


def fit_stacked(config: Mapping[str, Any], training_view: TrainingView, nets: list[MDNNetwork], z_tr: torch.Tensor, u_tr: torch.Tensor, z_va: torch.Tensor,
                 u_va: torch.Tensor, rngs: list[np.random.Generator], us_log: float, t0: float,
                 progress: Callable[[int, int, float], None] | None, chunk: int = 256,
                 gen: torch.Generator | None = None) -> tuple[list[dict[str, Any]], int]:
    """Train the ``E`` ensemble members ``nets`` as one network: their parameters stacked along a
    leading axis (``torch.func.stack_module_state``), the forward pass batched over members with
    ``torch.func.vmap`` of ``functional_call``, and
    :func:`~softsbi.inference.training.fit_early_stopping_stacked` (per-member clipping, validation,
    best epoch and patience). Member ``e`` sees the batches its own generator ``rngs[e]`` draws,
    as when trained alone, so this is the sequential ensemble up to floating-point rounding, with
    the per-step overhead paid once. The best weights are written into ``nets``. ``training_view`` is the
    estimator's :meth:`~softsbi.inference.neural_mdn.NeuralMDNEstimator.training_view` (drawn with ``gen``).

    Returns:
        ``(members, epochs)``: per-member ``{"epochs", "best_epoch", "val_loss", "train_loss",
        "last_train_loss"}`` and the epochs run.
    """
    c = config
    E = len(nets)
    params, buffers = stack_module_state(nets)
    base = nets[0]
    n_tr = len(z_tr)
    freeze_after = c.get("embedding_epochs")
    if not any(True for _ in base.features.parameters()):
        freeze_after = 0  # a fixed embedding (e.g. Flatten): its features never change
    cache: dict[str, torch.Tensor] = {}

    def member_nll_sum(p: dict, b: dict, zb: torch.Tensor, ub: torch.Tensor, embedded: bool) -> torch.Tensor:
        return -mdn_log_prob(functional_call(base, (p, b), (zb,), {"embedded": embedded}), ub).sum()

    train_nll = vmap(member_nll_sum, in_dims=(0, 0, 0, 0, None))
    val_nll = vmap(member_nll_sum, in_dims=(0, 0, 0, None, None))

    def embed(zz: torch.Tensor) -> torch.Tensor:
        """``(E, n, F)`` features of every member for inputs ``zz (n, ...)`` (no gradient)."""
        fp = {k[9:]: v for k, v in params.items() if k.startswith("features.")}
        fb = {k[9:]: v for k, v in buffers.items() if k.startswith("features.")}
        with torch.no_grad():
            if not fp and not fb:  # a fixed embedding: the same features for every member
                f = torch.cat([base.features(zz[i:i + chunk]) for i in range(0, len(zz), chunk)])
                return f.expand((E,) + f.shape)
            one = vmap(lambda p, b, x: functional_call(base.features, (p, b), (x,)), in_dims=(0, 0, None))
            return torch.cat([one(fp, fb, zz[i:i + chunk]) for i in range(0, len(zz), chunk)], dim=1)

    def freeze(epoch: int) -> None:
        """From epoch ``freeze_after`` on, the embedding nets stay as they are: their features of the
        training and validation inputs are computed once, and only the MLP and head train on."""
        if freeze_after is not None and epoch == freeze_after and not cache:
            cache["train"], cache["val"] = embed(z_tr), embed(z_va)

    freeze(0)
    def sub(a: torch.Tensor) -> dict:
        """``params``/``buffers`` rows of the still-training members ``a`` (all: no copy)."""
        if len(a) == E:
            return params, buffers
        return {k: v[a] for k, v in params.items()}, {k: v[a] for k, v in buffers.items()}

    def loss(batch: np.ndarray, active: torch.Tensor) -> torch.Tensor:
        idx = torch.as_tensor(batch)[active]  # (A, b): member active[j]'s batch
        p, b = sub(active)
        if cache:
            feats = cache["train"][active[:, None], idx]
            return train_nll(p, b, feats, u_tr[idx], True) / idx.shape[1]
        zb = z_tr[idx]  # (A, b, ...): the training view (e.g. point subsets) drawn for all members at once
        zb = training_view(zb.flatten(0, 1), gen).unflatten(0, idx.shape) if gen is not None else zb
        return train_nll(p, b, zb, u_tr[idx], False) / idx.shape[1]

    def batches() -> list[np.ndarray]:
        return member_batches(n_tr, int(c["batch_size"]), rngs)

    def validate(active: torch.Tensor) -> np.ndarray:
        p, b = sub(active)
        with torch.no_grad():
            if cache:
                f = cache["val"][active]
                tot = sum(val_nll(p, b, f[:, i:i + chunk], u_va[i:i + chunk], True)
                          for i in range(0, len(z_va), chunk))
            else:
                zv = z_va.expand((len(active),) + z_va.shape)
                tot = sum(val_nll(p, b, zv[:, i:i + chunk], u_va[i:i + chunk], False)
                          for i in range(0, len(z_va), chunk))
        return tot.double().numpy() / len(z_va) + us_log

    for net in nets:
        net.train()
    info = fit_early_stopping_stacked(
        params, loss, batches, validate, max_epochs=int(c["max_epochs"]), patience=int(c["patience"]),
        min_epochs=int(c["min_epochs"]), lr=float(c["lr"]), weight_decay=float(c["weight_decay"]),
        grad_clip=float(c["grad_clip"]) if c["grad_clip"] else None, loss_offset=us_log,
        max_seconds=None if c["max_seconds"] is None else float(c["max_seconds"]), progress=progress,
        on_epoch_end=freeze, t0=t0)
    with torch.no_grad():
        for e, net in enumerate(nets):
            for name, p in net.named_parameters():
                p.copy_(params[name][e])
            net.eval()
    return member_results(info)

def fit_shared_heads(config: Mapping[str, Any], nets: list[MDNNetwork], shared: str, z_tr: torch.Tensor, u_tr: torch.Tensor,
                      z_va: torch.Tensor, u_va: torch.Tensor, rngs: list[np.random.Generator], us_log: float,
                      progress: Callable[[int, int, float], None] | None, chunk: int = 64
                      ) -> tuple[list[dict[str, Any]], int]:
    """Train members ``1..E-1`` of ``nets`` on the frozen features of member 0 (already trained end to
    end): the shared-embedding ensemble of the ``ensemble_shared`` option.

    The shared part ``phi`` (``"embedding"``: the embedding net; ``"trunk"``: the embedding net and the
    first MLP layer with its activation) is copied from member 0 into every member, and
    ``phi(z)`` of the training and validation inputs is computed once (all points, no gradient).
    The remaining layers of each member (its own initialisation, its own batch order from ``rngs``)
    then train by maximum likelihood with early stopping on those cached features, all members as
    one stacked network (:class:`_StackedTails`, batched matrix products) with
    :func:`~softsbi.inference.training.fit_early_stopping_stacked` (per-member clipping, validation,
    best epoch and patience). This is a deep ensemble
    (Lakshminarayanan et al. 2017) of the heads only, on one learned representation (a
    "multi-head"/last-layers ensemble; the choice of what to share and the rest of this procedure
    are this project's own, measured by the calibration and estimators-speed suites, docs/benchmarks.md):
    the members no longer differ in their embedding, but training them costs a few small MLPs instead of
    ``E - 1`` embeddings of every point of every frame in every epoch.

    Returns:
        ``(members, epochs)``: per trained member ``{"epochs", "best_epoch", "val_loss", "train_loss",
        "last_train_loss"}`` and the sum of their epochs.
    """
    c = config
    first, rest = nets[0], nets[1:]
    n_shared = 2 if shared == "trunk" and len(first.mlp) >= 2 else 0  # Linear + activation
    with torch.no_grad():
        for net in rest:
            net.features.load_state_dict(first.features.state_dict())
            for j in range(n_shared):
                net.mlp[j].load_state_dict(first.mlp[j].state_dict())

    def phi(zz: torch.Tensor) -> torch.Tensor:
        f = first.features(zz)
        return first.mlp[:n_shared](f) if n_shared else f

    h_tr = torch.cat(predict_batched(phi, z_tr, batch_size=chunk, module=first))
    h_va = torch.cat(predict_batched(phi, z_va, batch_size=chunk, module=first))

    E, n_tr = len(rest), len(h_tr)
    tails = _StackedTails([net.mlp[n_shared:] for net in rest], [net.head for net in rest])
    params = dict(tails.named_parameters())

    def loss(batch: np.ndarray, active: torch.Tensor) -> torch.Tensor:
        idx = torch.as_tensor(batch)  # (E, b): member e's batch
        lp = mdn_log_prob(tails(h_tr[idx]), u_tr[idx].reshape(-1, u_tr.shape[1])).view(E, -1)
        return -lp.mean(1)[active]  # all members computed (small), only the active ones learn

    def batches() -> list[np.ndarray]:
        return member_batches(n_tr, int(c["batch_size"]), rngs)

    u_va_all = u_va.repeat(E, 1)

    def validate(active: torch.Tensor) -> np.ndarray:
        with torch.no_grad():
            lp = mdn_log_prob(tails(h_va.expand(E, -1, -1)), u_va_all).view(E, -1)
        return -lp.double().mean(1)[active].numpy() + us_log

    info = fit_early_stopping_stacked(
        params, loss, batches, validate, max_epochs=int(c["max_epochs"]), patience=int(c["patience"]),
        min_epochs=int(c["min_epochs"]), lr=float(c["lr"]), weight_decay=float(c["weight_decay"]),
        grad_clip=float(c["grad_clip"]) if c["grad_clip"] else None, loss_offset=us_log,
        max_seconds=None if c["max_seconds"] is None else float(c["max_seconds"]), progress=progress)
    tails.write_back()
    for net in rest:
        net.eval()
    return member_results(info)
