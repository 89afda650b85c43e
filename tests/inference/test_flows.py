"""The ``flow`` estimator (zuko normalising flow): posterior accuracy on a Gaussian with a known
posterior, shapes, persistence, options and its missing dependency (its use in ``softsbi fit``:
tests/workflows/test_flow_fit.py)."""
from __future__ import annotations

import sys

import numpy as np
import pytest

pytest.importorskip("zuko")

from softsbi.core.errors import DependencyMissing, ParameterError, ShapeError
from softsbi.inference.flows import FlowEstimator, FlowPosterior

SIGMA = 0.05  # observation noise of the toy simulator x = theta + N(0, SIGMA^2 I)
FAST = {"transforms": 2, "hidden": (32, 32), "patience": 10, "max_epochs": 200, "lr": 2e-3,
        "batch_size": 100}


def _gaussian_sims(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    return u, u + SIGMA * rng.standard_normal((n, 2))


@pytest.fixture(scope="module")
def fitted() -> FlowEstimator:
    u, x = _gaussian_sims(2000)
    est = FlowEstimator(**FAST)
    est.fit(u, x, seed=0)
    return est


def test_known_gaussian_posterior(fitted: FlowEstimator) -> None:
    # flat prior, x_o far from the box edges: the posterior is N(x_o, SIGMA^2 I)
    x_o = np.array([0.4, 0.6])
    q = fitted.posterior_at(x_o)
    assert isinstance(q, FlowPosterior) and q.dim == 2
    s = q.sample(4000, np.random.default_rng(1))
    assert s.shape == (4000, 2)
    np.testing.assert_allclose(s.mean(0), x_o, atol=0.2 * SIGMA)
    np.testing.assert_allclose(s.std(0), [SIGMA, SIGMA], rtol=0.25)
    assert abs(np.corrcoef(s.T)[0, 1]) < 0.15
    # log_prob is a normalised density: its mean over the draws is minus the entropy of N(x_o, SIGMA^2 I)
    lp = q.log_prob(s)
    assert lp.shape == (4000,) and np.isfinite(lp).all()
    neg_entropy = -(1 + np.log(2 * np.pi * SIGMA**2))
    assert abs(lp.mean() - neg_entropy) < 0.3
    # and it is highest near x_o
    assert q.log_prob(x_o[None])[0] > q.log_prob(np.array([[0.4 + 3 * SIGMA, 0.6]]))[0] + 2.0


def test_sampling_is_seeded(fitted: FlowEstimator) -> None:
    q = fitted.posterior_at(np.array([[0.5, 0.5]]))  # a leading 1 is accepted
    a = q.sample(50, np.random.default_rng(3))
    b = q.sample(50, np.random.default_rng(3))
    c = q.sample(50, np.random.default_rng(4))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


@pytest.mark.parametrize("kind", ["nsf", "maf"])
def test_the_flow_at_an_observation_is_the_conditional_flow(kind: str) -> None:
    """FlowNetwork.at folds the context into the conditioners' biases: the same density as the network's own
    conditional flow, and the network is left as it was."""
    import torch

    from softsbi.inference.flows import FlowNetwork

    torch.manual_seed(0)
    net = FlowNetwork(40, 3, kind, transforms=2, hidden=(16, 16), bins=4, embedding=(8,))
    z = torch.randn(1, 40)
    u = torch.randn(50, 3)
    with torch.no_grad():
        before = net.log_prob(u, z.expand(50, -1))
        flow = net.at(z)
        torch.testing.assert_close(flow.log_prob(u), before, rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(net.log_prob(u, z.expand(50, -1)), before)
        s = flow.sample((7,))
        assert s.shape == (7, 3) and torch.isfinite(s).all()


def test_state_dict_round_trip(fitted: FlowEstimator) -> None:
    state = fitted.state_dict()
    other = FlowEstimator()
    other.load_state_dict(state)
    assert other.config["transforms"] == 2
    x_o = np.array([0.3, 0.7])
    u = np.random.default_rng(5).random((20, 2))
    np.testing.assert_allclose(other.posterior_at(x_o).log_prob(u), fitted.posterior_at(x_o).log_prob(u), rtol=1e-6)
    np.testing.assert_array_equal(other.posterior_at(x_o).sample(10, np.random.default_rng(0)),
                                  fitted.posterior_at(x_o).sample(10, np.random.default_rng(0)))
    with pytest.raises(Exception, match="not a 'flow' estimator state"):
        other.load_state_dict({"format": "softsbi.neural-mdn/1", "estimator": "mdnn"})


def test_states_input_and_shape_errors() -> None:
    rng = np.random.default_rng(0)
    u = rng.random((40, 2))
    x = rng.normal(size=(40, 5, 4, 3))  # (N, T, 1+K, 3) states: BayesSim summaries as for mdnn
    est = FlowEstimator(transforms=1, hidden=(8,), max_epochs=2)
    info = est.fit(u, x, seed=0)
    assert info["epochs"] >= 1 and info["n_train"] + info["n_val"] == 40
    assert est.posterior_at(x[0]).sample(3, rng).shape == (3, 2)
    with pytest.raises(ShapeError, match=r"x_obs must have shape \(5, 4, 3\)"):
        est.posterior_at(x[0, :3])
    with pytest.raises(ShapeError, match=r"\(N, T, 1\+K, 3\).*or \(N, F\)"):
        FlowEstimator().fit(u, np.zeros((40, 2, 2)))
    with pytest.raises(RuntimeError, match="not fitted"):
        FlowEstimator().posterior_at(x[0])


def test_options_and_missing_dependency(monkeypatch) -> None:
    with pytest.raises(ParameterError, match="unknown option 'transform'"):
        FlowEstimator(transform=3)
    with pytest.raises(ParameterError, match="flow must be one of"):
        FlowEstimator(flow="realnvp")
    monkeypatch.setitem(sys.modules, "zuko", None)  # import zuko now raises ImportError
    with pytest.raises(DependencyMissing, match=r'pip install "softsbi\[flows\]"') as info:
        FlowEstimator()
    assert "\n" not in str(info.value)


def test_registered_as_plugin() -> None:
    from softsbi.plugins.manager import registry

    assert registry().estimator("flow") is FlowEstimator
