"""The built-in cameras of the built-in scenarios (scenario facts, not kernel facts)."""
from __future__ import annotations

from softsbi.core.camera import Camera
from softsbi.core.errors import DataError


def default_camera(scenario_name: str, size: int = 128) -> Camera:
    """The built-in camera of a scenario: overhead, looking straight down at its workspace (like the
    paper's wiping images), ``size x size`` px.

    Raises:
        DataError: a scenario without a built-in camera.
    """
    views = {
        # wipe: the grasped corner starts at the origin and the cloth (side <= 0.34 m) trails along -x;
        # the stroke goes +0.30 m in x then +0.15 m in y: workspace x in [-0.48, 0.32], y in [-0.24, 0.39];
        # fovy 52 deg shows x in [-0.57, 0.41], so the gripper and the arm stay in view
        "wipe": dict(eye=(-0.08, 0.075, 1.0), target=(-0.08, 0.075, 0.0), up=(1, 0, 0), fovy_deg=52.0),
        "fling": dict(eye=(0.0, -0.9, 0.75), target=(0.0, 0.0, 0.2), up=(0, 0, 1), fovy_deg=55.0),
        "lift": dict(eye=(0.0, 0.0, 1.2), target=(0.0, 0.0, 0.1), up=(1, 0, 0), fovy_deg=50.0),
        "winding": dict(eye=(0.0, -0.8, 0.6), target=(0.0, 0.0, 0.15), up=(0, 0, 1), fovy_deg=50.0),
    }
    views["wind"] = views["winding"]  # the winding's name before it was renamed (runs stored then keep it)
    if scenario_name not in views:
        raise DataError(f"no built-in camera for scenario '{scenario_name}'; choose one of {sorted(views)} "
                        f"or pass a Camera")
    return Camera.look_at(width=size, height=size, **views[scenario_name])


def scenario_camera(scenario, size: int = 128) -> Camera:
    """The first camera of ``scenario.cameras`` (a scenario file's ``cameras``) at ``size x size`` px, else
    :func:`default_camera` of its name.

    Raises:
        DataError: no camera in the scenario and no built-in one for its name.
    """
    cams = getattr(scenario, "cameras", None) or []
    if cams:
        c = cams[0]
        return Camera.look_at(width=size, height=size, eye=tuple(c["eye"]), target=tuple(c["target"]),
                              up=tuple(c.get("up", (0, 0, 1))), fovy_deg=float(c.get("fovy_deg", 50.0)))
    return default_camera(scenario.name, size)
