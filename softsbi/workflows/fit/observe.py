"""What a fit sees: the observer's options, the observed state of a recording, the sensor model of the per-frame
metric (:func:`metric_sensor`, shared with ``check``, ``compare`` and ``diagnose``) and the context every simulation
job of a fit runs with.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from softsbi.core.errors import DataError
from softsbi.core.store import RunStore
from softsbi.core.types import ParamSpace, Recording, Scenario
from softsbi.perception.depth_sensor import VirtualDepthSensor
from softsbi.plugins import registry
from softsbi.scenarios.cameras import scenario_camera
from softsbi.scenarios.spec import declared_spool, scenario_source
from softsbi.workflows.fit.config import FitConfig, RunRecord, needs_images
from softsbi.workflows.fit.jobs import SimContext


def metric_sensor(cfg: FitConfig, scenario: Scenario) -> dict[str, Any]:
    """The fit's sensor model as the metric applies it (one definition of the per-frame
    distance for the fit's report, ``check``, ``compare`` and ``diagnose``).

    ``metric_min_z``: simulated and measured points at or below ``table_z + min_height`` (m) are not
    seen (:func:`~softsbi.perception.pointcloud.sensor_view`), None without a height cut;
    ``metric_frames``: the frames the headline Chamfer averages (the fit's ``frames``), None = all.
    ``metric_camera``: with ``cfg.sensor == "camera"`` the recording's virtual depth sensor (JSON,
    :meth:`~softsbi.perception.depth_sensor.VirtualDepthSensor.to_json`, every kept pixel once) that makes
    the simulated clouds, the measured ones used as recorded (``metric_min_z`` None); else None.
    ``cfg`` must be :meth:`FitConfig.resolved`. Image fits (mask Chamfer) get none of them.

    Raises:
        DataError: ``sensor="camera"`` for a recording that is not a calibrated DiffCloud folder.
    """
    if needs_images(cfg):
        return {"metric_min_z": None, "metric_frames": None, "metric_camera": None}
    min_z = float(scenario.table_z) + float(cfg.min_height) if cfg.min_height else None
    frames = None if cfg.frames is None else [int(i) for i in cfg.frames]
    camera = None
    if cfg.sensor == "camera":
        src = Path(scenario_source(scenario))
        if not ((src / "lift_real2sim.yaml").is_file() and (src.parent / "calib_overhead").is_dir()
                and (src.parent / "calib_side").is_dir()):
            raise DataError(f"sensor='camera' needs a DiffCloud recording folder (lift_real2sim.yaml, with "
                            f"calib_overhead/ and calib_side/ beside it), got scenario source '{src}'; use "
                            f"sensor='height' for other recordings")
        camera, min_z = VirtualDepthSensor.for_diffcloud_recording(src, n_points=0, scenario=scenario).to_json(), None
    return {"metric_min_z": min_z, "metric_frames": frames, "metric_camera": camera}


def observer_options(cfg: FitConfig, scenario: Scenario) -> dict[str, Any]:
    """Constructor options of the observer for this fit: K and the sensor's visibility for point
    clouds (with an occluding obstacle, the scenario camera's position as the viewpoint); extractor
    checkpoint and camera (the scenario's, :func:`~softsbi.scenarios.cameras.scenario_camera`) for image
    observers.

    Raises:
        DataError: the scenario declares no camera where one is needed."""
    if needs_images(cfg):
        opts = dict(cfg.observer_options)
        if "camera" not in opts:  # the scenario's own camera (its file's cameras:)
            opts["camera"] = scenario_camera(scenario, int(opts.get("size", 128))).to_json()
        if "extractor" in opts:
            opts["extractor"] = str(Path(opts["extractor"]).resolve())
        return opts
    opts = {"n_points": cfg.n_points}
    if cfg.sensor == "camera" and cfg.observer == "pointcloud":  # the virtual depth sensor replaces the height cut
        opts["camera"] = metric_sensor(cfg, scenario)["metric_camera"]
    elif cfg.min_height:
        opts["min_z"] = float(scenario.table_z) + float(cfg.min_height)
    spool = declared_spool(scenario)
    if spool and cfg.observer == "pointcloud":  # an occluding obstacle (the winding's spool) hides what is behind it
        opts["viewpoint"] = [float(v) for v in scenario_camera(scenario).position]  # as seen by its camera
        opts["occluder"] = {"centre": list(spool["centre"]), "radius": float(spool["radius"]),
                            "z0": float(scenario.table_z), "height": float(spool["height"])}
    opts.update(cfg.observer_options)
    return opts


def observe_recording(cfg: FitConfig, meas: Recording) -> np.ndarray:
    """The observed state ``(T, 1+K, 3)`` under the fit's observer settings.

    Raises:
        DataError: an image observer with a measurement that has no frames, or a point-cloud
            observer with one that has neither state nor clouds.
    """
    obs = registry().observer(cfg.observer)(**observer_options(cfg, meas.scenario))
    if getattr(obs, "needs_images", False):
        if meas.images is None:
            raise DataError(f"observer '{cfg.observer}' works on images but the measurement '{meas.source}' has "
                            f"no frames; pass a folder of frames (000.png ...) or use --observer pointcloud")
        return obs.observe_images(meas.images, meas.scenario.gripper, meas.scenario.times, meas.source).state()
    if meas.x is None and meas.dense is None:
        raise DataError(f"measurement '{meas.source}' has no point clouds; observer '{cfg.observer}' needs them "
                        f"(for a folder of frames use --observer heatmap or transporter)")
    if hasattr(obs, "observe_clouds") and meas.dense is not None:
        o = obs.observe_clouds(list(meas.dense), meas.scenario.gripper, meas.scenario.times,
                               np.random.default_rng([cfg.seed, 31337]), source=meas.source)
        return o.state()
    return np.asarray(meas.x, float)


def fit_sim_context(cfg: FitConfig, recording: Recording, store: RunStore, space: ParamSpace) -> SimContext:
    """What every simulation job of this fit needs: simulator, observer, the metric's reference."""
    observed = store.read_observed()
    dense, masks = (observed.get(k) for k in ("dense", "masks"))  # a point-cloud fit's clouds, an image fit's masks
    rec = RunRecord.from_run_config(store.config)
    return SimContext(backend=cfg.backend, backend_options=cfg.backend_options,
                      scenario=recording.scenario.to_json(), effects=list(cfg.effects), observer=cfg.observer,
                      observer_options=observer_options(cfg, recording.scenario), param_names=space.names,
                      fixed=dict(cfg.fixed), dense=dense, n_dense=cfg.n_dense,
                      ref_masks=masks if rec.image_fit else None,
                      min_z=rec.metric_min_z, camera=rec.metric_camera)
