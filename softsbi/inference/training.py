"""Shared torch training utilities: thread scoping, the early-stopping loop, batched prediction.

One implementation serves every trainable model of softsbi (the neural posterior estimators of
:mod:`softsbi.inference.estimators` / :mod:`softsbi.inference.baselines` and the keypoint
extractors of :mod:`softsbi.perception.keypoints`), so they share one stopping rule:

* :func:`torch_threads` scopes torch's intra-op thread count (saved, set, restored -- also when
  the body raises).
* :func:`train_val_split` and :func:`minibatches` draw the random validation split and the
  per-epoch batch order from a NumPy generator.
* :func:`fit_early_stopping` is the training loop: mini-batch gradient steps (Adam by default),
  validation after every epoch, *early stopping* with a patience (Prechelt, "Early Stopping --
  But When?", in Neural Networks: Tricks of the Trade, 1998), and the weights of the best
  validation epoch restored at the end.
* :func:`fit_early_stopping_stacked` is the same loop for ``E`` independent models whose parameters
  are stacked along a leading axis (a deep ensemble trained as one ``torch.func.vmap``-ed network):
  per-model gradient clipping, validation, best weights and patience; one gradient step per batch
  for all models, so the per-step Python and autograd overhead is paid once instead of ``E`` times.
* :func:`predict_batched` applies a module to consecutive slices of its inputs in eval mode
  without gradients.

Determinism: the loop draws random numbers only through the callables it is given (``batches``,
``loss_fn``, ``validate``), in that order, once per epoch; given the same seeds it reproduces the
same weights bit for bit.
"""
from __future__ import annotations

import contextlib
import copy
import math
import os
import time
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence, TypeVar

import numpy as np
import torch
from torch import nn

__all__ = ["available_cpus", "threads_option", "torch_threads", "train_val_split", "minibatches", "fit_early_stopping",
           "fit_early_stopping_stacked", "predict_batched"]

B = TypeVar("B")
T = TypeVar("T")


def available_cpus() -> int:
    """Number of CPUs this process may run on (its affinity mask; ``os.cpu_count()`` elsewhere), >= 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


def threads_option(n: int | None) -> int:
    """The ``num_threads`` option of an estimator: ``n``, or every available CPU when None/0."""
    return int(n) if n else available_cpus()


@contextlib.contextmanager
def torch_threads(n: int | None, convolutions: bool = False) -> Iterator[None]:
    """Scope torch's intra-op thread count (``torch.set_num_threads``) to a ``with`` block.

    Args:
        n: threads inside the block; ``None`` or ``0`` leaves torch's current setting alone.
        convolutions: the block trains or runs convolutional networks. With one intra-op thread,
            torch 2.13's oneDNN (mkldnn) CPU convolutions corrupt the heap on channels-last inputs
            (segfault or "double free or corruption", reproduced here with the heatmap network), so
            oneDNN is switched off inside the block when torch runs on one thread (numbers with more
            threads are unchanged).

    The previous settings are restored on exit, also when the block raises.

    Example:
        >>> with torch_threads(1):
        ...     pass  # single-threaded torch here
    """
    old = torch.get_num_threads()
    if n:
        torch.set_num_threads(int(n))
    try:
        mkldnn = torch.backends.mkldnn.enabled
        if convolutions and torch.get_num_threads() == 1:
            torch.backends.mkldnn.enabled = False
        try:
            yield
        finally:
            torch.backends.mkldnn.enabled = mkldnn
    finally:
        torch.set_num_threads(old)


def train_val_split(n: int, val_fraction: float, rng: np.random.Generator, *, min_train: int = 1,
                    min_val: int = 1, groups: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Random train/validation split of ``n`` samples.

    Draws one permutation ``rng.permutation(n)`` (always, even when nothing is held out, so the
    generator's state afterwards does not depend on ``val_fraction``); its first
    ``n_val = min(max(min_val, round(val_fraction * n)), n - min_train)`` entries are the
    validation indices (``n_val = 0`` when ``val_fraction <= 0``).

    With ``groups`` (``(n,)`` labels: samples of one simulation observed several times,
    ``FitConfig.sensor_draws``) whole groups are held out: one permutation of the groups
    (``rng.permutation(n_groups)``), whose first groups go to validation until they hold at least ``n_val``
    samples (never leaving fewer than ``min_train``). A validation sample whose simulation is also in the
    training set would make early stopping and recalibration judge the network on what it has seen.

    Args:
        n: number of samples.
        val_fraction: share held out, in ``[0, 1)``.
        rng: NumPy generator.
        min_train: fewest training samples left (takes precedence over ``min_val``).
        min_val: fewest validation samples when ``val_fraction > 0``.
        groups: optional ``(n,)`` group labels.

    Returns:
        ``(train_idx (n - n_val,), val_idx (n_val,))`` int arrays in permutation order (not sorted).
    """
    n_val = max(0, min(max(int(min_val), int(round(float(val_fraction) * n))), n - int(min_train))) \
        if val_fraction > 0 else 0
    if groups is None:
        perm = rng.permutation(n)
        return perm[n_val:], perm[:n_val]
    groups = np.asarray(groups)
    if groups.shape != (n,):
        raise ValueError(f"groups must have shape ({n},), got {groups.shape}")
    labels = np.unique(groups)
    members = [np.nonzero(groups == g)[0] for g in labels[rng.permutation(len(labels))]]
    val: list[np.ndarray] = []
    held = 0
    for m in members:
        if held >= n_val or n - held - len(m) < min_train:
            break
        val.append(m)
        held += len(m)
    rest = members[len(val):]
    cat = lambda parts: np.concatenate(parts) if parts else np.zeros(0, int)  # noqa: E731
    return cat(rest), cat(val)


def minibatches(n: int, batch_size: int, rng: np.random.Generator, *, balanced: bool = False,
                min_size: int = 1) -> list[np.ndarray]:
    """Shuffled mini-batches of ``range(n)`` for one epoch (one ``rng.permutation(n)`` draw).

    Args:
        n: number of training samples.
        batch_size: largest batch.
        rng: NumPy generator.
        balanced: split the permutation into ``ceil(n / batch_size)`` batches of (nearly) equal size
            (``np.array_split``) instead of full batches followed by a remainder.
        min_size: with ``balanced=False``, a last batch smaller than this is merged into the one
            before (e.g. 2 for BatchNorm, which needs more than one sample).

    Returns:
        List of int index arrays covering ``range(n)`` once.
    """
    perm = rng.permutation(n)
    bs = max(1, int(batch_size))
    if balanced:
        return list(np.array_split(perm, max(1, math.ceil(n / bs))))
    starts = list(range(0, n, bs))
    if len(starts) > 1 and n - starts[-1] < min_size:
        starts.pop()
    return [perm[s:(starts[j + 1] if j + 1 < len(starts) else n)] for j, s in enumerate(starts)]


def _improves(key: Sequence[float], best: Sequence[float], min_delta: float) -> bool:
    """``key`` beats ``best``: its first entry is lower by more than ``min_delta``, or equal with the
    remaining entries lexicographically lower (ties broken by the later entries)."""
    if key[0] < best[0] - min_delta:
        return True
    for a, b in zip(key, best):
        if a != b:
            return a < b and key[0] == best[0]
    return False


def _adam(params: list[torch.Tensor], lr: float, weight_decay: float) -> torch.optim.Optimizer:
    """``torch.optim.Adam`` (Kingma & Ba 2015) with torch's fused kernel where every parameter is a floating
    CPU or CUDA tensor (the same update; measured less time per step than the default multi-tensor
    implementation on the RKHS estimator's 0.5 M parameters, one CPU thread: ~0.7 ms of a 8 ms step)."""
    fused = all(p.dtype in (torch.float32, torch.float64) and p.device.type in ("cpu", "cuda") for p in params)
    return torch.optim.Adam(params, lr=float(lr), weight_decay=float(weight_decay), fused=fused or None)


def fit_early_stopping(net: nn.Module, loss_fn: Callable[[B], torch.Tensor], batches: Callable[[], Iterable[B]], *,
                       max_epochs: int, patience: int, min_epochs: int = 1,
                       validate: Callable[[], float | Mapping[str, float]] | None = None,
                       monitor: Sequence[str] = ("val_loss",), min_delta: float = 0.0,
                       optimizer: torch.optim.Optimizer | None = None, lr: float = 1e-3, weight_decay: float = 0.0,
                       scheduler: Any = None, grad_clip: float | None = None, loss_offset: float = 0.0,
                       stop_on_nonfinite: bool = True, max_seconds: float | None = None,
                       progress: Callable[[int, int, float], None] | None = None,
                       history: list[dict[str, float]] | None = None, t0: float | None = None) -> dict[str, Any]:
    """Train ``net`` by mini-batch gradient descent with early stopping on a validation score.

    Every epoch: ``net.train()``; for each batch of ``batches()`` (called once per epoch, so it may
    reshuffle): ``loss = loss_fn(batch)``, zero the gradients, backpropagate, clip the gradient norm
    to ``grad_clip`` (if given), step the optimiser; then ``scheduler.step()`` (if given). The
    epoch's training loss is the batch losses averaged with weights ``len(batch)``, plus
    ``loss_offset``. Then ``validate()`` scores the epoch; when the score (the ``monitor`` entries,
    compared lexicographically) improves on the best one by more than ``min_delta`` (first entry),
    a copy of the weights is kept. Training stops after ``max_epochs``, when ``patience`` epochs in a
    row brought no improvement (only once ``epoch >= min_epochs``, and only with ``validate``), when
    ``max_seconds`` have passed since ``t0``, or (``stop_on_nonfinite``) at the first non-finite
    training loss (before validating that epoch). The best weights are then loaded and ``net`` is
    left in eval mode.

    Args:
        net: the model; its parameters are optimised.
        loss_fn: ``batch -> scalar loss tensor`` (with gradient).
        batches: returns the batches of one epoch (``len(batch)`` = samples in it), e.g.
            ``lambda: minibatches(n, 64, rng)``.
        max_epochs: most epochs.
        patience: epochs without improvement before stopping.
        min_epochs: no early stop before this epoch.
        validate: returns the validation loss of the current weights, or a mapping of named
            validation metrics (which must hold every ``monitor`` key, and ``"val_loss"``). ``None``:
            no validation data; the best epoch is the one with the lowest training loss, and there is
            no early stop.
        monitor: metric names forming the score, lower is better; ties on the first are broken by the
            next ones (e.g. ``("val_mean_px", "val_loss")``).
        min_delta: least decrease of the first score entry that counts as an improvement.
        optimizer: the optimiser; default ``torch.optim.Adam(net.parameters(), lr, weight_decay)``
            (Kingma & Ba 2015).
        lr, weight_decay: of the default Adam.
        scheduler: learning-rate scheduler stepped once per epoch (needs ``optimizer``).
        grad_clip: max gradient 2-norm (``nn.utils.clip_grad_norm_``); None: no clipping.
        loss_offset: constant added to the reported training loss (e.g. the log-Jacobian of a target
            standardisation); ``validate`` includes its own.
        stop_on_nonfinite: stop at a NaN/inf training loss.
        max_seconds: wall-clock budget (None: none); the best weights so far are kept.
        progress: ``progress(epoch, max_epochs, train_loss)`` after every completed epoch.
        history: list to append the per-epoch rows to while training (so ``progress`` can read
            them); a new list by default.
        t0: ``time.perf_counter()`` at the start of the whole fit (default: now), for ``max_seconds``
            and the ``seconds`` entries.

    Returns:
        ``{"epochs", "best_epoch", "train_loss", "val_loss", "last_train_loss", "seconds", "history",
        "best"}``: epochs run; the best epoch (0 when no epoch improved, e.g. a non-finite loss in
        the first epoch: the weights are then left as they are, and callers usually raise); training
        and validation loss at the best epoch (``inf`` if none); the last epoch's training loss;
        seconds since ``t0``; the rows ``{"epoch", "train_loss", "val_loss", <metrics>, "seconds"}``
        of every validated epoch; the best row (None if none).

    Raises:
        KeyError: ``validate`` returns a mapping without a ``monitor`` key.
    """
    t0 = time.perf_counter() if t0 is None else t0
    opt = optimizer if optimizer is not None else _adam(list(net.parameters()), lr, weight_decay)
    history = [] if history is None else history
    best: dict[str, float] | None = None
    best_key: tuple[float, ...] = (math.inf,) * len(monitor)
    best_state = None
    best_epoch = 0
    epoch = 0
    train_loss = math.inf
    for epoch in range(1, int(max_epochs) + 1):
        net.train()
        total, count = 0.0, 0
        for batch in batches():
            loss = loss_fn(batch)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if grad_clip is not None:
                nn.utils.clip_grad_norm_(net.parameters(), float(grad_clip))
            opt.step()
            total += float(loss.detach()) * len(batch)
            count += len(batch)
        if scheduler is not None:
            scheduler.step()
        train_loss = total / max(count, 1) + loss_offset
        if stop_on_nonfinite and not math.isfinite(train_loss):
            break
        if validate is None:
            metrics: Mapping[str, float] = {"val_loss": train_loss}
        else:
            v = validate()
            metrics = v if isinstance(v, Mapping) else {"val_loss": v}
        row = {"epoch": epoch, "train_loss": train_loss, **metrics, "seconds": time.perf_counter() - t0}
        history.append(row)
        key = tuple(row[m] for m in monitor) if validate is not None else (train_loss,)
        if _improves(key, best_key, min_delta):
            best, best_key, best_epoch = row, key, epoch
            best_state = copy.deepcopy(net.state_dict())
        if progress is not None:
            progress(epoch, int(max_epochs), train_loss)
        if validate is not None and epoch >= int(min_epochs) and epoch - best_epoch >= int(patience):
            break
        if max_seconds is not None and time.perf_counter() - t0 > float(max_seconds):
            break
    if best_state is not None:
        net.load_state_dict(best_state)
    net.eval()
    return {"epochs": epoch, "best_epoch": best_epoch,
            "train_loss": float(best["train_loss"]) if best else math.inf,
            "val_loss": float(best["val_loss"]) if best else math.inf,
            "last_train_loss": float(train_loss), "seconds": time.perf_counter() - t0, "history": history,
            "best": best}


def fit_early_stopping_stacked(params: Mapping[str, torch.Tensor], loss_fn: Callable[[B, torch.Tensor], torch.Tensor],
                               batches: Callable[[], Iterable[B]], validate: Callable[[torch.Tensor], np.ndarray], *,
                               max_epochs: int, patience: int, min_epochs: int = 1, lr: float = 1e-3,
                               weight_decay: float = 0.0, grad_clip: float | None = None, loss_offset: float = 0.0,
                               max_seconds: float | None = None,
                               progress: Callable[[int, int, float], None] | None = None,
                               on_epoch_end: Callable[[int], None] | None = None,
                               t0: float | None = None) -> dict[str, Any]:
    """:func:`fit_early_stopping` for ``E`` independent models trained together (e.g. a deep ensemble
    vmapped with ``torch.func.functional_call``), each with its own validation score, best epoch and
    patience.

    Every epoch: for each batch of ``batches()``: ``losses = loss_fn(batch, active)`` (shape
    ``(len(active),)``: the mean loss of each still-training model ``active[j]`` on its own part of
    the batch), backpropagate ``losses.sum()`` (a model's gradient is its own loss's, as the models
    share no parameter), clip each model's gradient to 2-norm ``grad_clip`` (as
    ``nn.utils.clip_grad_norm_`` per model), one Adam step (Kingma & Ba 2015; elementwise, so identical
    to one Adam per model). Then ``validate(active)`` returns their validation losses; a model's
    weights are copied when its loss improves on its best. A model that has gone ``patience`` epochs
    without improvement (once ``epoch >= min_epochs``) leaves ``active`` and costs nothing from then
    on (its rows may still drift under Adam's momentum and weight decay; they are overwritten by its
    best weights at the end), so every model trains exactly the epochs it would alone. Training stops
    when no model is active, after ``max_epochs``, after ``max_seconds`` since ``t0``, or at a
    non-finite training loss of any model. Each model's best weights are written back into ``params``
    (in place).

    Args:
        params: stacked leaf tensors ``name -> (E, ...)`` with ``requires_grad`` (e.g. from
            ``torch.func.stack_module_state``); optimised in place.
        loss_fn: ``(batch, active) -> (len(active),)`` losses with gradient; ``active`` is a sorted
            ``LongTensor`` of model indices.
        batches: returns one epoch's batches (``len(batch)`` = samples per model in it), for all ``E``
            models (so the batch order does not depend on which models are still active).
        validate: ``active -> (len(active),)`` validation losses of the current weights (no gradient
            needed).
        max_epochs, patience, min_epochs, lr, weight_decay, grad_clip, loss_offset, max_seconds,
        progress, t0: as :func:`fit_early_stopping` (``progress`` gets the mean training loss over
            the models).
        on_epoch_end: ``on_epoch_end(epoch)`` after every validated epoch (e.g. to freeze part of the
            models from then on).

    Returns:
        ``{"epochs", "member_epochs" (E,), "best_epoch" (E,), "train_loss" (E,), "val_loss" (E,),
        "last_train_loss" (E,), "seconds", "history"}``: epochs run; per model the epochs it trained, the
        best epoch (0 when none improved), training
        and validation loss there, and the last epoch's training loss (lists of floats); the
        per-epoch rows ``{"epoch", "train_loss", "val_loss", "seconds"}`` (lists per model).
    """
    t0 = time.perf_counter() if t0 is None else t0
    leaves = list(params.values())
    E = int(leaves[0].shape[0])
    opt = _adam(leaves, lr, weight_decay)
    best_val = np.full(E, np.inf)
    best_train = np.full(E, np.inf)
    best_epoch = np.zeros(E, dtype=int)
    best_state = {k: v.detach().clone() for k, v in params.items()}
    history: list[dict[str, Any]] = []
    train = np.full(E, np.inf)
    epoch = 0
    active = torch.arange(E)
    member_epochs = np.zeros(E, dtype=int)
    for epoch in range(1, int(max_epochs) + 1):
        act = active.numpy()
        total = torch.zeros(len(act), dtype=torch.float64)
        count = 0
        for batch in batches():
            losses = loss_fn(batch, active)
            opt.zero_grad(set_to_none=True)
            losses.sum().backward()
            if grad_clip is not None:
                with torch.no_grad():
                    sq = sum(p.grad.reshape(E, -1).pow(2).sum(1) for p in leaves if p.grad is not None)
                    coef = (float(grad_clip) / (sq.sqrt() + 1e-6)).clamp(max=1.0)
                    for p in leaves:
                        if p.grad is not None:
                            p.grad.mul_(coef.view((E,) + (1,) * (p.dim() - 1)))
            opt.step()
            total += losses.detach().double() * len(batch)
            count += len(batch)
        train[act] = total.numpy() / max(count, 1) + loss_offset
        member_epochs[act] = epoch
        if not np.isfinite(train[act]).all():
            break
        val = np.full(E, np.nan)
        val[act] = np.asarray(validate(active), dtype=float)
        history.append({"epoch": epoch, "train_loss": train.tolist(), "val_loss": val.tolist(),
                        "seconds": time.perf_counter() - t0})
        better = np.zeros(E, dtype=bool)
        better[act] = val[act] < best_val[act]
        if better.any():
            sel = torch.as_tensor(better)
            with torch.no_grad():
                for k, v in params.items():
                    best_state[k][sel] = v.detach()[sel]
            best_val[better], best_train[better], best_epoch[better] = val[better], train[better], epoch
        if progress is not None:
            progress(epoch, int(max_epochs), float(train[act].mean()))
        if on_epoch_end is not None:
            on_epoch_end(epoch)
        if epoch >= int(min_epochs):
            active = torch.as_tensor(np.nonzero(epoch - best_epoch < int(patience))[0])
            if len(active) == 0:
                break
        if max_seconds is not None and time.perf_counter() - t0 > float(max_seconds):
            break
    with torch.no_grad():
        for k, v in params.items():
            v.copy_(best_state[k])
    return {"epochs": epoch, "member_epochs": member_epochs.tolist(), "best_epoch": best_epoch.tolist(),
            "train_loss": best_train.tolist(),
            "val_loss": best_val.tolist(), "last_train_loss": np.asarray(train, float).tolist(),
            "seconds": time.perf_counter() - t0, "history": history}


def predict_batched(fn: Callable[..., T], *arrays: Any, batch_size: int, module: nn.Module | None = None
                    ) -> list[T]:
    """``[fn(a[i:i + batch_size], b[i:i + batch_size], ...) for i in 0, batch_size, ...]`` without gradients.

    Args:
        fn: called on aligned slices of ``arrays`` (NumPy arrays or tensors with the same length).
        arrays: the inputs, sliced along their first axis.
        batch_size: slice length (the last slice may be shorter).
        module: put into eval mode first (``module.eval()``), e.g. the network ``fn`` calls.

    Returns:
        The per-slice outputs, in order (concatenate or sum them as needed); empty for empty inputs.

    Raises:
        ValueError: no arrays, arrays of different lengths, or ``batch_size < 1``.
    """
    if not arrays or len({len(a) for a in arrays}) != 1:
        raise ValueError(f"predict_batched needs one or more arrays of the same length, got lengths "
                         f"{[len(a) for a in arrays]}")
    if int(batch_size) < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if module is not None:
        module.eval()
    bs, n = int(batch_size), len(arrays[0])
    with torch.no_grad():
        return [fn(*(a[i:i + bs] for a in arrays)) for i in range(0, n, bs)]
