"""The local thickness as check's and diagnose's fourteenth summary per frame (issue 19: point noise on a
moving cloth that the 13 position summaries do not see)."""
import numpy as np
import pytest

from softsbi.workflows.criticism.statistics import (
    FEATURE_FLOOR,
    FEATURE_NAMES,
    THICKNESS_FLOOR,
    cloud_features,
    misspecification_test,
    summary_floor,
    trajectory_features,
)


def _wavy_sheet(rng, n=600, amp=0.01, phase=0.0):
    """A 30 x 30 cm sheet hanging in the x-z plane with a gentle fold (m), ``n`` random surface points."""
    u, v = rng.random(n) * 0.3, rng.random(n) * 0.3
    return np.c_[u, amp * np.sin(2 * np.pi * u / 0.3 + phase), 0.1 + v]


def _trajectory(rng, noise=0.0, frames=6):
    clouds = [_wavy_sheet(rng, phase=0.3 * t) for t in range(frames)]
    return [c + rng.normal(0.0, noise, c.shape) for c in clouds]


def test_the_fourteenth_summary_is_the_local_thickness_and_sees_noise():
    rng = np.random.default_rng(0)
    sheet = _wavy_sheet(rng)
    f0 = cloud_features(sheet)
    f1 = cloud_features(sheet + rng.normal(0.0, 0.005, sheet.shape))
    assert len(FEATURE_NAMES) == len(f0) == 14 and FEATURE_NAMES[-1] == "thickness"
    assert f0[-1] < 1e-3 and f1[-1] > 2e-3  # 5 mm of noise: the thickness rises by millimetres
    # in units of their floors (what the tests weigh), the position summaries move about 20 times less
    assert (f1[-1] - f0[-1]) / THICKNESS_FLOOR > 20 * np.abs(f1[:-1] - f0[:-1]).max() / FEATURE_FLOOR
    assert cloud_features(sheet[:2])[-1] == 0.0  # too few points for a local plane: 0, not an error


def test_summary_floor_is_per_summary_for_the_trajectory_layout():
    fl = summary_floor(3 * len(FEATURE_NAMES))
    assert fl.shape == (42,) and fl[13] == fl[27] == fl[41] == THICKNESS_FLOOR and fl[0] == fl[12] == FEATURE_FLOOR
    assert summary_floor(5) == FEATURE_FLOOR  # another layout: the scalar floor


@pytest.mark.parametrize("noise, rejects", [(0.0, False), (0.004, True)])
def test_the_omnibus_test_rejects_noise_only_through_the_thickness(noise, rejects):
    """Thirty noise-free rollouts as the null; a measurement with 4 mm of noise per axis is beyond all of them
    with the thickness and inside them without it; a noise-free measurement is inside either way."""
    rng = np.random.default_rng(1)
    sims = np.array([trajectory_features(_trajectory(rng)) for _ in range(30)])
    obs = trajectory_features(_trajectory(rng, noise))
    _, with_thickness = misspecification_test(obs, sims)
    k = len(FEATURE_NAMES)
    positions = np.ones(sims.shape[1], bool)
    positions[k - 1::k] = False
    _, without = misspecification_test(obs[positions], sims[:, positions])
    assert (with_thickness.value <= 1 / 31) == rejects
    assert without.value > 0.1
