"""``softsbi view RUN``: watch a finished fit's posterior-predictive rollouts against the measurement.

Two outputs from one set of simulations (:func:`posterior_rollouts`):

* :func:`write_animation` - an animated GIF (``RUN/view.gif``): the measured cloud (dark grey)
  against ``n_eval`` posterior-predictive rollouts (faded blue wireframes) and the gripper
  (red), in the scenario's view (``view:``) and the other one (side or top), with the per-frame Chamfer error of the
  rollouts below; one animation frame per recorded frame.
* :func:`write_rerun` - a `rerun <https://rerun.io>`_ recording (``RUN/view.rrd``) of the same
  scene in 3-D on a ``time`` timeline (seconds), to scrub through with ``rerun RUN/view.rrd``.

:func:`write_view` writes both. The rollouts are simulated at the first ``n_eval`` rows of
the run's posterior samples (the fit's evaluation samples) with the run's effects and the fit's
evaluation seeds, in worker processes (:func:`~softsbi.workflows.fit.jobs.simulate_job`). Their
Chamfer error per frame is measured from the mesh's vertices and face centroids to the measured
cloud (deterministic; ``softsbi check`` samples the surface like the fit, so its numbers can differ
by a few millimetres).

A fit's best fit (:mod:`~softsbi.workflows.fit.bestfit`; its rollout stored in the run) is drawn in both
outputs beside the posterior rollouts, in its own colour (purple), with its Chamfer per frame.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from softsbi.workflows.fit.bestfit import read_best_fit
from softsbi.workflows.fit.jobs import JobResult
from softsbi.workflows.fit.runs import RunView, load_run
from softsbi.workflows.lock import check_out_dir

from softsbi.core.errors import DependencyMissing, SoftsbiError
from softsbi.core.jsonfile import check_result_path
from softsbi.core.store import RunStore
from softsbi.core.defaults import VIEW_N_EVAL

from softsbi.report.animation import draw_gif, import_rerun, log_rrd




# ----------------------------------------------------------------------------------------
# simulation shared by both outputs


def writable_target(path: Path, run_dir: str | Path) -> Path:
    """Check, before simulating, that the output file ``path`` can be written: no folder in its place
    (:func:`~softsbi.core.jsonfile.check_result_path`) and a folder that takes a new file
    (:func:`~softsbi.workflows.lock.check_out_dir`; a read-only run directory, ``run_dir``, is told to be copied).

    Raises:
        ResultUnwritable: a folder stands at ``path``. RunDirError: its folder cannot be written (one line with the
            fix).
    """
    path = check_result_path(path)
    if path.parent.resolve() == Path(run_dir).resolve():
        check_out_dir(path.parent, "run directory", f"view writes {path.name} into it: copy the run directory to a "
                                                    f"writable place and view the copy")
    else:
        check_out_dir(path.parent, "folder", f"give a writable path for {path.name}")
    return path


def best_fit_rollout(run_dir: str | Path) -> dict[str, Any] | None:
    """The fit's stored best fit (:func:`~softsbi.workflows.fit.bestfit.read_best_fit`) as the animation draws it:
    ``{"vertices", "faces", "chamfer" (T,) m, "label"}``; None when the run stored no best-fit rollout."""
    b = read_best_fit(RunStore.open(Path(run_dir) / "run.zarr"))
    if b is None or b.vertices is None:
        return None
    unit = "cm" if b.unit == "m" else b.unit
    value = b.value * 100 if b.unit == "m" else b.value
    return {"vertices": np.asarray(b.vertices, float), "faces": np.asarray(b.faces, int),
            "chamfer": np.asarray(b.per_frame, float), "label": f"best fit ({b.source}, {value:.2f} {unit})"}


def posterior_rollouts(run_dir: str | Path, n_eval: int = VIEW_N_EVAL,
                       workers: int | None = None) -> tuple[RunView, list[JobResult], np.ndarray]:
    """Simulate a finished run at its first ``n_eval`` posterior samples.

    Args:
        run_dir: a finished point-cloud fit (``run.zarr`` + ``report.json``).
        n_eval: posterior samples to simulate (rows ``0 .. n_eval-1`` of the run's
            posterior samples; fewer if the run stored fewer).
        workers: simulation processes (None = one per core).

    Returns:
        ``(view, rollouts, chamfer)``: the opened run (:class:`~softsbi.workflows.fit.runs.RunView`;
        ``view.dense (T, P, 3)`` m is the measurement), the ``S`` successful rollouts (job results,
        :class:`~softsbi.workflows.fit.jobs.JobResult`, with
        ``vertices (T, N, 3)`` m, ``faces (F, 3)`` int (``F = 0`` for a rope), ``gripper (T, 3)`` m,
        ``sample`` = the posterior row simulated, ``seed``), and their bidirectional Chamfer
        distance to the measured cloud per frame ``(S, T)`` in metres: the fit's own metric
        (:func:`~softsbi.workflows.fit.run.simulate_job`), so the mean matches ``softsbi check``.

    Raises:
        SoftsbiError: ``n_eval < 1``; not a finished point-cloud fit (see
            :func:`~softsbi.workflows.fit.runs.load_run`; SchemaError for a folder that is no run);
            every rollout failed.
    """
    if int(n_eval) < 1:
        raise SoftsbiError(f"n_eval must be at least 1 (got {n_eval})")
    view = load_run(run_dir, n_eval=int(n_eval))
    # the fit's own job, evaluation samples and seeds: the rollouts are the fit's posterior-predictive
    # rollouts and their Chamfer is the fit's metric (as in `softsbi check` and report.json)
    rollouts, res = view.posterior_rollouts(workers)
    rollouts = [replace(r, faces=np.asarray(r.faces if r.faces is not None else np.zeros((0, 3)), int))
                for r in rollouts]
    if not rollouts:
        reasons = sorted({str(r.reason) for r in res if r is not None})
        raise SoftsbiError(f"all {len(res)} posterior rollouts of '{run_dir}' failed ({'; '.join(reasons)}); "
                           f"nothing to show")
    ch = np.array([r.chamfer for r in rollouts], dtype=float)
    return view, rollouts, ch




def write_animation(run_dir: str | Path, path: str | Path | None = None, n_eval: int = VIEW_N_EVAL,
                    workers: int | None = None, fps: float = 5) -> Path:
    """Write an animated GIF of a finished fit's posterior-predictive rollouts against the measurement.

    One animation frame per recorded frame (``T`` frames): the scenario's view (``view:``, a side view or the top
    view) and the other (:func:`~softsbi.report.style.view_planes`)
    of the measured cloud (dark grey), ``n_eval`` posterior rollouts (faded blue mesh edges)
    and the gripper (red ``+``, its path faint), at fixed equal-aspect limits (m) covering
    every frame; below, the Chamfer distance (cm) of each rollout and their mean per frame with
    a marker at the current frame; the title names the run, ``frame k (of 0-T-1)`` (numbered from 0, as in
    every figure), ``t`` (s) and the
    current mean Chamfer.

    Args:
        run_dir: a finished point-cloud fit (``run.zarr`` + ``report.json``).
        path: where to write (default ``RUN/view.gif``).
        n_eval: posterior samples simulated (see :func:`posterior_rollouts`).
        workers: simulation processes (None = one per core).
        fps: animation frames per second.

    Returns:
        The GIF's path.

    Raises:
        ResultUnwritable: a folder stands at the GIF's path; RunDirError: its folder cannot be written (both before
            simulating).
        SoftsbiError: see :func:`posterior_rollouts`.
    """
    path = writable_target(Path(path) if path else Path(run_dir) / "view.gif", run_dir)
    view, rollouts, ch = posterior_rollouts(run_dir, n_eval, workers)
    return draw_gif(view, rollouts, ch, path, fps, best=best_fit_rollout(run_dir))


# ----------------------------------------------------------------------------------------
# rerun recording


def write_rerun(run_dir: str | Path, path: str | Path | None = None, n_eval: int = VIEW_N_EVAL,
                workers: int | None = None) -> Path:
    """Write a rerun recording (``.rrd``) of a finished fit's posterior-predictive rollouts.

    Timeline ``time`` (s, the recorded frame times). Entities (metres, z up):
    ``world/measured`` (Points3D, the measured cloud per frame), ``world/posterior/<i>`` (Mesh3D
    per frame from the rollout's vertices and faces; LineStrips3D for a rope without faces),
    ``world/gripper`` (Points3D, the gripper per frame), ``world/gripper_path`` (static
    LineStrips3D), ``world/table`` (static Boxes3D outline at the table height),
    ``error/chamfer_cm`` (Scalars: mean Chamfer of the rollouts per frame, cm) and
    ``error/rollouts/<i>`` (Scalars: each rollout's Chamfer, cm). A default blueprint shows the
    3-D scene above the error plot. Open it with ``rerun RUN/view.rrd``.

    Args:
        run_dir: a finished point-cloud fit (``run.zarr`` + ``report.json``).
        path: where to write (default ``RUN/view.rrd``).
        n_eval: posterior samples simulated (see :func:`posterior_rollouts`).
        workers: simulation processes (None = one per core).

    Returns:
        The recording's path.

    Raises:
        DependencyMissing: rerun-sdk is not installed (checked before simulating; the message
            names ``pip install "softsbi[view]"``).
        ResultUnwritable: a folder stands at the recording's path; RunDirError: its folder cannot be written (both
            before simulating).
        SoftsbiError: see :func:`posterior_rollouts`.
    """
    rr = import_rerun()
    path = writable_target(Path(path) if path else Path(run_dir) / "view.rrd", run_dir)
    view, rollouts, ch = posterior_rollouts(run_dir, n_eval, workers)
    return log_rrd(rr, view, rollouts, ch, path, best=best_fit_rollout(run_dir))


# ----------------------------------------------------------------------------------------
# both


def write_view(run_dir: str | Path, n_eval: int = VIEW_N_EVAL, workers: int | None = None, gif: bool = True,
               rrd: bool | None = None, fps: float = 5) -> dict[str, Any]:
    """Simulate once and write ``RUN/view.gif`` and/or ``RUN/view.rrd`` (see :func:`write_animation`,
    :func:`write_rerun`).

    Args:
        rrd: write the rerun recording: True (rerun-sdk needed), False, or None (the default) when rerun-sdk is
            installed; without it ``rrd_missing`` says what it needs.

    Returns:
        dict with ``gif`` and ``rrd`` (Path, or None when not written), ``rrd_missing`` (why the ``.rrd`` was not
        written with ``rrd=None``, else None), ``times_s`` ``(T,)``,
        ``chamfer_per_frame_m`` ``(T,)`` (mean over the rollouts, metres; the fit's sensor model),
        ``chamfer_mean_m`` (over the fit's frames, as ``report.json``'s headline),
        ``n_rollouts`` (successful) and ``failed_rollouts``.

    Raises:
        DependencyMissing: ``rrd`` asked for and rerun-sdk not installed (before simulating).
        ResultUnwritable: a folder stands at ``view.gif`` or ``view.rrd``; RunDirError: the run directory cannot be
            written, e.g. read-only (both before simulating).
        SoftsbiError: nothing to write (``gif`` False and no rerun recording; before simulating); see
            :func:`posterior_rollouts`.
    """
    out: dict[str, Any] = {"gif": None, "rrd": None, "rrd_missing": None}
    rr = None
    if rrd or rrd is None:
        try:
            rr = import_rerun()
        except DependencyMissing as exc:
            if rrd:
                raise
            out["rrd_missing"] = str(exc)
    if not gif and rr is None:  # before simulating: nothing would be written
        raise SoftsbiError("--no-gif leaves nothing to write: " + (
            "--no-rrd switches off the rerun recording too; drop one of them" if rrd is False else
            f"the rerun recording is not written ({out['rrd_missing']}); drop --no-gif or install the extra"))
    run_dir = Path(run_dir)
    for name, wanted in (("view.gif", gif), ("view.rrd", rr is not None)):
        if wanted:  # a folder in a file's place, a read-only run: refused before simulating
            writable_target(run_dir / name, run_dir)
    view, rollouts, ch = posterior_rollouts(run_dir, n_eval, workers)
    best = best_fit_rollout(run_dir)
    if gif:
        out["gif"] = draw_gif(view, rollouts, ch, run_dir / "view.gif", fps, best=best)
    if rr is not None:
        out["rrd"] = log_rrd(rr, view, rollouts, ch, run_dir / "view.rrd", best=best)
    mean = ch.mean(0)
    frames = view.metric_frames  # the fit's headline averages its own frames (report.json, check)
    out.update({"times_s": view.scenario.times.tolist(), "chamfer_per_frame_m": mean.tolist(),
                "chamfer_mean_m": float(mean[frames].mean() if frames else mean.mean()), "n_rollouts": len(rollouts),
                "failed_rollouts": len(view.post_theta) - len(rollouts)})
    return out
