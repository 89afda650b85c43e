"""The tables and sentences ``fit`` (and the demo's fits) and ``calibrate`` print, rendered from their results
(``report.json`` and ``calibration.json`` as dicts). Pure functions: the CLI only prints what they return."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from softsbi.core.results.fitreport import CalibrationResult
from softsbi.core.metrics import describe_change
from softsbi.inference.calibration import SHAPES
from softsbi.inference.contraction import INFORMED_MAX_RATIO, bound_sentence, contraction_from_report, format_estimate
from softsbi.report.text import rollouts, truth_miss_hint


@dataclass(frozen=True)
class TextTable:
    """A table to print: column headers, rows of cell strings (each as long as ``columns``) and a title."""
    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    title: str | None = None


def posterior_table(rep: Mapping[str, Any]) -> TextTable:
    """The fit's posterior per parameter in physical units (``rep``: ``report.json``): estimate, 90% interval, its
    width over the prior's, and with a simulated recording's ``truth`` the hidden value and whether the interval
    holds it."""
    truth = rep.get("truth") or {}
    con = contraction_from_report(rep)
    cols = (("parameter", "unit", "estimate", "90% interval", "width / prior")
            + (("hidden value", "inside 90%?") if truth else ()))
    rows = []
    for p in rep["parameters"]:
        n = p["name"]
        c = con[n]
        row = [n, p["unit"], format_estimate(c), f"[{rep['posterior_q05'][n]:.4g}, {rep['posterior_q95'][n]:.4g}]",
               f"{c['width_ratio']:.2f}" + ("" if c["informed"] else " not informed")]
        if truth:
            ok = rep["truth_in_90pct_interval"].get(n)
            row += [f"{truth[n]:.4g}" if n in truth else "-", "-" if ok is None else ("yes" if ok else "NO")]
        rows.append(tuple(row))
    return TextTable(cols, tuple(rows), title="Posterior (physical units)")


def best_fit_lines(rep: Mapping[str, Any], widened: Sequence[str] = ()) -> list[str]:
    """The fit's widened priors (``widened``: each of ``rep['widened']`` in words) and its best fit
    (``rep['best_fit']``), one line each."""
    lines = ["Note: " + w + "." for w in widened]
    b = rep.get("best_fit")
    if not b:
        return lines
    units = {p["name"]: p["unit"] for p in rep["parameters"]}
    value = (f"Chamfer {b['chamfer_m'] * 100:.2f} cm" if "chamfer_m" in b else
             f"mask Chamfer {b.get('mask_chamfer_px', float('nan')):.2f} px")
    ref = b.get("refine")
    how = f"the lowest of {b['simulations_searched']} simulations" + (
        f", {ref['simulations']} of them by CMA-ES from the posterior" if ref else "")
    return lines + ["Best fit: " + ", ".join(f"{k}={v:.4g}{'' if units.get(k) in (None, '', '1') else ' ' + units[k]}"
                                             for k, v in b["theta"].items())
                    + f"; {value} ({b['source']}; {how}; its rollout in clouds.png and softsbi view)"]


def fit_report_lines(rep: Mapping[str, Any], out: Path, widened: Sequence[str] = ()) -> list[str]:
    """The sentences under :func:`posterior_table`, in order: the hint that the intervals miss too many hidden
    values, how to read the table, the bounds the posterior presses, :func:`best_fit_lines`, the Chamfer before and
    after the fit, and what was simulated and written (``out``: the run directory)."""
    lines = []
    hint = truth_miss_hint(rep.get("truth_in_90pct_interval") or {}, str(out)) if rep.get("truth") else None
    if hint:
        lines.append(hint)
    lines.append(f"estimate: mean ± std, or geometric mean ×/÷ multiplicative spread for log-scaled parameters; "
                 f"width / prior: the 90% interval's width over the prior's in the parameter's own scale (log for "
                 f"log-scaled ones); above {INFORMED_MAX_RATIO:g} the data do not inform the parameter")
    lines += ["Note: " + bound_sentence(e) + "." for e in rep.get("posterior_at_bounds") or []]
    lines += best_fit_lines(rep, widened)
    if rep.get("mask_chamfer_prior_px") and rep.get("mask_chamfer_posterior_px"):
        lines.append(f"Mask Chamfer to the measured frames: prior {rep['mask_chamfer_prior_px']:.2f} px -> posterior "
                     f"{rep['mask_chamfer_posterior_px']:.2f} px "
                     f"({describe_change(rep['mask_chamfer_prior_px'], rep['mask_chamfer_posterior_px'])})")
    if rep.get("chamfer_prior_m") and rep.get("chamfer_posterior_m"):
        lines.append(f"Chamfer to the measurement: prior {rep['chamfer_prior_m'] * 100:.2f} cm -> posterior "
                     f"predictive {rep['chamfer_posterior_m'] * 100:.2f} cm{rollouts(rep.get('chamfer_posterior_n'))} "
                     f"({describe_change(rep['chamfer_prior_m'], rep['chamfer_posterior_m'])})")
        if rep["chamfer_posterior_m"] > rep["chamfer_prior_m"]:
            lines.append("Note: rollouts at the posterior miss the measurement by more than rollouts at the prior: "
                         "what the fit matched (the observed state) does not bring the simulated object closer, a "
                         f"sign that the model cannot reach the data; `softsbi check {out}` shows where and when it "
                         f"misses")
    lines.append(f"{rep['simulations']} simulations ({rep['failed_simulations']} failed), {rep['wall_time_s']:.0f} s. "
                 f"Outputs in {out}: report.json, run.zarr, chamfer_rounds.png, posterior_pairs.png, clouds.png")
    return lines


def calibration_table(out: CalibrationResult) -> TextTable:
    """``calibrate``'s table: expected coverage at 50% and 90% with the calibrated range of the whole curve's
    simultaneous band and the verdict at each level."""
    c = out.coverage
    conf = 100 * c.band_simultaneous_confidence
    return TextTable(
        ("level", "expected coverage", f"calibrated range ({conf:.1f}%, whole curve)", "verdict"),
        tuple((f"{int(100 * g)}%", f"{at:.2f}", f"[{b[0]:.2f}, {b[1]:.2f}]", v)
              for g, at, b, v in ((0.5, c.at_50, c.band_50, out.verdict_50), (0.9, c.at_90, c.band_90, out.verdict_90))),
        title=f"Calibration of '{out.estimator}' on {out.n_test} fresh test simulations")


def calibration_lines(out: CalibrationResult) -> list[str]:
    """One line per diagnostic ``calibrate``'s verdict reads: joint HPD coverage, TARP and SBC per parameter."""
    c, d = out.coverage, out.diagnostics
    conf = 100 * c.band_simultaneous_confidence
    out_pw = c.outside_pointwise
    t = d["tarp"]
    s = d["sbc"]
    bad = [p for p in s["parameters"] if p["rejects"]]
    return [
        "joint coverage (HPD): " + ("inside" if c.inside_simultaneous else "OUTSIDE")
        + f" the simultaneous {conf:.1f}% band over {len(c.levels) - 2} levels"
        + ("" if c.inside_simultaneous else f" ({d['coverage']['direction']})") + "; "
        + (f"outside the pointwise 95% band at {', '.join(f'{int(round(100 * g))}%' for g in out_pw)}"
           if out_pw else "inside the pointwise 95% band at every level"),
        f"TARP: KS p={t['ks_pvalue']:.2g} (rejects below {t['level']:.3g}), ATC {t['atc']:+.3f}: "
        + (f"rejects ({t['direction']})" if t["rejects"] else "consistent with calibrated"),
        f"SBC per parameter (KS, mean, spread and histogram band, each at {s['level']:.2g}: Bonferroni over "
        f"{len(s['parameters'])} parameters): "
        + ("; ".join(f"{p['name']} " + " and ".join(SHAPES[k] for k in p["shapes"]) for p in bad) if bad
           else "every rank histogram uniform")
        + (f"; uniform: {', '.join(p['name'] for p in s['parameters'] if not p['rejects'])}"
           if bad and len(bad) < len(s["parameters"]) else ""),
    ]
