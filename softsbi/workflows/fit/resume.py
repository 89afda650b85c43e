"""Opening a fit's run to resume it: the stored settings and their check, damaged simulations and groups computed
again, failed simulations retried (``--retry-failed``), what the resumed run holds, and its wall time over all its
sessions.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from softsbi.core.errors import SchemaError
from softsbi.core.store import RunStore
from softsbi.core.types import STATUS_OK, STATUS_PENDING, ParamSpace, Recording
from softsbi.perception.masks import hsv_mask
from softsbi.workflows.fit.config import RESUME_DEFAULTS, FitConfig, needs_images, resume_identity
from softsbi.workflows.fit.observe import metric_sensor, observe_recording, observer_options
from softsbi.workflows.reporting import FitCallbacks


def stored_config(cfg: FitConfig, meas: Recording, inferred: ParamSpace) -> dict[str, Any]:
    """What the run store keeps: the settings (also whole, as ``fit_config``) and what comes from
    the recording (scenario, inferred parameter space, source, truth, observer options, metric)."""
    d = cfg.to_json()
    d["fit_config"] = cfg.to_json()
    d.update({"scenario": meas.scenario.to_json(), "param_space": inferred.to_json(),
              "observed_source": meas.source, "truth": meas.truth,
              "observer_options": observer_options(cfg, meas.scenario),
              "metric": "mask_chamfer_px" if (needs_images(cfg) and meas.images is not None) else "chamfer_m",
              **metric_sensor(cfg, meas.scenario)})
    d.pop("n_points", None)
    return d


def open_store(out_dir: Path, recording: Recording, cfg: FitConfig, space: ParamSpace,
               callbacks: FitCallbacks) -> tuple[RunStore, float]:
    """Open the run store to resume it (checking the settings) or create it with the observed
    state; returns the store and the wall time already spent in it (s)."""
    config = stored_config(cfg, recording, space)
    store_path = out_dir / "run.zarr"
    if RunStore.exists(store_path):
        store = RunStore.open(store_path)
        store.check_resumable(config, FitConfig.resume_keys(), RESUME_DEFAULTS, resume_identity)
        prev = store.config.get("wall_time_s", 0.0) or 0.0
        callbacks.message(resume_message(store, prev))
        store.update_config(rounds=cfg.rounds)
        return store, prev
    x0 = observe_recording(cfg, recording)  # before creating the store: bad input leaves nothing behind
    store = RunStore.create(store_path, config)
    masks = hsv_mask(recording.images) if config["metric"] == "mask_chamfer_px" else None
    store.write_observed(x0, recording.scenario.gripper, recording.scenario.times, recording.dense,
                         recording.source, images=recording.images, masks=masks)
    store.update_config(rounds=cfg.rounds)
    return store, 0.0


def repair_damaged(store: RunStore, callbacks: FitCallbacks) -> None:
    """Stored simulations whose chunks are missing or unreadable are named and simulated again
    from their stored parameters and seeds, never dropped or trained on; the rounds after the
    first damaged one are drawn again from its new posterior. Other groups with an unreadable array are
    computed again (a round's posterior, the evaluation, a calibration), or named when they cannot be
    (the observed data, a round's draws: :class:`SchemaError`)."""
    for name, why in store.damaged_groups().items():
        parts = name.split("/")
        if name == "observed" or (parts[0] == "rounds" and len(parts) == 2):
            raise SchemaError(f"'{store.path / name}' cannot be trusted ({why}); fit into a new --out folder")
        callbacks.message(f"'{store.path / name}' cannot be trusted ({why}); computing it again")
        if parts[0] != "rounds":
            store.remove_group(name)
        elif store.is_complete(int(parts[1])):  # (not when an earlier round's redo removed it)
            store.redo(int(parts[1]), [])  # retrain the round; the rounds after it are drawn again
    found = store.damaged()
    if found is None:
        return
    r, bad = found  # the earliest damaged round: the rounds after it are drawn again anyway
    rows = sorted(bad)
    reasons = sorted(set(bad.values()))
    dropped = store.redo(r, rows)
    callbacks.message(f"round {r + 1}: {len(rows)} stored simulations of {store.path} cannot be trusted "
                      f"(simulations {rows[:10]}{' ...' if len(rows) > 10 else ''}: {'; '.join(reasons)}); "
                      f"simulating them again from their stored seeds"
                      + (f", and drawing the {dropped} simulations of later rounds again" if dropped else ""))


def retry_failed_simulations(store: RunStore, callbacks: FitCallbacks) -> None:
    """Make the stored failed simulations pending again (``fit --retry-failed``)."""
    redo = store.reset_failures()
    if redo is None:
        callbacks.message("no stored failed simulations to retry")
        return
    r, n_failed, n_dropped = redo
    callbacks.message(f"retrying {n_failed} failed simulations of round {r + 1}"
                      + (f"; the {n_dropped} simulations of later rounds were drawn from the old posterior of "
                         f"round {r + 1} and are drawn again" if n_dropped else ""))


def resume_message(store: RunStore, spent_s: float) -> str:
    """What a resumed fit finds: complete rounds, the partly stored round, stored failed simulations (and the
    option that simulates them again), the time already spent."""
    done = store.completed_rounds()
    parts = [f"resuming run in {store.path} after round {len(done)}" if done else f"resuming run in {store.path}"]
    nxt = len(done)
    if store.is_begun(nxt):
        n = int(len(store.round_data(nxt)["status"]))
        stored = n - len(store.pending(nxt))
        parts.append(f"round {nxt + 1}: {stored} of {n} simulations already stored")
    failed = sum(int(np.sum((st != STATUS_OK) & (st != STATUS_PENDING)))
                 for st in (store.round_data(r, ("status",))["status"] for r in store.round_ids()))
    if failed:
        parts.append(f"{failed} stored simulations failed (after fixing what made them fail, --retry-failed "
                     f"simulates them again)")
    parts.append(f"{spent_s:.0f} s spent before")
    return "; ".join(parts)


class RunClock:
    """Wall time of a run over all its sessions (s), saved to the store's config as ``wall_time_s``
    at least every ``every`` seconds while simulating, so a killed session's time is not lost."""

    def __init__(self, store: RunStore, before: float, every: float = 15.0):
        self.store, self.before, self.every = store, before, every
        self.t0 = time.perf_counter()
        self.saved_at = self.t0

    def spent(self) -> float:
        """The run's wall time so far (s): the earlier sessions' and this one's."""
        return self.before + time.perf_counter() - self.t0

    def save(self, force: bool = False) -> float:
        """Store :meth:`spent` as the run's ``wall_time_s`` when ``every`` seconds passed since the last save (or
        ``force``); returns it."""
        now = time.perf_counter()
        if force or now - self.saved_at >= self.every:
            self.saved_at = now
            self.store.update_config(wall_time_s=self.spent())
        return self.spent()
