"""Hand-built typed results (softsbi.core.results) for tests that need a check, a diagnosis or a comparison
without simulating one: fixed numbers, so rendered sentences and figures are reproducible."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from softsbi.core.results import (Band, Candidate, CheckResult, Diagnosis, EnergyScore, Estimate, JointTest, MCPValue,
                                  Phase, Refit, Score)

#: region names as check_run writes them (R1 nearest the first handle's grasp)
REGIONS = tuple(f"R{r + 1}" + (" (at the grasp)" if r == 0 else " (farthest from the grasp)" if r == 8 else "")
                for r in range(9))


def joint(omnibus: int = 0, directional: int | None = 0, n: int = 200, alpha: float = 0.05,
          family: tuple[str, ...] = ("wind", "extra-damping"), effect: str = "wind") -> JointTest:
    """A joint test from the exceedance counts of its omnibus and directional test among ``n`` nulls (``directional``
    None: the omnibus test alone)."""
    return JointTest(
        omnibus=MCPValue(exceed=omnibus, n=n),
        directional=None if directional is None else MCPValue(exceed=directional, n=n),
        directional_effect=None if directional is None else effect,
        family=family,
        alpha=alpha,
        max_null=200,
        statistic=3.2,
    )


def score(value: float, se: float = 0.4, n: int = 30) -> Score:
    """An energy score of the summaries (dimensionless), the score a diagnosis decides on."""
    return Score(value=value, se=se, n=n)


def energy(energy_m: float, se_m: float = 0.0004, spread_m: float = 0.004, n: int = 30) -> EnergyScore:
    """An energy score of the clouds with its terms consistent: ``chamfer = energy + spread / 2``."""
    return EnergyScore(energy_m=energy_m, se_m=se_m, chamfer_m=energy_m + spread_m / 2, spread_m=spread_m, n=n)


def candidate(effect: str, explained: float = 0.3, exceed: int = 0, kind: str = "physics", generic: bool = False,
              description: str = "", n: int = 200, **estimate: float) -> Candidate:
    return Candidate(effect=effect, kind=kind, generic=generic, description=description, explained=explained,
                     adjusted=MCPValue(exceed=exceed, n=n), estimate=estimate)


def refit(effects: tuple[str, ...], value: float, test: JointTest, **fields) -> Refit:
    """A refit whose score of the summaries is ``value`` (its posterior-predictive Chamfer ``value / 1000 + 0.002`` m,
    over 30 rollouts)."""
    fields.setdefault("chamfer_n", 30)
    return Refit(effects=effects, run=f"run/refit-{'+'.join(effects)}", test=test, score=score(value),
                 chamfer_m=value / 1000 + 0.002, **fields)


def check_result(T: int = 25, long: bool = False, test: JointTest | None = None, **fields) -> CheckResult:
    """A check of a 25-frame lift whose error grows with time (worst late, in the farthest region)."""
    t = np.linspace(0, 0.96, T)
    mean = 0.01 + 0.15 * t ** 2
    cuts = np.linspace(0, T, 4).round().astype(int)
    phases = tuple(
        Phase(
            phase=p,
            frames=(int(cuts[k]), int(cuts[k + 1] - 1)),
            t_s=(float(t[cuts[k]]), float(t[cuts[k + 1] - 1])),
            chamfer_m=float(mean[cuts[k] : cuts[k + 1]].mean()),
            chamfer_one_sided_m=float(0.8 * mean[cuts[k] : cuts[k + 1]].mean()),
            in_fit=True,
            worst_region=REGIONS[8],
        )
        for k, p in enumerate(["early", "middle", "late"])
    )
    run = "/very/long/path/to/a/run/directory/" + ("with_a_really_long_name_" * 6 if long else "run")
    region = mean[:, None] * np.linspace(0.5, 1.5, 9)
    band = Band(mean=tuple(mean.tolist()), q05=tuple((0.8 * mean).tolist()), q95=tuple((1.2 * mean).tolist()))
    out = CheckResult(
        run=run,
        n_rollouts=30,
        failed_rollouts=0,
        times_s=tuple(t.tolist()),
        chamfer=band,
        chamfer_one_sided=band,
        chamfer_mean_m=float(mean.mean()),
        chamfer_one_sided_mean_m=float(0.8 * mean.mean()),
        metric_min_z_m=None,
        metric_frames=None,
        metric_sensor="none",
        table_z_m=0.0,
        regions=REGIONS,
        region_error_m=tuple(map(tuple, region.tolist())),
        region_compared=tuple(tuple([True] * 9) for _ in range(T)),
        region_mean_m=dict(zip(REGIONS, region.mean(0).tolist())),
        phases=phases,
        worst_frames=(T - 1, T - 2, T - 3),
        worst_regions=(REGIONS[8], REGIONS[7]),
        test=test or joint(),
        ranking=(),
        energy=energy(float(mean.mean()) - 0.002),
    )
    return replace(out, **fields)


def training_report_doc(names: tuple[str, ...] = ("a", "b")) -> dict:
    """A stored task's training report in its stored JSON form (:meth:`TrainingReport.to_json`), 20 held-out
    simulations, calibrated; ``a`` informed (90% width 0.4 of the prior's), the others not."""
    d = len(names)
    return {"n_test": 20, "n_draws": 50, "parameters": list(names),
            "coverage": {"levels": [0.5, 0.9], "hpd": [0.5, 0.9], "band_lo": [0.3, 0.75], "band_hi": [0.7, 1.0],
                         "at_50": 0.5, "at_90": 0.9},
            "sbc": {"n_bins": 4, "histograms": [[5, 5, 5, 5]] * d, "band": [1.0, 9.0], "ks_pvalue": [0.5] * d,
                    "rejects": [False] * d},
            "tarp": {"levels": [0.5], "coverage": [0.5]}, "verdict": "calibrated", "calibrated": True,
            "contraction": {n: {"width_ratio": 0.4 if i == 0 else 0.95, "informed": i == 0}
                            for i, n in enumerate(names)}}


# -- a task's recordings (softsbi.core.results.joint): each recording's own diagnosis and a candidate's refit on it -

def wind_refit(value: float, test: JointTest | None = None, on: bool = True, wind_y: float = 0.8,
               se: float = 0.2, effect: str = "wind") -> Refit:
    """The wind's refit of one recording (``effect``'s, its parameter still ``wind_y``): summary energy score
    ``value``, adequate unless ``test`` says otherwise, its ``wind_y`` 90% interval excluding the off value 0 when
    ``on`` (``wind_y +- 0.3`` m/s, else ``+- 3 wind_y``)."""
    half = 0.3 if on else 3 * abs(wind_y) + 0.1
    est = Estimate(name="wind_y", unit="m/s", mean=wind_y, q05=wind_y - half, q95=wind_y + half, width_ratio=0.2,
                   effect=effect, may_be_off=not on)
    return Refit(effects=(effect,), run=f"r/refit-{effect}", test=test or joint(120, 150), score=score(value, se),
                 estimates=(est,), chamfer_n=30)


def recording(name: str, nominal: float, test: JointTest, refits: tuple[Refit, ...] = (), k_se: float = 2.0,
              se: float = 0.2) -> Diagnosis:
    """One recording's own diagnosis: its nominal fit's check ``test`` and score ``nominal``, its own ``refits``
    and the single diagnosis' decision on them (softsbi.workflows.criticism.decide)."""
    from softsbi.workflows.criticism.decide import decide
    nom = score(nominal, se)
    return Diagnosis(run=f"runs/{name}", candidates=("wind", "extra-damping"), alpha=0.05, k_se=k_se, test=test,
                     ranking=(candidate("wind", 0.5), candidate("extra-damping", 0.2)), nominal=nom, refits=refits,
                     decision=decide(test, nom, refits, k_se), confirm=1)
