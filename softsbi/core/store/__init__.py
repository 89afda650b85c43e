"""The run store: one Zarr v3 group per fit (``RUN_DIR/run.zarr``).

Layout (schema ``softsbi.run``, version :data:`SCHEMA_VERSION`)::

    / attrs: schema, schema_version, softsbi_version, created, config (backend, scenario,
             param_space, effects, observer, estimator, rounds, sims_per_round, seed, ...)
    observed/   x (T, 1+K, 3) m, gripper (T, 3) m, times (T,) s, dense (T, P, 3) m
    rounds/<r>/ theta (N, D) physical units, u (N, D) unit cube, seed (N,),
                x (N, T, 1+K, 3) m, status (N,) uint8 (255 = pending), chamfer (N, T) m
                attrs: begun, complete, failures {i: reason}, train info
                posterior/   q(u | x_obs), format POSTERIOR_FORMAT, sha256 checksum of its content:
                    kind "mixture": weights (C,), means (C, D), scale_tril (C, D, D) (unit cube)
                    kind "estimator": the state of the estimator that gives it (any estimator):
                        attrs estimator (plugin name), options, state (the state dict with
                        every array replaced by {"$array": name}); state/<name> the arrays
    evaluation/ theta, u, status, chamfer  (rollouts at final-posterior samples)
    refine/     u, theta, seed, generation, status, chamfer  (``fit --refine``: CMA-ES rows, one per chunk)
    best_fit/   theta, u, chamfer, vertices, faces, gripper  (the fit's best simulation and its rollout)

A ``fit --widen`` run keeps its widenings in ``config["widenings"]`` and the widened prior in
``config["param_space"]``; every round's ``u`` is in that prior's unit cube
(:mod:`softsbi.workflows.fit.prior_widening`).

Every array carries ``units`` in its attributes and dimension names. Simulation results
are chunked one simulation per chunk and Zarr's local store writes each chunk atomically
(temporary file + rename), so a run killed at any point resumes with every finished
simulation kept; a round is marked ``complete`` only after its posterior is written.
A round's posterior is read back only when its checksum matches (:meth:`RunStore.read_posterior`):
a damaged or missing posterior is named in one line, never used.

Version 2 added the posterior's ``kind``, ``format`` and ``checksum``; version-1 runs (every
posterior a mixture, no checksum) are read as they are.

:class:`RunStore` is defined here; the package's modules hold its parts: a round's posterior group
(:mod:`softsbi.core.store.posterior`), the named groups outside the rounds (:mod:`softsbi.core.store.groups`) and
what in a store cannot be read (:mod:`softsbi.core.store.damage`).
"""
from __future__ import annotations

import datetime as _dt
import shutil
from dataclasses import dataclass, field, fields
from importlib.metadata import version as _installed_version
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import zarr

from softsbi.core.distributions import MixtureOfGaussians
from softsbi.core.errors import ObservedDamaged, SchemaError
# a round's posterior (EstimatorState and POSTERIOR_FORMAT are importable from here too)
from softsbi.core.store.posterior import (POSTERIOR_FORMAT, EstimatorState, encode_posterior,  # noqa: F401
                                          put_array, read_posterior_group, write_posterior)
from softsbi.core.store.damage import (array_names, check_metadata, damage_fix, damaged_rows, group_names,
                                       observed_faults, round_faults, unreadable_groups)
from softsbi.core.store.groups import NamedGroups
from softsbi.core.types import STATUS_PENDING, jsonable

SCHEMA = "softsbi.run"
SCHEMA_VERSION = 2
#: the schema versions this softsbi reads (version 1: no posterior kinds or checksums)
READABLE_VERSIONS = (1, 2)


#: the arrays every round holds (:meth:`RunStore.round_data`); a fit with sensor draws adds ``sensor_u``, ``sensor_x``
ROUND_ARRAYS = ("theta", "u", "seed", "x", "status", "chamfer")


@dataclass(frozen=True, kw_only=True)
class RoundRecord:
    """A round's stored attributes (:meth:`RunStore.round_record`); one a round lacks (a round begun but not finished,
    or stored by an older version) reads as its default.

    Attributes:
        proposal: what its parameters were drawn from (words). complete: whether its posterior is stored.
        failures: ``{row: reason}`` of its failed simulations. info: its training information (the estimator's, with
            the stored task that served it, if any). bank_hits: its simulations read from a simulation bank.
    """

    proposal: str = ""
    complete: bool = False
    failures: dict[str, str] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    bank_hits: int = 0

    @classmethod
    def of(cls, attrs: Mapping[str, Any]) -> "RoundRecord":
        """The record of a round group's attributes (other attributes are left out)."""
        return cls(**{f.name: attrs[f.name] for f in fields(cls) if f.name in attrs})

    @property
    def task(self) -> str | None:
        """The key (digest) of the stored task the round's estimator came from or was stored as (its training info's
        ``task``), or None: no stored task, or a round not finished."""
        task = self.info.get("task")
        return None if task is None else str(task)

    @property
    def n_train_total(self) -> int:
        """How many simulations (with sensor pairs) the round's estimator was trained on (its training info's
        ``n_train_total``); 0 where the info lacks it (a round not finished)."""
        return int(self.info.get("n_train_total") or 0)


def installed_version() -> str:
    """The installed softsbi's version (``"unknown"`` in a source tree that is not installed)."""
    try:
        return _installed_version("softsbi")
    except Exception:  # noqa: BLE001 - not installed (source tree)
        return "unknown"


class RunStore(NamedGroups):
    """Read/write access to a run's Zarr store.

    Use :meth:`create` for a new run and :meth:`open` for an existing one. The groups outside the rounds
    (``evaluation``, ``refine``, ``best_fit``, ...) are read and written through :class:`NamedGroups`' methods.

    Raises:
        SchemaError: the path is not a softsbi run, or has another schema version.
    """

    def __init__(self, path: Path, root: zarr.Group):
        self.path = Path(path)
        self.root = root

    @property
    def root(self) -> zarr.Group:
        """The store's root group; setting it (a reopened store) forgets the array handles opened through it."""
        return self._root

    @root.setter
    def root(self, group: zarr.Group) -> None:
        self._root = group
        self._arrays: dict[tuple[int, str], zarr.Array | None] = {}

    def _round_array(self, r: int, name: str) -> zarr.Array | None:
        """Round ``r``'s array ``name`` (None when the round has none), opened once per store: every open reads
        the round's and the array's metadata from disk, and :meth:`write_simulation` writes three arrays per
        simulation."""
        key = (r, name)
        if key not in self._arrays:
            g = self._round(r)
            self._arrays[key] = g[name] if name in g else None
        return self._arrays[key]

    # -- life cycle -----------------------------------------------------------------
    @classmethod
    def exists(cls, path: str | Path) -> bool:
        return (Path(path) / "zarr.json").exists()

    @classmethod
    def create(cls, path: str | Path, config: Mapping[str, Any]) -> "RunStore":
        """Create a new store at ``path`` (must not exist yet)."""
        path = Path(path)
        if cls.exists(path):
            raise SchemaError(f"a run store already exists at '{path}'; open it with RunStore.open or choose "
                              f"another --out")
        path.parent.mkdir(parents=True, exist_ok=True)
        root = zarr.open_group(str(path), mode="w")
        root.attrs.update({"schema": SCHEMA, "schema_version": SCHEMA_VERSION, "softsbi_version": installed_version(),
                           "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                           "config": jsonable(dict(config))})
        root.require_group("rounds")
        return cls(path, root)

    @classmethod
    def open(cls, path: str | Path, mode: str = "a") -> "RunStore":
        """Open an existing store, checking its schema and version."""
        path = Path(path)
        if not cls.exists(path):
            if path.name == "run.zarr" and not path.parent.exists():
                raise SchemaError(f"run directory '{path.parent}' does not exist; pass the --out folder of a "
                                  f"`softsbi fit`")
            if path.name == "run.zarr" and not path.exists():
                raise SchemaError(f"'{path.parent}' is not a run directory (it holds no run.zarr); pass the --out "
                                  f"folder of a `softsbi fit`")
            raise SchemaError(f"'{path}' is not a softsbi run store (no zarr.json); pass the run.zarr written "
                              f"by `softsbi fit`")
        try:
            root = zarr.open_group(str(path), mode=mode)
        except Exception as exc:  # noqa: BLE001
            raise SchemaError(f"'{path / 'zarr.json'}' cannot be read ({type(exc).__name__}): the run store is "
                              f"damaged; fit into a new --out folder") from None
        schema = root.attrs.get("schema")
        version = root.attrs.get("schema_version")
        if schema != SCHEMA:
            raise SchemaError(f"'{path}' is a Zarr store but not a softsbi run (schema={schema!r}); "
                              f"point at a run.zarr written by `softsbi fit`")
        if version not in READABLE_VERSIONS:
            raise SchemaError(f"run store '{path}' has schema version {version}, this softsbi reads versions "
                              f"{list(READABLE_VERSIONS)}; re-run the fit into a new --out folder with this version, or "
                              f"install the softsbi version that wrote it ({root.attrs.get('softsbi_version')})")
        check_metadata(path, root)
        return cls(path, root)

    @property
    def config(self) -> dict[str, Any]:
        return dict(self.root.attrs["config"])

    def check_resumable(self, config: Mapping[str, Any], keys: Sequence[str],
                        defaults: Mapping[str, Any] | None = None,
                        identity: Callable[[str, Any], Any] | None = None) -> None:
        """Raise :class:`SchemaError` if ``config`` differs from the stored one in one of ``keys``
        (the settings that would make the stored simulations invalid for this fit; the fit
        workflow derives them from its configuration). ``defaults`` are the values of keys that
        runs written before the key existed lack. ``identity(key, value)``, when given, is what is
        compared of each value (e.g. a scenario without the path of the file it was read from)."""
        stored = self.config
        new = jsonable(dict(config))
        defaults = dict(defaults or {})
        same = identity or (lambda k, v: v)
        diff = [k for k in keys if k in new and same(k, stored.get(k, defaults.get(k))) != same(k, new.get(k))]
        if diff:
            raise SchemaError(f"the run at '{self.path}' was started with different settings for {diff}; "
                              f"resume it with the same settings or fit into a new --out folder")

    def update_config(self, **kw: Any) -> None:
        cfg = self.config
        cfg.update(jsonable(kw))
        self.root.attrs["config"] = cfg

    # -- observed data --------------------------------------------------------------
    def write_observed(self, x: np.ndarray, gripper: np.ndarray, times: np.ndarray,
                       dense: np.ndarray | None = None, source: str = "", images: np.ndarray | None = None,
                       masks: np.ndarray | None = None) -> None:
        """Store the observed state ``x (T, 1+K, 3)``, the gripper path and, when given, the dense
        clouds ``(T, P, 3)`` m, the frames ``images (T, H, W, 3)`` uint8 and their cloth ``masks
        (T, H, W)`` bool (references of the 3-D and the mask Chamfer metric)."""
        g = self.root.require_group("observed")
        if images is not None:
            put_array(g, "images", np.asarray(images, np.uint8), ("frame", "row", "col", "rgb"), "1")
        if masks is not None:
            put_array(g, "masks", np.asarray(masks, bool), ("frame", "row", "col"), "1")
        put_array(g, "x", x, ("frame", "point", "xyz"), "m")
        put_array(g, "gripper", gripper, ("frame", "xyz"), "m")
        put_array(g, "times", times, ("frame",), "s")
        if dense is not None:
            put_array(g, "dense", dense, ("frame", "point", "xyz"), "m")
        g.attrs["source"] = source

    def read_observed(self) -> dict[str, np.ndarray]:
        """The observed arrays (:meth:`write_observed`) by name.

        Raises:
            ObservedDamaged: the group is missing, one of its arrays cannot be read (a truncated or corrupt
                chunk) or has the wrong shape (:func:`~softsbi.core.store.damage.observed_faults`); the fix says
                that the fit rebuilds it from the recording.
        """
        where = self.path / "observed"
        fix = "re-running the same `softsbi fit` command rebuilds it from the recording"
        if "observed" not in self.root:
            raise ObservedDamaged(f"'{where}' is missing", fix)
        for why in observed_faults(self.root).values():
            raise ObservedDamaged(f"'{where}' cannot be used ({why})", fix)
        g = self.root["observed"]
        out = {}
        for k in array_names(g):
            try:
                out[k] = g[k][...]
            except Exception as exc:  # noqa: BLE001 - the codec's error for a damaged chunk
                raise ObservedDamaged(f"'{where}' cannot be read (its '{k}' array: {type(exc).__name__})",
                                      fix) from None
        return out

    # -- rounds -----------------------------------------------------------------------
    def _round(self, r: int) -> zarr.Group:
        return self.root["rounds"][str(r)]

    def round_ids(self) -> list[int]:
        return sorted(int(k) for k in group_names(self.root["rounds"]))

    def is_begun(self, r: int) -> bool:
        return str(r) in self.root["rounds"] and bool(self._round(r).attrs.get("begun", False))

    def is_complete(self, r: int) -> bool:
        return str(r) in self.root["rounds"] and bool(self._round(r).attrs.get("complete", False))

    def completed_rounds(self) -> list[int]:
        out = []
        for r in self.round_ids():
            if not self.is_complete(r):
                break
            out.append(r)
        return out

    def begin_round(self, r: int, theta: np.ndarray, u: np.ndarray, seeds: np.ndarray,
                    x_shape: tuple[int, ...], proposal: str, sensor_u: np.ndarray | None = None) -> None:
        """Create round ``r`` with its parameter draws; results start as pending.

        ``sensor_u`` ``(n, K, D)`` (unit cube): K further parameter vectors per simulation that differ from
        ``u`` in the sensor parameters only (``FitConfig.sensor_draws``); their observations ``sensor_x``
        ``(n, K, *x_shape)`` are written with the simulation (:meth:`write_simulation`).
        A half-created round (killed before ``begun`` was set) is removed first.
        """
        rounds = self.root["rounds"]
        if str(r) in rounds:
            if self.is_begun(r):
                raise SchemaError(f"round {r + 1} (group rounds/{r}) already begun in '{self.path}'")
            shutil.rmtree(self.path / "rounds" / str(r), ignore_errors=True)
            rounds = self.root = zarr.open_group(str(self.path), mode="a")
            rounds = self.root["rounds"]
        g = rounds.require_group(str(r))
        n, d = theta.shape
        T = x_shape[0]
        put_array(g, "theta", theta, ("simulation", "parameter"), "physical (see param_space)")
        put_array(g, "u", u, ("simulation", "parameter"), "unit cube")
        put_array(g, "seed", np.asarray(seeds, np.int64), ("simulation",), "1")
        g.create_array("x", shape=(n, *x_shape), dtype="float32", chunks=(1, *x_shape), fill_value=np.nan,
                       dimension_names=("simulation", "frame", "point", "xyz"), attributes={"units": "m"})
        g.create_array("chamfer", shape=(n, T), dtype="float32", chunks=(1, T), fill_value=np.nan,
                       dimension_names=("simulation", "frame"), attributes={"units": "m"})
        if sensor_u is not None:
            k = sensor_u.shape[1]
            put_array(g, "sensor_u", sensor_u, ("simulation", "draw", "parameter"), "unit cube")
            g.create_array("sensor_x", shape=(n, k, *x_shape), dtype="float32", chunks=(1, k, *x_shape),
                           fill_value=np.nan, dimension_names=("simulation", "draw", "frame", "point", "xyz"),
                           attributes={"units": "m"})
        g.create_array("status", shape=(n,), dtype="uint8", chunks=(1,), fill_value=STATUS_PENDING,
                       dimension_names=("simulation",),
                       attributes={"units": "1", "codes": "0 ok, 1 diverged, 2 implausible, 3 error, 255 pending"})
        g.attrs.update({"proposal": proposal, "failures": {}, "complete": False})
        g.attrs["begun"] = True

    def write_simulation(self, r: int, i: int, x: np.ndarray | None, chamfer: np.ndarray | None,
                         status: int, reason: str = "", sensor_x: np.ndarray | None = None) -> None:
        """Store simulation ``i`` of round ``r`` (``sensor_x``: its observations at the round's ``sensor_u``
        draws); ``status`` is written last (it marks the row done)."""
        if x is not None:
            self._round_array(r, "x")[i] = np.asarray(x, np.float32)
        if sensor_x is not None and (sx := self._round_array(r, "sensor_x")) is not None:
            sx[i] = np.asarray(sensor_x, np.float32)
        if chamfer is not None:
            self._round_array(r, "chamfer")[i] = np.asarray(chamfer, np.float32)
        if status != 0 and reason:
            g = self._round(r)
            fails = dict(g.attrs.get("failures", {}))
            fails[str(i)] = reason
            g.attrs["failures"] = fails
        self._round_array(r, "status")[i] = np.uint8(status)

    def round_data(self, r: int, keys: Sequence[str] = ROUND_ARRAYS) -> dict[str, np.ndarray]:
        """Round ``r``'s arrays named in ``keys`` that it holds (default :data:`ROUND_ARRAYS`; add
        ``"sensor_u"``, ``"sensor_x"`` for a fit's sensor draws, which only those who need them read)."""
        g = self._round(r)
        return {k: g[k][...] for k in keys if k in g}

    def round_attrs(self, r: int) -> dict[str, Any]:
        return dict(self._round(r).attrs)

    def round_record(self, r: int) -> RoundRecord:
        """Round ``r``'s stored attributes, typed (:class:`RoundRecord`)."""
        return RoundRecord.of(self._round(r).attrs)

    def add_bank_hits(self, r: int, n: int) -> None:
        """Count ``n`` more of round ``r``'s simulations as read from a simulation bank (round attribute
        ``bank_hits``, at most the round's size; a redone row read again is not counted twice over the size)."""
        g = self._round(r)
        g.attrs["bank_hits"] = min(int(g.attrs.get("bank_hits", 0)) + int(n), int(g["status"].shape[0]))

    def pending(self, r: int) -> np.ndarray:
        return np.nonzero(self._round(r)["status"][...] == STATUS_PENDING)[0]

    def finish_round(self, r: int, q: Any, info: Mapping[str, Any],
                     estimator: "EstimatorState | None" = None) -> None:
        """Write round ``r``'s posterior ``q(u | x_obs)`` and training info, then mark the round complete.

        A :class:`MixtureOfGaussians` ``q`` is kept as its arrays. Any other ``q`` (e.g. a normalising
        flow) is kept as the state of the estimator that gives it, ``estimator`` (its plugin name,
        constructor options and ``state_dict()``: NumPy arrays, numbers, strings, None, and dicts and
        lists of them; array-likes such as CPU tensors are stored as NumPy arrays), from which
        :meth:`read_posterior` restores it.

        Raises:
            SchemaError: ``q`` is not a mixture and no ``estimator`` state is given, or the state holds a
                value that is none of the above.
        """
        # encoded before anything is written: a state that cannot be stored changes nothing
        arrays, attrs = encode_posterior(q, estimator, f"round {r + 1}")
        g = self._round(r)
        g.attrs["complete"] = False
        if "posterior" in g:  # a half-written posterior of an interrupted session, or one trained again
            shutil.rmtree(self.path / "rounds" / str(r) / "posterior", ignore_errors=True)
            self.root = zarr.open_group(str(self.path), mode="a")
            g = self._round(r)
        write_posterior(g.require_group("posterior"), arrays, attrs)
        g.attrs["info"] = jsonable(dict(info))
        g.attrs["complete"] = True

    def read_posterior(self, r: int) -> "MixtureOfGaussians | EstimatorState":
        """Round ``r``'s stored posterior: the mixture, or the :class:`EstimatorState` to restore the
        estimator from (:meth:`finish_round`), after checking the stored checksum.

        Raises:
            PosteriorDamaged: the posterior is missing, cannot be read, or does not match its checksum (one line
                naming the round and the fix: the fit trains the round again from its stored simulations).
            SchemaError: a posterior format this softsbi does not read.
        """
        where = f"run '{self.path}': round {r + 1}'s stored posterior"
        fix = ("re-run the same `softsbi fit` command: it trains that round again from its stored simulations, "
               "which are intact")
        return read_posterior_group(lambda: self._round(r)["posterior"], where, fix,
                                    str(self.root.attrs.get("softsbi_version")))

    def reset_failures(self) -> tuple[int, int, int] | None:
        """Make the failed simulations of the earliest round that has any pending again
        (:meth:`redo`).

        Returns:
            ``(round, failed simulations reset, simulations of later rounds removed)``, or None when
            no round holds a failed simulation.
        """
        for r in self.round_ids():
            status = self._round(r)["status"][...]
            failed = np.nonzero((status != 0) & (status != STATUS_PENDING))[0]
            if len(failed):
                return r, int(len(failed)), self.redo(r, failed)
        return None

    def damaged_groups(self) -> dict[str, str]:
        """Groups holding an array that cannot be read whole (a truncated or corrupt chunk), other than the
        per-simulation arrays :meth:`damaged` repairs row by row: ``{group path: reason}``, e.g.
        ``{"evaluation": "its 'chamfer' array cannot be read (RuntimeError)"}``; the paths are ``observed``,
        ``rounds/<r>`` (the round's draws), ``rounds/<r>/posterior`` and the other top-level groups."""
        return unreadable_groups(self.root, self.round_ids())

    def damaged(self) -> tuple[int, dict[int, str]] | None:
        """The earliest round with stored simulations that cannot be trusted: a chunk that cannot
        be read (truncated or corrupt) or a simulation marked done whose state is missing (a deleted
        chunk reads as its fill value).

        Returns:
            ``(round, {simulation: reason})``, or None when every stored simulation is intact.

        Raises:
            SchemaError: a round's array has the wrong shape (:meth:`damaged_groups` names it too): one line naming
                the array, its shape, the expected one and the fix.
        """
        for r in self.round_ids():
            for why in round_faults(self.root, r).values():
                raise SchemaError(f"'{self.path / 'rounds' / str(r)}' cannot be trusted ({why}); "
                                  f"{damage_fix(self.path, f'rounds/{r}')}")
            bad = damaged_rows(self._round(r), self.is_complete(r))
            if bad:
                return r, bad
        return None

    def redo(self, r: int, rows: Sequence[int]) -> int:
        """Make simulations ``rows`` of round ``r`` pending again (their parameters and seeds stay),
        mark the round incomplete (its posterior is removed) and remove every later round and the
        final evaluation, which were drawn from its old posterior.

        Returns:
            the number of simulations of later rounds removed.
        """
        later = [k for k in self.round_ids() if k > r]
        dropped = sum(int(self._round(k)["status"].shape[0]) for k in later)
        for k in later:
            shutil.rmtree(self.path / "rounds" / str(k), ignore_errors=True)
        shutil.rmtree(self.path / "evaluation", ignore_errors=True)
        shutil.rmtree(self.path / "rounds" / str(r) / "posterior", ignore_errors=True)
        self.root = zarr.open_group(str(self.path), mode="a")
        g = self._round(r)
        g.attrs["complete"] = False
        rows = np.asarray(sorted(int(i) for i in rows), dtype=np.int64)
        if len(rows):
            for i in rows:  # whole-chunk writes: a damaged chunk is replaced, never read
                g["x"][int(i)] = np.full(g["x"].shape[1:], np.nan, np.float32)
                g["chamfer"][int(i)] = np.full(g["chamfer"].shape[1:], np.nan, np.float32)
            g["status"].oindex[rows] = np.uint8(STATUS_PENDING)
            fails = {k: v for k, v in dict(g.attrs.get("failures", {})).items() if int(k) not in set(rows.tolist())}
            g.attrs["failures"] = fails
        return int(dropped)
