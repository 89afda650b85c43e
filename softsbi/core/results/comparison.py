"""The typed result of ``compare`` (:class:`CompareResult`): two fits of one measurement side by side, row by row.

Its JSON form (``compare.json``) is written and read like every result of :mod:`softsbi.core.results`.
Units: distances in metres.
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Any

from softsbi.core.jsonfile import UPGRADED
from softsbi.core.results import CheckResult


class Metric(str, Enum):
    """What a row of ``compare`` measures: its key (the row's label in words is :attr:`Row.what`).

    ``CHAMFER``: the posterior-predictive Chamfer, mean over the fit's frames; ``CHAMFER_ONE_SIDED``: the same,
    measured -> simulated; ``ENERGY_CHAMFER``: the Chamfer energy score (:class:`EnergyScore`); ``POSTERIOR_MEAN``:
    the posterior-mean rollout's Chamfer; ``PHASE``, ``REGION``: the Chamfer of one phase or region (:attr:`Row.part`).
    """

    CHAMFER = "chamfer"
    CHAMFER_ONE_SIDED = "chamfer_one_sided"
    ENERGY_CHAMFER = "energy_chamfer"
    POSTERIOR_MEAN = "posterior_mean_chamfer"
    PHASE = "phase"
    REGION = "region"


@dataclass(frozen=True, kw_only=True)
class Row:
    """One row of a comparison: values ``a`` and ``b`` (m) of one ``metric``.

    Attributes:
        what: the row's label in words (:func:`softsbi.report.text.row_label`), for people reading ``compare.json``.
        a, b: the two runs' values (m).
        metric: what it measures (the key rows are found by).
        part: the phase or region of a ``PHASE`` or ``REGION`` row, else ``""``.
    """

    what: str
    a: float
    b: float
    metric: Metric
    part: str = ""

    @property
    def change(self) -> float:
        """Relative change ``(b - a) / a`` (0 when ``a`` is 0)."""
        return (self.b - self.a) / self.a if self.a else 0.0


#: the label prefixes of ``compare.json`` rows written before rows had a ``metric`` (schema 3), in the order they are
#: tried: how :func:`from_json` reads an old file's rows (a phase row is ``"<phase> phase (t0-t1 s)"``)
LEGACY_ROW_LABELS = (("posterior-predictive Chamfer", Metric.CHAMFER), ("one-sided Chamfer", Metric.CHAMFER_ONE_SIDED),
                     ("energy score", Metric.ENERGY_CHAMFER), ("posterior-mean rollout", Metric.POSTERIOR_MEAN),
                     ("region ", Metric.REGION))


def _legacy_row(data: dict[str, Any]) -> dict[str, Any]:
    """A row of an old ``compare.json`` (no ``metric``) with its metric and part read from its label."""
    if "metric" in data:
        return data
    what = str(data.get("what", ""))
    metric = next((m for prefix, m in LEGACY_ROW_LABELS if what.startswith(prefix)), None)
    if metric is Metric.REGION:
        return {**data, "metric": metric, "part": what[len("region "):]}
    if metric is None and " phase (" in what:
        return {**data, "metric": Metric.PHASE, "part": what.split(" phase (")[0]}
    if metric is None:
        raise ValueError(f"a compare row of unknown kind: {what!r}")
    return {**data, "metric": metric}


UPGRADED["Row"] = _legacy_row


@dataclass(frozen=True, kw_only=True)
class CompareResult:
    """The result of ``compare``: two fits of one measurement side by side.

    Attributes:
        run_a, run_b, label_a, label_b: the runs and their labels (the effects each adds).
        rows: keyed by :class:`Metric`: posterior-predictive Chamfer first, then one-sided Chamfer, Chamfer energy
            score, posterior-mean rollout, per phase, per region (:meth:`row` finds one).
        same_sensor: whether both fits see the clouds through the same sensor model.
        check_a, check_b: the two checks.
        png: the figure.
    """

    run_a: str
    run_b: str
    label_a: str
    label_b: str
    rows: tuple[Row, ...]
    same_sensor: bool
    check_a: CheckResult
    check_b: CheckResult
    png: str = ""

    def row(self, metric: Metric) -> Row | None:
        """The first row of ``metric`` (None when the comparison has none, e.g. no energy score)."""
        return next((r for r in self.rows if r.metric == metric), None)
