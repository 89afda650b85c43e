"""A scenario's camera: the first of the cameras its file declares (``cameras:``, :class:`~softsbi.scenarios.spec.CameraSpec`)."""
from __future__ import annotations

from typing import Any, Mapping

from softsbi.core.camera import Camera
from softsbi.core.errors import DataError
from softsbi.core.types import Scenario


def camera_from_dict(c: Mapping[str, Any], size: int | None = None) -> Camera:
    """The :class:`Camera` of one entry of :attr:`Scenario.cameras`.

    Args:
        c: look-at (``eye``, ``target``, ``up``, ``fovy_deg``) or calibrated (``intrinsics`` ``{fx, fy, cx, cy}``
            px, ``world_to_cam`` 3x4), with ``width``, ``height`` px (default 128).
        size: None: the declared image size; else a look-at camera renders ``size x size`` px and a calibrated
            one is rescaled to ``size`` px wide, keeping its aspect ratio.

    Raises:
        DataError: neither kind of camera, or an invalid one (e.g. ``eye == target``).
    """
    w, h = int(c.get("width", 128)), int(c.get("height", 128))
    if "intrinsics" in c and "world_to_cam" in c:
        k = c["intrinsics"]
        cam = Camera(w, h, float(k["fx"]), float(k["fy"]), float(k["cx"]), float(k["cy"]),
                     tuple(tuple(float(v) for v in r) for r in c["world_to_cam"]))
        return cam if size is None else cam.resized(int(size), max(8, round(int(size) * h / w)))
    if "eye" in c and "target" in c:
        return Camera.look_at(width=int(size or w), height=int(size or h), eye=tuple(c["eye"]), target=tuple(c["target"]),
                              up=tuple(c.get("up", (0, 0, 1))), fovy_deg=float(c.get("fovy_deg", 50.0)))
    raise DataError(f"camera {c.get('name', '')!r} has neither eye and target (look-at) nor intrinsics and world_to_cam "
                    f"(calibrated); give one of them")


def scenario_camera(scenario: Scenario, size: int | None = 128) -> Camera:
    """The scenario's camera: the first of :attr:`Scenario.cameras` (:func:`camera_from_dict`; ``size`` px,
    None = the declared size). It renders the scenario's images and is the viewpoint the point-cloud
    observer hides occluded points from.

    Raises:
        DataError: the scenario declares no camera.
    """
    if not scenario.cameras:
        raise DataError(f"scenario '{scenario.name}' declares no camera; add one under 'cameras:' in its scenario "
                        f"file (eye, target, up, fovy_deg; or intrinsics and world_to_cam) or pass a camera")
    return camera_from_dict(scenario.cameras[0], size)
