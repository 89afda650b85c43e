"""The typed form of a fit's ``report.json`` (:class:`FitReport`), of ``calibration.json``
(:class:`CalibrationResult`) and of a stored task's training report (:class:`TrainingReport`).

The fit writes ``report.json`` as a plain JSON object; :meth:`FitReport.from_json` reads it into frozen dataclasses
and :meth:`FitReport.to_json` gives back the same object. Reports written by older softsbi versions lack keys
added since: every key but :data:`REQUIRED_KEYS` is optional and reads as None (or an empty tuple / mapping, or
the default documented on the field); keys this version does not know are kept in :attr:`FitReport.extra`.

Units: distances in metres (``_m``) or, for an image fit, pixels (``_px``); parameters in their own units.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from softsbi.core.jsonfile import ResultDamaged, _build, _plain

#: what every reader of a fit's ``report.json`` needs in it: a file without them is damaged
REQUIRED_KEYS = ("parameters", "posterior_median")
#: the image metric: its headline keys are ``mask_chamfer_*_px`` and its ``chamfer_*_m`` are None
MASK_METRIC = "mask_chamfer_px"
#: the command that writes a run's ``report.json`` again, named by :class:`~softsbi.core.results.ResultDamaged`
REWRITE = "re-running the fit with the same `softsbi fit ... --out {run}` command"


@dataclass(frozen=True, kw_only=True)
class ParameterRow:
    """One inferred parameter as the report lists it (:meth:`~softsbi.core.types.ParamSpace.to_json`).

    Attributes:
        name, unit, description: as the parameter's. low, high: the prior box (own units). log: log-uniform prior.
        limits: ``(lowest, highest)`` physically meaningful values (None for an infinite end), None when unset.
    """

    name: str
    low: float
    high: float
    unit: str = ""
    log: bool = False
    description: str = ""
    limits: tuple[float | None, float | None] | None = None

    def to_json(self) -> dict[str, Any]:
        """The entry as written (``limits`` only where set)."""
        d = _plain(self)
        if self.limits is None:
            d.pop("limits")
        return d


@dataclass(frozen=True, kw_only=True)
class Contraction:
    """How much the posterior narrowed one parameter (:func:`~softsbi.inference.contraction.contraction`).

    Attributes:
        scale: ``"log"`` or ``"linear"``. center, spread: the posterior's (own units; spread None for log ones).
        q05, q95: its 90% interval. width_ratio: the interval's width over the prior's, in the parameter's scale.
        informed: ``width_ratio <= informed_max_width_ratio``.
        slab_mass: the posterior's mass next to the lower and the upper prior bound, each in the slab of
            :data:`~softsbi.inference.contraction.BOUND_SLAB` of the range (None: an older report).
        unit_mean, unit_std: the posterior's mean and standard deviation in unit coordinates (the prior box mapped
            to [0, 1] in the parameter's own scale; None: an older report).
    """

    scale: str | None = None
    center: float | None = None
    spread: float | None = None
    q05: float | None = None
    q95: float | None = None
    width_ratio: float | None = None
    informed: bool | None = None
    slab_mass: tuple[float, float] | None = None
    unit_mean: float | None = None
    unit_std: float | None = None

    def to_json(self) -> dict[str, Any]:
        """The entry as written (an older report's, without ``slab_mass`` or the unit moments, as read)."""
        d = _plain(self)
        for k in ("slab_mass", "unit_mean", "unit_std"):
            if d[k] is None:
                del d[k]
        return d


@dataclass(frozen=True, kw_only=True)
class BoundPressure:
    """A parameter whose posterior piles up at a prior bound (:func:`~softsbi.inference.contraction.bound_pressure`).

    Attributes:
        param: the parameter. side: ``"lower"`` or ``"upper"``. bound: that bound (own units). unit: its unit.
        mass: the posterior's mass next to the bound. suggested_bounds: the prior to try instead (None: the bound
            is a physical limit).
    """

    param: str
    side: str
    bound: float | None = None
    unit: str | None = None
    mass: float | None = None
    suggested_bounds: tuple[float, float] | None = None

    def to_json(self) -> dict[str, Any]:
        """The entry as written."""
        return _plain(self)


@dataclass(frozen=True, kw_only=True)
class RoundRow:
    """One round of the fit (``per_round``).

    Attributes:
        round: its index (0-based). usable, failed, bank_hits: its simulations that trained the estimator, that
            failed, that were read from the simulation bank. chamfer_posterior_m, chamfer_posterior_std_m: the
            final posterior's Chamfer (m; only the last round has it). mask_chamfer_posterior_px,
            mask_chamfer_posterior_std_px: the same for an image fit (px). mass_in_box: the round posterior's mass
            inside the prior box. train_seconds: the estimator's training time. posterior_mean: the round
            posterior's mean (own units). task: the key of the stored task whose trained posterior the round
            conditioned instead of training (:mod:`softsbi.workflows.fit.task_store`), else None.
    """

    round: int
    usable: int | None = None
    failed: int | None = None
    bank_hits: int = 0
    chamfer_posterior_m: float | None = None
    chamfer_posterior_std_m: float | None = None
    mask_chamfer_posterior_px: float | None = None
    mask_chamfer_posterior_std_px: float | None = None
    mass_in_box: float | None = None
    train_seconds: float | None = None
    posterior_mean: Mapping[str, float] | None = None
    task: str | None = None

    def to_json(self, metric: str) -> dict[str, Any]:
        """The row as written for a report of ``metric`` (an image fit's rows carry the ``_px`` pair instead)."""
        d = _plain(self)
        drop = ("chamfer_posterior_m", "chamfer_posterior_std_m") if metric == MASK_METRIC else (
            "mask_chamfer_posterior_px", "mask_chamfer_posterior_std_px")
        drop += ("task",) if self.task is None else ()  # a round trained in the fit
        return {k: v for k, v in d.items() if k not in drop}


@dataclass(frozen=True, kw_only=True)
class BestFitRow:
    """``best_fit``: the best-scoring simulation the fit found (:mod:`~softsbi.workflows.fit.bestfit`).

    Attributes:
        theta: its parameters (own units). value: its score under the report's metric (m or px; stored under the
            metric's name, e.g. ``chamfer_m``). per_frame: that score per frame. source: where it came from
            (a round, the evaluation or the refinement). simulation, seed: its index and simulation seed there.
            simulations_searched: how many simulations were searched. rollout: where its rollout is stored in the
            run (None: not stored). refine: the CMA-ES refinement's summary (None: no refinement).
    """

    theta: Mapping[str, float]
    value: float | None = None
    per_frame: tuple[float, ...] | None = None
    source: str | None = None
    simulation: int | None = None
    seed: int | None = None
    simulations_searched: int | None = None
    rollout: str | None = None
    refine: Mapping[str, Any] | None = None

    @staticmethod
    def keys(metric: str) -> tuple[str, str]:
        """The names :attr:`value` and :attr:`per_frame` are stored under for ``metric``."""
        return metric, metric.replace("_m", "_per_frame_m").replace("_px", "_per_frame_px")

    @classmethod
    def from_json(cls, data: Mapping[str, Any], metric: str) -> "BestFitRow":
        """Read the ``best_fit`` object of a report of ``metric``."""
        value, per_frame = cls.keys(metric)
        d = {k: v for k, v in data.items() if k not in (value, per_frame)}
        return _build(cls, {**d, "value": data.get(value), "per_frame": data.get(per_frame)})

    def to_json(self, metric: str) -> dict[str, Any]:
        """The object as written for a report of ``metric``."""
        value, per_frame = self.keys(metric)
        d = _plain(self)
        return {"theta": d["theta"], value: d["value"], per_frame: d["per_frame"],
                **{k: d[k] for k in ("source", "simulation", "seed", "simulations_searched", "rollout", "refine")}}


#: report keys written only in some reports: an image fit's (:data:`MASK_METRIC`) and the ones that need a
#: Chamfer of prior and posterior or a hidden truth; absent keys read as None and None ones are not written
_MASK_KEYS = ("mask_chamfer_prior_px", "mask_chamfer_prior_std_px", "mask_chamfer_posterior_px",
              "mask_chamfer_posterior_std_px")
_OMIT_IF_NONE = ("chamfer_reduction", "truth_in_90pct_interval")


@dataclass(frozen=True, kw_only=True)
class FitReport:
    """A finished fit's ``report.json``, typed (module docstring: reading older reports).

    Attributes:
        observed: the measurement's source. backend, estimator, effects: the model fitted.
        parameters: the inferred parameters and their prior (:class:`ParameterRow`). fixed: parameters held fixed.
        rounds, sims_per_round, simulations: the budget (simulations: all of them, the evaluation's included).
        proposal: ``"corrected"``, ``"truncated"`` or ``"prior"``. min_height_m: the recording's height cut.
        frames: the frames fitted (None: all). failed_simulations, bank_hits: simulations that failed, that were
            read from the simulation bank.
        chamfer_prior_m, chamfer_prior_std_m, chamfer_posterior_m, chamfer_posterior_std_m, chamfer_posterior_n:
            the mean Chamfer (m) of prior and posterior-predictive rollouts over :attr:`metric_frames`, its spread
            and the posterior rollouts it averages (None for an image fit: see the ``mask_*`` fields).
        metric_min_z_m, metric_frames, metric_sensor: the metric's sensor model (height cut, frames, sensor).
        chamfer_posterior_one_sided_m, chamfer_posterior_one_sided_std_m: the measured -> simulated Chamfer (m).
        chamfer_prior_per_frame_m, chamfer_posterior_per_frame_m, chamfer_posterior_one_sided_per_frame_m: per frame.
        posterior_mean, posterior_std, posterior_q05, posterior_q95, posterior_median: per parameter (own units).
        contraction: per parameter (:class:`Contraction`). informed_max_width_ratio: its "informed" threshold.
        posterior_at_bounds: parameters pressing a prior bound (:class:`BoundPressure`), most mass first.
        truth: a simulated recording's hidden parameters (None for a real one).
        per_round: one :class:`RoundRow` per round. wall_time_s: the fit's time. metric: ``"chamfer_m"`` or
            :data:`MASK_METRIC`.
        mask_chamfer_prior_px, mask_chamfer_prior_std_px, mask_chamfer_posterior_px, mask_chamfer_posterior_std_px:
            an image fit's headline (px; None otherwise).
        chamfer_reduction: ``1 - posterior / prior`` Chamfer (None when either is missing).
        truth_in_90pct_interval: per parameter, whether the truth lies inside the 90% interval (None: no truth).
        best_fit: :class:`BestFitRow` (None: none stored). widened: the fit's prior widenings
            (:func:`~softsbi.workflows.fit.prior_widening.records`, in order).
        extra: keys this version does not know, kept as read.
    """

    parameters: tuple[ParameterRow, ...]
    posterior_median: Mapping[str, float]
    observed: str | None = None
    backend: str | None = None
    estimator: str | None = None
    effects: tuple[str, ...] = ()
    fixed: Mapping[str, float] = field(default_factory=dict)
    rounds: int | None = None
    sims_per_round: int | None = None
    simulations: int | None = None
    proposal: str | None = None
    min_height_m: float | None = None
    frames: tuple[int, ...] | None = None
    failed_simulations: int | None = None
    bank_hits: int = 0
    chamfer_prior_m: float | None = None
    chamfer_prior_std_m: float | None = None
    chamfer_posterior_m: float | None = None
    chamfer_posterior_std_m: float | None = None
    chamfer_posterior_n: int | None = None
    metric_min_z_m: float | None = None
    metric_frames: tuple[int, ...] | None = None
    metric_sensor: str | None = None
    chamfer_posterior_one_sided_m: float | None = None
    chamfer_posterior_one_sided_std_m: float | None = None
    chamfer_prior_per_frame_m: tuple[float, ...] | None = None
    chamfer_posterior_per_frame_m: tuple[float, ...] | None = None
    chamfer_posterior_one_sided_per_frame_m: tuple[float, ...] | None = None
    posterior_mean: Mapping[str, float] = field(default_factory=dict)
    posterior_std: Mapping[str, float] = field(default_factory=dict)
    posterior_q05: Mapping[str, float] = field(default_factory=dict)
    posterior_q95: Mapping[str, float] = field(default_factory=dict)
    contraction: Mapping[str, Contraction] = field(default_factory=dict)
    informed_max_width_ratio: float | None = None
    posterior_at_bounds: tuple[BoundPressure, ...] = ()
    truth: Mapping[str, float] | None = None
    per_round: tuple[RoundRow, ...] = ()
    wall_time_s: float | None = None
    metric: str = "chamfer_m"
    mask_chamfer_prior_px: float | None = None
    mask_chamfer_prior_std_px: float | None = None
    mask_chamfer_posterior_px: float | None = None
    mask_chamfer_posterior_std_px: float | None = None
    chamfer_reduction: float | None = None
    truth_in_90pct_interval: Mapping[str, bool] | None = None
    best_fit: BestFitRow | None = None
    widened: tuple[Mapping[str, Any], ...] = ()
    extra: Mapping[str, Any] = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        """The inferred parameters' names, in column order."""
        return [p.name for p in self.parameters]

    @property
    def task(self) -> str | None:
        """The key of the stored task whose trained posterior the fit's first round conditioned (the fit then stopped
        at it when it ran one round, :attr:`RoundRow.task`), else None."""
        return self.per_round[0].task if self.per_round else None

    @classmethod
    def from_json(cls, data: Mapping[str, Any], path: str | Path = "report.json",
                  rewrite: str | None = None) -> "FitReport":
        """Read a ``report.json`` object (this version's or an older one: module docstring).

        Args:
            path: the file, for the error. rewrite: the command that writes it again (default: the fit's own,
                :data:`REWRITE`, in the run directory of ``path``).

        Raises:
            ResultDamaged: it lacks a key of :data:`REQUIRED_KEYS` or holds a value of the wrong kind; one line
                naming the file and ``rewrite``.
        """
        path = Path(path)
        rewrite = rewrite or REWRITE.format(run=path.parent)
        missing = [k for k in REQUIRED_KEYS if k not in data]
        if missing:
            raise ResultDamaged(path, f"it lacks {', '.join(repr(k) for k in missing)}", rewrite)
        known = {f.name for f in dataclasses.fields(cls)} - {"extra", "best_fit"}
        try:
            metric = str(data.get("metric") or "chamfer_m")
            d = {k: v for k, v in data.items() if k in known}
            report = _build(cls, d)
            best = data.get("best_fit")
            # _build leaves a Mapping's values as read: the contraction's entries are typed here
            widths = {str(k): _build(Contraction, v) for k, v in (data.get("contraction") or {}).items()}
            return dataclasses.replace(
                report, metric=metric, best_fit=None if best is None else BestFitRow.from_json(best, metric),
                contraction=widths,
                extra={k: v for k, v in data.items() if k not in known and k != "best_fit"})
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise ResultDamaged(path, f"not a fit report: {exc}", rewrite) from None

    def to_json(self) -> dict[str, Any]:
        """The ``report.json`` object this report was read from (keys an older report lacked included)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            name, value = f.name, getattr(self, f.name)
            if name == "extra" or (name in _MASK_KEYS and self.metric != MASK_METRIC) or (
                    name in _OMIT_IF_NONE and value is None):
                continue
            if name == "parameters":
                out[name] = [p.to_json() for p in value]
            elif name == "per_round":
                out[name] = [r.to_json(self.metric) for r in value]
            elif name == "contraction":
                out[name] = {k: c.to_json() for k, c in value.items()}
            elif name == "best_fit":
                out[name] = None if value is None else value.to_json(self.metric)
            else:
                out[name] = _plain(value)
        out.update(_plain(self.extra))
        return out

    def interval(self, name: str) -> tuple[float | None, float | None]:
        """Parameter ``name``'s 90% posterior interval ``(q05, q95)`` (own units; None where the report lacks it)."""
        return tuple(None if name not in q else float(q[name])  # type: ignore[return-value]
                     for q in (self.posterior_q05, self.posterior_q95))

    def width_ratio(self, name: str) -> float | None:
        """Parameter ``name``'s 90% interval width over the prior's (:class:`Contraction`; None where the report
        lacks it: a report written before contraction, or a parameter it does not infer)."""
        return self.contraction[name].width_ratio if name in self.contraction else None

    def slab_mass(self, name: str) -> tuple[float, float] | None:
        """Parameter ``name``'s posterior mass next to its lower and its upper prior bound
        (:attr:`Contraction.slab_mass`; None where the report lacks it: an older report, or a parameter it does not
        infer)."""
        return self.contraction[name].slab_mass if name in self.contraction else None

    def bound_pressure(self, name: str) -> BoundPressure | None:
        """The prior bound parameter ``name``'s posterior piles up at (:attr:`posterior_at_bounds`), or None: none
        (or a report written before bound pressure)."""
        return next((b for b in self.posterior_at_bounds if b.param == name), None)

    def space_json(self) -> list[dict[str, Any]]:
        """:attr:`parameters` as :meth:`~softsbi.core.types.ParamSpace.from_json` takes them."""
        return [p.to_json() for p in self.parameters]


# ----------------------------------------------------------------------------------------
# calibration.json


@dataclass(frozen=True, kw_only=True)
class Coverage:
    """Expected coverage of the highest-density regions at every credibility level.

    Attributes:
        levels: the levels ``(L,)``. hpd: the coverage at each. band_lo, band_hi: the pointwise binomial band of a
            calibrated estimator (``band_confidence``). at_50, at_90: the coverage at 50% and 90%.
        band_simultaneous_lo, band_simultaneous_hi: the whole curve's band at the verdict's level
            (``band_simultaneous_confidence``; None in a file written before it). outside_pointwise: levels outside
            the pointwise band. inside_simultaneous: the curve stays inside the whole curve's band.
        band_50, band_90: the verdict's band at 50% and 90%.
    """

    levels: tuple[float, ...]
    hpd: tuple[float, ...]
    band_lo: tuple[float, ...]
    band_hi: tuple[float, ...]
    at_50: float
    at_90: float
    band_confidence: float = 0.95
    band_simultaneous_lo: tuple[float, ...] | None = None
    band_simultaneous_hi: tuple[float, ...] | None = None
    band_simultaneous_confidence: float | None = None
    outside_pointwise: tuple[float, ...] = ()
    inside_simultaneous: bool | None = None
    band_50: tuple[float, float] | None = None
    band_90: tuple[float, float] | None = None


@dataclass(frozen=True, kw_only=True)
class RankHistograms:
    """SBC rank histograms, one per parameter (:func:`~softsbi.inference.calibration.rank_tests`).

    Attributes:
        n_bins: bins per histogram. histograms: the counts ``(D, n_bins)``. band: the band ``(low, high)`` (counts)
            a uniform histogram keeps every bin inside at level ``band_level`` (None: an older file's pointwise
            band at ``band_confidence``). shapes: per parameter, the shapes its histogram rejects uniformity with
            (:data:`~softsbi.inference.calibration.SHAPES`). rejects: per parameter. ks_pvalue, chi2_pvalue: per
            parameter.
    """

    n_bins: int
    histograms: tuple[tuple[int, ...], ...]
    band: tuple[float, float]
    ks_pvalue: tuple[float, ...]
    chi2_pvalue: tuple[float, ...] = ()
    band_level: float | None = None
    band_confidence: float | None = None
    shapes: tuple[tuple[str, ...], ...] = ()
    rejects: tuple[bool, ...] = ()


@dataclass(frozen=True, kw_only=True)
class Tarp:
    """TARP coverage (Lemos et al. 2023, :func:`~softsbi.inference.calibration.tarp_coverage`).

    Attributes:
        levels, coverage: its curve. atc: the mean coverage minus level. ks_pvalue: uniformity of its ranks.
    """

    levels: tuple[float, ...]
    coverage: tuple[float, ...]
    atc: float | None = None
    ks_pvalue: float | None = None


@dataclass(frozen=True, kw_only=True)
class CalibrationResult:
    """``calibration.json``: simulation-based calibration of a run's estimator
    (:func:`~softsbi.workflows.tasks.calibrate.calibrate_run`).

    Attributes:
        run: the run directory. estimator, estimator_options: the estimator calibrated.
        n_test: test simulations used. n_test_failed: test simulations that failed. n_no_mass_in_box: test cases
            whose posterior had no mass in the prior box. n_train: training simulations. n_draws: posterior draws
            per test case. rounds: the run's finished rounds.
        test_proposal, coordinates: what the test cases were drawn from and in which coordinates.
        parameters: the inferred parameters' names. coverage: :class:`Coverage`.
        verdict_50, verdict_90: the coverage's verdict at 50% and 90%. verdict: the one verdict.
        calibrated: no diagnostic rejects. alpha: the verdict's family-wise level.
        too_narrow, too_wide, biased: parameters whose marginals are.
        diagnostics: each diagnostic's test as :func:`softsbi.inference.calibration.verdict` gives it
            (``coverage``, ``tarp``, ``sbc``). sbc: :class:`RankHistograms`. tarp: :class:`Tarp`.
        train_seconds, simulation_seconds: timings. estimator_fit: the training's summary (epochs, ...).
        refit_max_mean_difference: how far the retrained estimator's posterior mean lies from the run's
            (unit coordinates; None when another estimator was calibrated).
    """

    run: str
    estimator: str
    n_test: int
    n_train: int
    parameters: tuple[str, ...]
    coverage: Coverage
    verdict: str
    sbc: RankHistograms
    tarp: Tarp
    estimator_options: Mapping[str, Any] = field(default_factory=dict)
    n_test_failed: int = 0
    n_no_mass_in_box: int = 0
    n_draws: int | None = None
    rounds: int | None = None
    test_proposal: str = ""
    coordinates: str = ""
    verdict_50: str | None = None
    verdict_90: str | None = None
    calibrated: bool | None = None
    alpha: float | None = None
    too_narrow: tuple[str, ...] = ()
    too_wide: tuple[str, ...] = ()
    biased: tuple[str, ...] = ()
    diagnostics: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    train_seconds: float | None = None
    simulation_seconds: float | None = None
    estimator_fit: Mapping[str, Any] = field(default_factory=dict)
    refit_max_mean_difference: float | None = None

    @property
    def is_calibrated(self) -> bool:
        """:attr:`calibrated`, or for a file written before it, whether the verdict says so."""
        return self.verdict == "calibrated" if self.calibrated is None else self.calibrated

    @classmethod
    def from_json(cls, data: Mapping[str, Any], path: str | Path = "calibration.json",
                  rewrite: str | None = None) -> "CalibrationResult":
        """Read a ``calibration.json`` object (an older one's missing keys read as the defaults).

        Raises:
            ResultDamaged: it is not a calibration (a key without a default missing, a value of the wrong kind).
        """
        path = Path(path)
        try:
            return _build(cls, dict(data))
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise ResultDamaged(path, f"not a calibration: {exc}",
                                rewrite or f"`softsbi calibrate {path.parent}`") from None

    def to_json(self) -> dict[str, Any]:
        """The ``calibration.json`` object (the order and keys it is written with; None-valued keys an older
        file lacked are written as None)."""
        out = _plain(self)
        for name in ("band_level", "band_confidence"):  # one of the two: the band's level, or an old file's
            if out["sbc"][name] is None:
                out["sbc"].pop(name)
        order = ("run", "estimator", "estimator_options", "n_test", "n_test_failed", "n_no_mass_in_box", "n_train",
                 "n_draws", "rounds", "test_proposal", "coordinates", "parameters", "coverage", "verdict_50",
                 "verdict_90", "verdict", "calibrated", "alpha", "too_narrow", "too_wide", "biased", "diagnostics",
                 "sbc", "tarp", "train_seconds", "simulation_seconds", "estimator_fit", "refit_max_mean_difference")
        return {k: out[k] for k in order}


@dataclass(frozen=True, kw_only=True)
class TrainingReport:
    """A stored task's training report (``softsbi task train``,
    :func:`~softsbi.workflows.tasks.training.training_report`): its amortised posterior measured on held-out
    simulations drawn from the prior.

    Attributes:
        n_test: held-out simulations measured. n_draws: posterior draws per held-out simulation. parameters: the
            inferred parameters' names. coverage: :class:`Coverage`. sbc: :class:`RankHistograms`. tarp:
            :class:`Tarp`. verdict, calibrated, too_narrow, too_wide, biased: as :class:`CalibrationResult`'s.
        contraction: per parameter, the median 90% interval's width over the prior's (``width_ratio``) and whether
            the data inform it (``informed``). n_test_failed: held-out simulations that failed.
        simulation_seconds, train_seconds, wall_seconds: the held-out simulations', the training's and the whole
            training's time (s).
    """

    n_test: int
    n_draws: int
    parameters: tuple[str, ...]
    coverage: Coverage
    sbc: RankHistograms
    tarp: Tarp
    verdict: str
    calibrated: bool
    contraction: Mapping[str, Contraction]
    n_test_failed: int = 0
    too_narrow: tuple[str, ...] = ()
    too_wide: tuple[str, ...] = ()
    biased: tuple[str, ...] = ()
    simulation_seconds: float | None = None
    train_seconds: float | None = None
    wall_seconds: float | None = None

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> "TrainingReport":
        """Read the stored form (:meth:`to_json`).

        Raises:
            ValueError: it is not a training report (a key missing, a value of the wrong kind).
        """
        try:
            return _build(cls, dict(data))
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"not a training report: {exc}") from None

    def to_json(self) -> dict[str, Any]:
        """The stored form: plain JSON values."""
        return _plain(self)
