"""Hand-built typed results (softsbi.core.results) for tests that need a check, a diagnosis or a comparison
without simulating one: fixed numbers, so rendered sentences and figures are reproducible."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from softsbi.core.results import Band, Candidate, CheckResult, EnergyScore, JointTest, MCPValue, Phase, Refit, Score

#: region names as check_run writes them (R1 nearest the first handle's grasp)
REGIONS = tuple(f"R{r + 1}" + (" (at the grasp)" if r == 0 else " (farthest from the grasp)" if r == 8 else "")
                for r in range(9))


def joint(omnibus: int = 0, directional: int | None = 0, n: int = 200, alpha: float = 0.05,
          family: tuple[str, ...] = ("wind", "extra-damping"), effect: str = "wind") -> JointTest:
    """A joint test from the exceedance counts of its omnibus and directional test among ``n`` nulls (``directional``
    None: the omnibus test alone)."""
    return JointTest(MCPValue(omnibus, n), None if directional is None else MCPValue(directional, n),
                     None if directional is None else effect, family, alpha, 200, 3.2)


def score(value: float, se: float = 0.4, n: int = 30) -> Score:
    """An energy score of the summaries (dimensionless), the score a diagnosis decides on."""
    return Score(value, se, n)


def energy(energy_m: float, se_m: float = 0.0004, spread_m: float = 0.004, n: int = 30) -> EnergyScore:
    """An energy score of the clouds with its terms consistent: ``chamfer = energy + spread / 2``."""
    return EnergyScore(energy_m, se_m, energy_m + spread_m / 2, spread_m, n)


def candidate(effect: str, explained: float = 0.3, exceed: int = 0, kind: str = "physics", generic: bool = False,
              description: str = "", n: int = 200, **estimate: float) -> Candidate:
    return Candidate(effect, kind, generic, description, explained, MCPValue(exceed, n), estimate)


def refit(effects: tuple[str, ...], value: float, test: JointTest, **fields) -> Refit:
    """A refit whose score of the summaries is ``value`` (its posterior-predictive Chamfer ``value / 1000 + 0.002`` m,
    over 30 rollouts)."""
    fields.setdefault("chamfer_n", 30)
    return Refit(effects, f"run/refit-{'+'.join(effects)}", test, score(value), value / 1000 + 0.002, **fields)


def check_result(T: int = 25, long: bool = False, test: JointTest | None = None, **fields) -> CheckResult:
    """A check of a 25-frame lift whose error grows with time (worst late, in the farthest region)."""
    t = np.linspace(0, 0.96, T)
    mean = 0.01 + 0.15 * t ** 2
    cuts = np.linspace(0, T, 4).round().astype(int)
    phases = tuple(Phase(p, (int(cuts[k]), int(cuts[k + 1] - 1)), (float(t[cuts[k]]), float(t[cuts[k + 1] - 1])),
                         float(mean[cuts[k]:cuts[k + 1]].mean()), float(0.8 * mean[cuts[k]:cuts[k + 1]].mean()),
                         True, REGIONS[8]) for k, p in enumerate(["early", "middle", "late"]))
    run = "/very/long/path/to/a/run/directory/" + ("with_a_really_long_name_" * 6 if long else "run")
    region = mean[:, None] * np.linspace(0.5, 1.5, 9)
    band = Band(tuple(mean.tolist()), tuple((0.8 * mean).tolist()), tuple((1.2 * mean).tolist()))
    out = CheckResult(run, 30, 0, tuple(t.tolist()), band, band, float(mean.mean()), float(0.8 * mean.mean()), None,
                      None, "none", 0.0, REGIONS, tuple(map(tuple, region.tolist())),
                      tuple(tuple([True] * 9) for _ in range(T)), dict(zip(REGIONS, region.mean(0).tolist())),
                      phases, (T - 1, T - 2, T - 3), (REGIONS[8], REGIONS[7]), test or joint(), (),
                      energy(float(mean.mean()) - 0.002))
    return replace(out, **fields)
