"""Opening a fit's run to resume it: the stored settings and their check, damaged simulations and groups computed
again, failed simulations retried (``--retry-failed``), what the resumed run holds, and its wall time over all its
sessions.
"""
from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from softsbi.core.errors import ObservedDamaged, SchemaError, SoftsbiError, SoftsbiWarning
from softsbi.core.store import RunStore
from softsbi.core.store.damage import array_names, damage_fix, observed_faults
from softsbi.core.types import STATUS_OK, STATUS_PENDING, ParamSpace, Recording, Scenario
from softsbi.perception.masks import hsv_mask
from softsbi.workflows.fit.config import RESUME_DEFAULTS, FitConfig, RunRecord, needs_images, resume_identity
from softsbi.workflows.fit.observe import metric_sensor, observe_recording, observer_options
from softsbi.workflows.measurement import load_recording
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
    state (rebuilt from ``recording`` when the stored one is damaged); returns the store and the wall time already
    spent in it (s).

    Raises:
        SchemaError: the run has other settings, or its damaged observed state differs from ``recording``'s."""
    config = stored_config(cfg, recording, space)
    store_path = out_dir / "run.zarr"
    if RunStore.exists(store_path):
        store = RunStore.open(store_path)
        store.check_resumable(config, FitConfig.resume_keys(), RESUME_DEFAULTS, resume_identity)
        prev = RunRecord.from_run_config(store.config).wall_time_s
        callbacks.message(resume_message(store, prev))
        try:
            store.read_observed()
        except ObservedDamaged as exc:  # the recording this fit is given rebuilds it
            rebuild_observed(store, recording, cfg)
            callbacks.message(f"{exc.problem}: rebuilt it from the recording '{recording.source}'")
        store.update_config(rounds=cfg.rounds)
        return store, prev
    observed = _observed(cfg, recording, config["metric"])  # before creating the store: bad input leaves nothing
    store = RunStore.create(store_path, config)
    store.write_observed(**observed)
    store.update_config(rounds=cfg.rounds)
    return store, 0.0


def _observed(cfg: FitConfig, recording: Recording, metric: str) -> dict[str, Any]:
    """:meth:`RunStore.write_observed`'s arguments: ``recording`` as the fit (``cfg``, resolved) observes it."""
    masks = hsv_mask(recording.images) if metric == "mask_chamfer_px" else None
    return {"x": observe_recording(cfg, recording), "gripper": recording.scenario.gripper,
            "times": recording.scenario.times, "dense": recording.dense, "source": recording.source,
            "images": recording.images, "masks": masks}


def rebuild_observed(store: RunStore, recording: Recording, cfg: FitConfig) -> dict[str, np.ndarray]:
    """Write the run's ``observed`` group again from the ``recording`` it was fitted to (``cfg``: the fit's
    settings, resolved); returns the observed arrays. The arrays of the damaged group that can still be read must
    equal the rebuilt ones.

    Raises:
        SchemaError: the recording no longer gives what the fit observed (it changed since the fit).
        OSError: the run store cannot be written (the arrays are not returned then).
    """
    new = _observed(cfg, recording, RunRecord.from_run_config(store.config).metric)
    group = store.root["observed"] if "observed" in store.root else None
    wrong = observed_faults(store.root)  # the arrays of the wrong shape: rebuilt
    for k in () if group is None else [k for k in array_names(group) if k not in wrong]:
        try:
            old = group[k][...]
        except Exception:  # noqa: BLE001 - the damaged array: rebuilt
            continue
        if new.get(k) is None or np.shape(old) != np.shape(new[k]) or not np.allclose(old, new[k], equal_nan=True):
            raise SchemaError(f"'{store.path / 'observed'}' cannot be rebuilt: the recording '{recording.source}' no "
                              f"longer gives what the fit observed (its '{k}' differs); fit it into a new --out "
                              f"folder")
    store.remove_group("observed")
    store.write_observed(**new)
    return store.read_observed()


def observed_data(store: RunStore) -> dict[str, np.ndarray]:
    """A finished run's observed arrays (:meth:`RunStore.read_observed`). When they are damaged (a truncated or
    corrupt chunk, the group missing), they are rebuilt from the point-cloud recording named in the run's
    settings, said in one line (:class:`~softsbi.core.errors.SoftsbiWarning`); in a read-only run directory they
    are used without being stored.

    Raises:
        ObservedDamaged: damaged, and the recording cannot be read (moved, or an image fit's frames): the line
            names the ``softsbi fit`` command that rebuilds it.
        SchemaError: the recording no longer gives what the fit observed.
    """
    try:
        return store.read_observed()
    except ObservedDamaged as exc:
        damage = exc
    config = store.config
    rec = RunRecord.from_run_config(config)
    source = rec.observed_source
    run_dir = store.path.parent
    if rec.image_fit or not source or not Path(source).is_dir():
        raise ObservedDamaged(damage.problem, f"re-run the fit with its recording (`softsbi fit --observed "
                                              f"{source or 'REC'} ... --out {run_dir}`): it rebuilds it") from None
    cfg = FitConfig.from_run_config(config)
    try:
        rec = load_recording(source, n_points=cfg.n_points, seed=cfg.seed,
                             scenario=Scenario.from_json(rec.scenario))
    except SoftsbiError as exc:
        raise ObservedDamaged(damage.problem, f"its recording cannot be read to rebuild it ({exc})") from None
    cfg = cfg.resolved(rec)
    try:
        arrays = rebuild_observed(store, rec, cfg)
        done = "rebuilt it"
    except OSError as exc:  # a read-only run: used, not stored
        arrays = {k: v for k, v in _observed(cfg, rec, "chamfer_m").items() if isinstance(v, np.ndarray)}
        done = f"rebuilt it for this command (not stored: {exc.strerror or exc})"
    warnings.warn(SoftsbiWarning(f"{damage.problem}: {done} from the recording '{source}'"), stacklevel=2)
    return arrays


def repair_damaged(store: RunStore, callbacks: FitCallbacks) -> None:
    """Stored simulations whose chunks are missing or unreadable are named and simulated again
    from their stored parameters and seeds, never dropped or trained on; the rounds after the
    first damaged one are drawn again from its new posterior. Other groups with an unreadable array are
    computed again (a round's posterior, the evaluation, a calibration), or named when they cannot be
    (a round's draws: :class:`SchemaError`); the observed data are rebuilt by :func:`open_store`."""
    for name, why in store.damaged_groups().items():
        parts = name.split("/")
        if name == "observed":  # the recording the fit is given rebuilds it
            continue
        if parts[0] == "rounds" and len(parts) == 2:
            raise SchemaError(f"'{store.path / name}' cannot be trusted ({why}); {damage_fix(store.path, name)}")
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
