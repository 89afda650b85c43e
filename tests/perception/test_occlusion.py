"""The winding scenario's spool hides part of the rope: the point-cloud observer leaves those points out."""
from __future__ import annotations

import numpy as np
import pytest

from softsbi.scenarios.builtin import make_scenario
from softsbi.workflows.fit.run import FitConfig, observer_options
from softsbi.perception.pointcloud import PointCloudObserver, occluded_by_cylinder

pytestmark = pytest.mark.integration


def test_cylinder_occlusion_geometry():
    cam = np.array([0.0, -0.8, 0.6])
    pts = np.array([[0, 0.05, 0.02],    # behind the spool: hidden
                    [0, -0.05, 0.02],   # in front of it
                    [0.1, 0.05, 0.02],  # beside it
                    [0, 0.05, 0.30],    # behind but above the line of sight over the top
                    [0, 0.0, 0.04]])    # inside the spool's axis: the segment enters the cylinder
    assert occluded_by_cylinder(pts, cam, (0, 0), 0.03, 0.0, 0.08).tolist() == [True, False, False, False, True]
    # the viewpoint straight above the spool sees the points around it and nothing below its top
    top = occluded_by_cylinder(np.array([[0.05, 0, 0.0], [0.0, 0.0, 0.0]]), (0, 0, 1.0), (0, 0), 0.03, 0.0, 0.08)
    assert top.tolist() == [False, True]


def test_winding_fit_observes_only_the_visible_rope():
    from softsbi.plugins import registry
    sc = make_scenario("winding")
    opts = observer_options(FitConfig(observer="pointcloud", n_points=32), sc)
    assert set(opts) >= {"viewpoint", "occluder"}
    assert "occluder" not in observer_options(FitConfig(observer="pointcloud"), make_scenario("fling"))
    sim = registry().simulator("mujoco-flex")()
    ro = sim.simulate(sc, sim.param_space(sc).midpoint())
    assert ro.ok
    obs = PointCloudObserver(**opts).observe(ro, np.random.default_rng(0))
    o = opts["occluder"]
    for t in (len(sc.times) // 2, len(sc.times) - 1):  # once the rope wraps round the spool
        hidden = occluded_by_cylinder(obs.points[t], opts["viewpoint"], o["centre"], o["radius"], o["z0"], o["height"])
        assert not hidden.any()
    # and some of the rope really is behind the spool at the end (the model is not vacuous)
    dense = PointCloudObserver(n_points=400).observe(ro, np.random.default_rng(1)).points[-1]
    assert occluded_by_cylinder(dense, opts["viewpoint"], o["centre"], o["radius"], o["z0"], o["height"]).mean() > 0.05
    with pytest.raises(ValueError, match="both"):
        PointCloudObserver(viewpoint=(0, 0, 1))
