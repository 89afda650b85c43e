"""Stored tasks: what a task has learned from its prior, trained once and reused by every later recording of it.

A fit's first round draws its parameters from the prior, and neither those draws, their simulations (the
simulation bank keeps them) nor the estimator trained on them depend on the recording: only conditioning the
trained estimator on the recording's observation does (BayesSim's amortisation, Ramos et al. 2019). A *task* is
everything that determines that first round: the scenario, the backend and its options (but the speed knobs,
:data:`~softsbi.workflows.fit.config.SPEED_OPTIONS`), the model (the effects
switched on), what the fit sees (observer and its options, sensor model, frames), the priors (the inferred
parameters' bounds and scales, the fixed values), the estimator and its options, the seed, and the softsbi version
(:func:`task_identity`). Its SHA-256 is the task's key (:func:`task_digest`).

A :class:`TaskStore` (a folder ``tasks/`` inside the simulation bank, whose rollouts the tasks' prior rounds are)
keeps, per key, the trained estimator's state, its training information, how many prior simulations trained it
and, when ``softsbi task train`` trained it, a training report: simulation-based calibration of the amortised
posterior on held-out prior simulations of the task (expected coverage, SBC ranks, TARP, contraction per
parameter; :func:`~softsbi.workflows.tasks.calibrate.calibration_stats`).

A fit of a task whose key is stored takes its first round from the stored task: the same prior draws and seeds
(their rollouts read from the bank), the stored estimator conditioned on the new recording, no training. Its later
rounds sharpen that posterior as usual. A fit of a task that is not stored stores its first round's estimator, so
the second recording of a task never trains its first round again; ``task train`` trains one on a larger prior
simulation budget with its training report, for the model and each candidate effect. A stored task whose key does
not match is never used: a changed softsbi version, scenario, backend, model, prior or estimator gives another key.

Entries are written into a temporary folder and renamed into place (atomic on one file system); each carries its
identity and a SHA-256 of its content (:mod:`~softsbi.core.store.posterior`), both checked on reading. A moved
entry (another key) counts as absent. A damaged entry (:class:`DamagedTask`) is never used: ``task list`` and
``task show`` name it, ``task delete`` removes it, and a fit trains its first round itself, saying so, and replaces
the entry only when no training report was stored in it (:meth:`PriorRound.damage_line`).
"""
from __future__ import annotations

import contextlib
import contextvars
import hashlib
import json
import os
import shutil
import tempfile
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import zarr
from filelock import FileLock, Timeout

from softsbi.core.errors import PosteriorDamaged, SoftsbiError, storage_error
from softsbi.core.results.fitreport import TrainingReport
from softsbi.core.store import installed_version
from softsbi.core.store.posterior import EstimatorState, encode_posterior, read_posterior_group, write_posterior
from softsbi.core.types import ParamSpace, Recording, jsonable
from softsbi.plugins import registry
from softsbi.core import defaults
from softsbi.workflows.fit.bank import _engine_version, bank_folder
from softsbi.workflows.fit.config import FitConfig, estimator_options, needs_images, resume_identity
from softsbi.workflows.fit.jobs import SimContext
from softsbi.workflows.fit.observe import metric_sensor, observer_options

#: format of a stored task (part of its key: a new format trains every task again)
TASK_FORMAT = "softsbi.task/1"
#: the stored tasks' folder inside a simulation bank
TASKS_FOLDER = "tasks"
#: the entry of a stored task's ``info`` that marks a task ``softsbi task train`` trained (a fit's first round
#: stores none): with ``--n-test 0`` it has no training report, and is still no fit's
TASK_TRAIN_INFO = "task_train"


def task_identity(cfg: FitConfig, space: ParamSpace, ctx: SimContext, estimator_options: Mapping[str, Any]) -> dict:
    """Everything that determines a fit's first round (module docstring), as JSON: the key's content.

    Args:
        cfg: the fit's settings, :meth:`~softsbi.workflows.fit.config.FitConfig.resolved` (frames as indices).
        space: the inferred parameters (names, prior bounds, log scale) of the fit's first round.
        ctx: the fit's simulation context (scenario, observer options and sensor model as the jobs apply them).
        estimator_options: the estimator's configuration: its defaults (``defaults()``, where it has them) updated
            by the options the fit gives it (:func:`~softsbi.workflows.fit.config.estimator_options`), so that a
            changed default of the estimator keys its tasks anew.
    """
    return jsonable({
        "format": TASK_FORMAT, "softsbi": installed_version(),
        "backend": cfg.backend, "backend_options": resume_identity("backend_options", dict(cfg.backend_options)),
        "engine": _engine_version(cfg.backend),
        "scenario": resume_identity("scenario", ctx.scenario), "effects": list(cfg.effects),
        "observer": cfg.observer, "observer_options": dict(ctx.observer_options),
        "frames": None if cfg.frames is None else [int(i) for i in cfg.frames],
        "metric_min_z": ctx.min_z, "metric_camera": ctx.camera,
        "parameters": space.to_json(), "fixed": dict(cfg.fixed),
        "estimator": cfg.estimator, "estimator_options": dict(estimator_options),
        "seed": int(cfg.seed), "sensor_draws": int(cfg.sensor_draws)})


def first_round_context(cfg: FitConfig, recording: Recording, space: ParamSpace) -> SimContext:
    """The simulation context of a fit's first round as far as the task goes: the simulator, the scenario, the
    observer and the sensor model, without a measurement to score against (``dense`` None)."""
    sensor = metric_sensor(cfg, recording.scenario)
    return SimContext(backend=cfg.backend, backend_options=cfg.backend_options, scenario=recording.scenario.to_json(),
                      effects=list(cfg.effects), observer=cfg.observer,
                      observer_options=observer_options(cfg, recording.scenario), param_names=space.names,
                      fixed=dict(cfg.fixed), dense=None, n_dense=cfg.n_dense, min_z=sensor["metric_min_z"],
                      camera=sensor["metric_camera"])


def task_digest(identity: Mapping[str, Any]) -> str:
    """The task's key: the SHA-256 (hex) of its identity's canonical JSON."""
    return hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()


#: the entries :func:`read_once` keeps, by (store folder, key); None outside it
_READ_ONCE: contextvars.ContextVar[dict[tuple[str, str], Any] | None] = contextvars.ContextVar("read_once",
                                                                                              default=None)


@contextlib.contextmanager
def read_once() -> Iterator[None]:
    """Inside the block, each stored task is read from the disk once (:meth:`TaskStore.entry`): a command that
    reaches one task through several steps (``diagnose``: the candidates' amortised posteriors, their refits, the
    checks' calibration) reads its metadata and estimator state once. Nested blocks share the outermost's entries."""
    if _READ_ONCE.get() is not None:
        yield
        return
    token = _READ_ONCE.set({})
    try:
        yield
    finally:
        _READ_ONCE.reset(token)


def task_store_of(sim_bank: str = defaults.SIM_BANK) -> "TaskStore | None":
    """The task store of a fit's ``--sim-bank`` setting (``"default"``: the user's bank, ``"off"``: none; else a
    folder): ``BANK/tasks``; None when the bank is off (a stored task's prior round is read from the bank)."""
    bank = bank_folder(sim_bank)
    return None if bank is None else TaskStore(bank / TASKS_FOLDER)


def model_name(identity: Mapping[str, Any]) -> str:
    """The name of a task's model (:func:`task_identity`): ``nominal`` or ``nominal+<effect>...`` (the effects
    switched on)."""
    return "+".join(["nominal", *identity["effects"]])


@dataclass(frozen=True)
class StoredTask:
    """One stored task.

    Attributes:
        digest: its key (:func:`task_digest` of ``identity``).
        identity: what determines it (:func:`task_identity`).
        n_prior: the prior draws of its first round (the fit's round-1 draws ``[seed, 0, 0]``, seeds
            ``[seed, 0, 1]``); the estimator was trained on the usable ones.
        estimator: the trained estimator's state (restore: the plugin ``estimator.name`` with its options).
        info: the training information (:meth:`~softsbi.core.interfaces.PosteriorEstimator.fit`'s, with counts).
        report: the training report (``task train``: calibration on held-out prior simulations,
            :class:`~softsbi.core.results.fitreport.TrainingReport`), or None (stored by a fit's first round, or trained
            by ``task train --n-test 0``: :attr:`by_task_train`).
        path: its folder.
    """

    digest: str
    identity: dict[str, Any]
    n_prior: int
    estimator: EstimatorState
    info: dict[str, Any]
    report: TrainingReport | None
    path: Path

    @property
    def model(self) -> str:
        """The model's name: ``nominal`` or ``nominal+<effect>...`` (the effects switched on)."""
        return model_name(self.identity)

    @property
    def by_task_train(self) -> bool:
        """Whether ``softsbi task train`` trained it (with its training report, or without one: ``--n-test 0``),
        not a fit's first round."""
        return self.report is not None or bool(self.info.get(TASK_TRAIN_INFO))

    def restore(self) -> Any:
        """The trained estimator, restored through the plugin registry (not yet conditioned on any observation).

        Raises:
            PluginNotFound: the estimator that trained it is not installed."""
        est = registry().estimator(self.estimator.name)(**self.estimator.options)
        est.load_state_dict(self.estimator.state)
        return est


@dataclass(frozen=True)
class DamagedTask:
    """A stored task that cannot be read: never used, named by ``task list`` and ``task show``, removed by
    ``task delete``.

    Attributes:
        digest: its key (its folder's name). path: its folder. problem: what cannot be read.
        trained: whether it may hold a training report (``task train``'s; True when its attributes cannot be read,
            so that a fit never replaces it unasked).
        identity: what determines it (:func:`task_identity`) when that can still be read, else None.
    """

    digest: str
    path: Path
    problem: str
    trained: bool = True
    identity: dict[str, Any] | None = None

    @property
    def model(self) -> str:
        """The model's name (:attr:`StoredTask.model`), ``"?"`` when its identity cannot be read."""
        return "?" if self.identity is None else model_name(self.identity)


class TaskStore:
    """Stored tasks by key in a folder (created on the first store): ``<path>/<digest>/task.zarr``."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def _where(self, digest: str) -> Path:
        return self.path / digest

    def get(self, digest: str) -> StoredTask | None:
        """The stored task of ``digest``; None when absent, damaged (:meth:`entry`), of another format, or stored
        under another key (a folder moved or copied)."""
        found = self.entry(digest)
        return found if isinstance(found, StoredTask) else None

    def entry(self, digest: str) -> StoredTask | DamagedTask | None:
        """The entry of ``digest``: the stored task, a :class:`DamagedTask` (its metadata, estimator state (its
        checksum) or training report cannot be read, or its folder lacks ``task.zarr``), or None when absent, of
        another format or stored under another key (a folder moved or copied). Inside :func:`read_once`, each
        entry is read from the disk once (:meth:`put` and :meth:`delete` of this process read it again)."""
        cache = _READ_ONCE.get()
        if cache is None:
            return self._read(digest)
        key = (str(self.path.resolve()), digest)
        if key not in cache:
            cache[key] = self._read(digest)
        return cache[key]

    def _forget(self, digest: str) -> None:
        """Drop ``digest``'s entry from the :func:`read_once` cache (it was stored or deleted here)."""
        cache = _READ_ONCE.get()
        if cache is not None:
            cache.pop((str(self.path.resolve()), digest), None)

    def _read(self, digest: str) -> StoredTask | DamagedTask | None:
        """:meth:`entry` read from the disk: its metadata, its estimator state (checksummed) and its report."""
        where = self._where(digest)
        if not where.is_dir():
            return None
        if not (where / "task.zarr").is_dir():
            return DamagedTask(digest, where, "its task.zarr is missing")
        try:
            g = zarr.open_group(str(where / "task.zarr"), mode="r")
            attrs = dict(g.attrs)
            identity = attrs["identity"]
        except Exception as exc:  # noqa: BLE001 - unreadable metadata: its training report may be in it
            return DamagedTask(digest, where, f"its metadata cannot be read ({type(exc).__name__})")
        if attrs.get("format") != TASK_FORMAT or not isinstance(identity, dict) or task_digest(identity) != digest:
            return None  # an entry of another format (which may lack the attribute), or stored under another key
        # an entry of this format holds every attribute :meth:`put` writes (in one update); its identity is the
        # mapping it was put with (:func:`task_identity`'s for a fit's), which may lack the softsbi version
        trained = "report" in attrs and attrs["report"] is not None  # an entry missing it is damaged below
        try:
            stored_report = attrs["report"]
            state = read_posterior_group(lambda: g["estimator"], "its estimator", "train it again",
                                         str(identity.get("softsbi")))
            if not isinstance(state, EstimatorState):
                raise TypeError("its estimator state is not an estimator's")
            report = None if stored_report is None else TrainingReport.from_json(stored_report)
            return StoredTask(digest, identity, int(attrs["n_prior"]), state, dict(attrs["info"]), report, where)
        except PosteriorDamaged as exc:
            return DamagedTask(digest, where, exc.problem, trained, identity)
        except Exception as exc:  # noqa: BLE001 - a schema, a report or a count that cannot be read
            return DamagedTask(digest, where, f"{type(exc).__name__}: {exc}", trained, identity)

    def check_writable(self) -> None:
        """Check, before any training, that a task can be stored here: its entries are written in ``tmp/`` first.

        Raises:
            StorageError: a full ("no space left on the device"), read-only or forbidden disk. SoftsbiError:
                ``tmp`` or a folder above it is a file. One line naming the file or folder and the fix.
        """
        tmp = self.path / "tmp"
        if tmp.exists() and not tmp.is_dir():
            raise SoftsbiError(f"'{tmp}' is a file where the task store writes its entries: move it away (or give "
                               f"--sim-bank another folder), then re-run the same command")
        try:
            tmp.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=tmp) as f:  # a few blocks, so that a full disk refuses now
                f.write(b"\0" * 65536)
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            raise storage_error(exc, self.path, out_flag="--sim-bank") or SoftsbiError(
                f"the task store {self.path} cannot be written ({exc.strerror or exc}): give --sim-bank a folder you "
                f"can write") from None

    @contextlib.contextmanager
    def lock(self, digest: str, waiting: Callable[[], None] | None = None) -> Iterator[None]:
        """Hold the lock of task ``digest`` (``tmp/<digest>.lock``, released when the process ends, even killed)
        for the ``with`` block, so that one process trains it; ``waiting`` is called before waiting for another
        holder."""
        path = self.path / "tmp" / f"{digest}.lock"
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = FileLock(str(path))
        try:
            lock.acquire(timeout=0)
        except Timeout:
            if waiting is not None:
                waiting()
            lock.acquire()
        try:
            yield
        finally:
            lock.release()

    def put(self, identity: Mapping[str, Any], n_prior: int, estimator: EstimatorState, info: Mapping[str, Any],
            report: TrainingReport | None = None, strict: bool = False) -> StoredTask | None:
        """Store a trained task (replacing the entry of its key). Returns it, or None when the store cannot be
        written (a read-only or full disk: nothing is stored, nothing is lost); ``strict``: raise that
        ``OSError`` instead."""
        digest = task_digest(identity)
        self._forget(digest)
        arrays, attrs = encode_posterior(None, estimator, f"stored task {digest[:12]}")
        tmp = self.path / "tmp" / f"{digest}-{uuid.uuid4().hex}"
        where = self._where(digest)
        try:
            g = zarr.open_group(str(tmp / "task.zarr"), mode="w")
            write_posterior(g.require_group("estimator"), arrays, attrs)
            g.attrs.update(jsonable({"format": TASK_FORMAT, "identity": dict(identity), "n_prior": int(n_prior),
                                     "info": dict(info), "report": None if report is None else report.to_json()}))
            if where.exists():
                shutil.rmtree(where, ignore_errors=True)
            where.parent.mkdir(parents=True, exist_ok=True)
            tmp.rename(where)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
            if strict:
                raise
            return None
        return self.get(digest)

    def list(self) -> list[StoredTask]:
        """Every intact stored task (:meth:`entries` without the damaged ones)."""
        return [t for t in self.entries() if isinstance(t, StoredTask)]

    def entries(self) -> list[StoredTask | DamagedTask]:
        """Every stored task and every damaged entry (:meth:`entry`), by key."""
        if not self.path.is_dir():
            return []
        found = (self.entry(d.name) for d in sorted(self.path.iterdir()) if d.is_dir() and d.name != "tmp")
        return [t for t in found if t is not None]

    def find(self, prefix: str) -> StoredTask | DamagedTask:
        """The stored task or damaged entry whose key starts with ``prefix`` (at least 4 characters).

        Raises:
            SoftsbiError: no task or several tasks match (the line lists them)."""
        prefix = prefix.strip().lower()
        if len(prefix) < 4:
            raise SoftsbiError(f"task key '{prefix}' is too short: give at least its first 4 characters "
                               f"(`softsbi task list` shows them)")
        hits = [t for t in self.entries() if t.digest.startswith(prefix)]
        if len(hits) != 1:
            what = ("no stored task" if not hits else
                    f"{len(hits)} stored tasks ({', '.join(t.digest[:12] for t in hits)})")
            raise SoftsbiError(f"{what} in {self.path} match key '{prefix}'; `softsbi task list` shows the stored ones")
        return hits[0]

    def delete(self, prefix: str) -> StoredTask | DamagedTask:
        """Delete the stored task or damaged entry whose key starts with ``prefix`` (:meth:`find`); returns what was
        deleted."""
        task = self.find(prefix)
        shutil.rmtree(task.path)
        self._forget(task.digest)
        return task


class PriorRound:
    """A fit's first round as a stored task: the task it uses (``task``, None when none is stored under its key)
    and the store where it keeps the one it trains.

    Args:
        store: the task store (None: no stored tasks, e.g. ``--no-sim-bank``).
        identity: the fit's first round's :func:`task_identity` (None: the fit cannot use stored tasks).
    """

    def __init__(self, store: TaskStore | None, identity: dict[str, Any] | None):
        self.store, self.identity = store, identity
        self.digest = None if identity is None else task_digest(identity)
        found = None if store is None or self.digest is None else store.entry(self.digest)
        self.task = found if isinstance(found, StoredTask) else None
        #: the damaged entry stored under this key (never used), or None
        self.damaged = found if isinstance(found, DamagedTask) else None

    def damage_line(self) -> str | None:
        """What a fit does about a damaged entry under its key, in one line (None when there is none): it trains
        its first round itself; it replaces the entry unless a training report may be in it."""
        d = self.damaged
        if d is None:
            return None
        head = f"stored task {d.digest[:12]} ({d.model}) in {d.path.parent} is damaged ({d.problem})"
        if not d.trained:
            return f"{head}: this fit trains its first round itself and stores it in its place"
        return (f"{head}: this fit trains its first round itself and leaves the entry, which holds a training "
                f"report; `softsbi task delete {d.digest[:12]}` removes it and `softsbi task train` trains it again")

    @classmethod
    def of(cls, cfg: FitConfig, recording: Recording, space: ParamSpace) -> "PriorRound":
        """The first round of a fit of ``recording`` (``cfg`` resolved, ``space`` the first round's parameters):
        none with ``--sensor-draws`` (its extra observations are drawn per round), a ``start_box`` (its draws are not
        the prior's), an image observer (its fits are per recording) or without a simulation bank.

        Raises:
            PluginNotFound: the estimator or an effect of ``cfg`` is not installed."""
        store = task_store_of(cfg.sim_bank)
        if store is None or cfg.sensor_draws or cfg.start_box or needs_images(cfg):
            return cls(None, None)
        est_cls = registry().estimator(cfg.estimator)
        # the estimator's whole configuration: a changed default of the estimator trains its tasks again
        opts = {**(est_cls.defaults() if hasattr(est_cls, "defaults") else {}), **estimator_options(cfg, est_cls)}
        return cls(store, task_identity(cfg, space, first_round_context(cfg, recording, space), opts))

    def usable(self, n_drawn: int) -> bool:
        """Whether the stored task serves a first round of ``n_drawn`` prior draws: it was trained on at least as
        many (the first ``n_drawn`` of its draws are the round's)."""
        return self.task is not None and self.task.n_prior >= n_drawn

    def trained(self, n_drawn: int) -> bool:
        """Whether the stored task serves a first round of ``n_drawn`` draws (:meth:`usable`) and was trained by
        ``task train`` with its training report: its posterior was measured on held-out simulations, so a fit may
        stop at it (a task stored by a fit's first round only starts the fit's sequential rounds)."""
        return self.usable(n_drawn) and self.task is not None and self.task.report is not None

    def keep(self, n_prior: int, est: Any, info: Mapping[str, Any], options: Mapping[str, Any],
             name: str) -> StoredTask | None:
        """Store the first round's trained estimator ``est`` (plugin ``name`` with ``options``) as the task when
        none is stored under its key; None when nothing was stored (a task was already there, no store, or an
        estimator without a state, or a damaged entry that may hold a training report: :meth:`damage_line`)."""
        if self.store is None or self.identity is None or self.task is not None or \
                (self.damaged is not None and self.damaged.trained):
            return None
        try:
            state = EstimatorState(name, dict(options), est.state_dict())
        except NotImplementedError:
            return None
        self.task = self.store.put(self.identity, n_prior, state, info)
        return self.task


def served_by_task(info: Mapping[str, Any]) -> bool:
    """Whether a fit's first round was a stored task's posterior (``info``: the round's stored training info)."""
    return info.get("trained_here") is False and bool(info.get("task"))
