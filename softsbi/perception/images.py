"""Image observers: rendered (or recorded) RGB frames -> keypoints from a trained extractor.

The paper's input (Antonova et al. 2022, Sec. V) is RGB video: keypoints are extracted from every
frame by a supervised heatmap model or an unsupervised Transporter and treated as an unordered set
per frame. Here the observers ``heatmap`` and ``transporter`` wrap a trained
:class:`~softsbi.core.interfaces.KeypointExtractor` checkpoint; the fit loop sees that they need
images (``needs_images``) and asks the backend for rendered rollouts
(:meth:`~softsbi.core.interfaces.Simulator.simulate_images`) through the observer's camera.

The observed state of a frame is ``[gripper (m), (u/W, v/H, 0) for each keypoint]``
(:meth:`softsbi.core.types.Observation.state`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar, Mapping

import numpy as np

from softsbi.core.camera import Camera, RenderStyle
from softsbi.scenarios.cameras import scenario_camera
from softsbi.core.errors import DataError, ShapeError, SoftsbiError
from softsbi.core.interfaces import Observer
from softsbi.core.types import Observation, Rollout
from softsbi.plugins.hookspecs import hookimpl
from softsbi.data.frames import load_frames, save_frames
from softsbi.data.keypoints import check_images
from softsbi.plugins import registry
from softsbi.scenarios.catalog import load_scenario

__all__ = ["HeatmapObserver", "ImageKeypointObserver", "TransporterObserver", "check_images", "load_frames",
           "save_frames"]

class ImageKeypointObserver(Observer):
    """Keypoints found by a trained extractor in rendered frames (base of ``heatmap`` / ``transporter``).

    Args:
        extractor: path of the extractor checkpoint (``.pt`` written by its ``save`` or by
            ``softsbi train-extractor``).
        size: square image size (px) of the scenario's camera, used when ``camera`` is None.
        camera: a :class:`~softsbi.core.camera.Camera` as JSON (``Camera.to_json()``; ``softsbi fit`` passes
            its scenario's); None = the camera of the scenario named ``scenario``
            (:func:`~softsbi.scenarios.cameras.scenario_camera`).
        scenario: a scenario name or file (:func:`~softsbi.scenarios.load_scenario`), read when
            ``camera`` is None (runs stored before the fit passed the camera name their scenario).
        style: :class:`~softsbi.core.camera.RenderStyle` as JSON (colours of the rendered scene).

    Raises:
        SoftsbiError: no checkpoint given. DataError: unreadable checkpoint (from the extractor's
        ``load``).
    """

    name: ClassVar[str] = "image-keypoints"
    needs_images: ClassVar[bool] = True
    #: extractor plugin that reads the checkpoint
    extractor_kind: ClassVar[str] = ""

    def __init__(self, extractor: str | Path | None = None, size: int = 128,
                 camera: Mapping[str, Any] | None = None, scenario: str = "wipe",
                 style: Mapping[str, Any] | None = None):
        if not extractor:
            raise SoftsbiError(f"observer '{self.name}' needs a trained extractor checkpoint: pass --extractor "
                               f"PATH.pt (train one with `softsbi train-extractor {self.extractor_kind} ...`)")
        if not Path(extractor).is_file():
            raise DataError(f"extractor checkpoint '{extractor}' does not exist; train one with "
                            f"`softsbi train-extractor {self.extractor_kind} --out {extractor}`")
        self.extractor_path = str(extractor)
        self.extractor = registry().extractor(self.extractor_kind).load(extractor)
        if camera:
            self.camera = Camera.from_json(camera)
        else:
            self.camera = scenario_camera(load_scenario(scenario), int(size))
        self.style = RenderStyle.from_json(style)

    @property
    def n_keypoints(self) -> int:
        return int(self.extractor.n_keypoints)

    def observe_images(self, images: np.ndarray, gripper: np.ndarray, times: np.ndarray,
                       source: str = "") -> Observation:
        """Keypoints of recorded or rendered frames.

        Args:
            images: ``(T, H, W, 3)`` uint8 RGB, ``H, W`` = the camera's size.
            gripper: ``(T, 3)`` m. times: ``(T,)`` s.

        Returns:
            :class:`Observation` with ``points (T, K, 2)`` px and ``image_size = (W, H)``.

        Raises:
            ShapeError: bad images, or a size other than the camera's.
        """
        images = check_images(images)
        H, W = images.shape[1:3]
        if (W, H) != (self.camera.width, self.camera.height):
            raise ShapeError(f"frames are {W}x{H} px but the observer's camera is {self.camera.width}x"
                             f"{self.camera.height}; render or resize the frames to the camera size")
        if len(images) != len(gripper):
            raise ShapeError(f"{len(images)} frames but {len(gripper)} gripper poses; every frame needs one")
        kp = np.asarray(self.extractor.predict(images), float)
        return Observation(points=kp, gripper=np.asarray(gripper, float), times=np.asarray(times, float),
                           source=source, image_size=(W, H))

    def observe(self, rollout: Rollout, rng: np.random.Generator) -> Observation:
        if rollout.rgb is None:
            raise ShapeError(f"observer '{self.name}' needs rendered frames (rollout.rgb); simulate with "
                             f"Simulator.simulate_images(..., camera=observer.camera)")
        return self.observe_images(rollout.rgb, rollout.gripper, rollout.times, source="simulated")


class HeatmapObserver(ImageKeypointObserver):
    """Keypoints of the supervised ``heatmap`` extractor (Grannen et al. 2020) in rendered frames."""

    name: ClassVar[str] = "heatmap"
    extractor_kind: ClassVar[str] = "heatmap"


class TransporterObserver(ImageKeypointObserver):
    """Keypoints of the unsupervised ``transporter`` extractor (Kulkarni et al. 2019) in rendered frames."""

    name: ClassVar[str] = "transporter"
    extractor_kind: ClassVar[str] = "transporter"


@hookimpl
def softsbi_observers():
    return [HeatmapObserver, TransporterObserver]
