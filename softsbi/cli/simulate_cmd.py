"""``softsbi simulate`` (one rollout, optionally rendered, as a recording) and ``softsbi compare-backends`` (one
scenario on two engines)."""
from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Any, Optional

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import H_BACKEND, H_JSON, IMAGE_SIZE_OK, bound, names, parse_kv
from softsbi.cli.output import Output
from softsbi.core.errors import SoftsbiError
from softsbi.core import defaults as D


class Match(str, Enum):
    """Choices of ``compare-backends --match``."""
    physical = "physical"
    unit = "unit"


def simulate(backend: str = typer.Option(D.BACKEND, help=H_BACKEND),
             scenario: str = typer.Option(D.SCENARIO, help="scenario name (`softsbi scenarios` lists them) or scenario "
                                                       "file (.yaml)"),
             recording: Optional[Path] = typer.Option(None, help="real recording folder to take the scenario from"),
             theta: list[str] = typer.Option(None, "--theta", help="name=value (repeatable); unset: scale = the scenario's object "
                                                             "size, others = prior midpoint"),
             effect: list[str] = typer.Option(None, "--effect", help="effect names to switch on"),
             backend_opt: list[str] = typer.Option(None, "--backend-opt", help="backend option name=value"),
             out: Path = typer.Option(Path("rollout"), help="output folder: rollout.zarr, preview.png and a "
                                                            "recording (recording.yaml + clouds/) that `softsbi fit "
                                                            "--observed OUT` reads"),
             render: Optional[int] = typer.Option(None, callback=IMAGE_SIZE_OK, help="also render every frame through the scenario's "
                                                             "overhead camera at this square size (px): "
                                                             "OUT/frames/000.png ... + truth.json, a measurement "
                                                             "for `fit --observer heatmap|transporter`"),
             render_memory_gb: Optional[float] = typer.Option(None, callback=bound(0, strict=True), help="cap on the rendered frames' estimated "
                                                                         "memory, GB (default 4); larger renders "
                                                                         "are refused before simulating"),
             overwrite: bool = typer.Option(False, "--overwrite", help="replace what --out holds (an earlier "
                                                                       "simulation); without it a non-empty --out "
                                                                       "is refused"),
             as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Roll a scenario out at given parameters; write Zarr and a PNG preview (and rendered frames)."""
    from softsbi.workflows.simulate import RENDER_MEMORY_GB, simulate_to_folder  # start-up: the simulation workflow

    o = Output(as_json)
    doc = simulate_to_folder(out, backend=backend, scenario=scenario, recording=recording,
                             theta=parse_kv(theta, "--theta"), effects=names(effect, "--effect"),
                             backend_options=parse_kv(backend_opt, "--backend-opt"), render=render,
                             render_memory_gb=RENDER_MEMORY_GB if render_memory_gb is None else render_memory_gb,
                             overwrite=overwrite)
    if json_done(o, doc):
        if doc["status"] != 0:
            raise typer.Exit(1)
        return
    o.line(f"{backend} {scenario}: status {'ok' if doc['status'] == 0 else doc['reason']}, {doc['frames']} frames, "
           f"{doc['vertices']} vertices, {doc['wall_s']:.2f} s wall -> {doc['rollout']}")
    if doc["status"] != 0:  # the failed rollout is kept for a look, but there is no recording to fit
        o.error(f"the simulation failed ({doc['reason']}); no recording was written")
        raise typer.Exit(1)
    if doc["recording"]:
        o.line(f"recording: {doc['recording']} (`softsbi fit --observed {doc['recording']} --out RUN` fits it)")
    if doc["preview"]:
        o.line(f"preview: {doc['preview']}")
    if doc["frames_dir"]:
        o.line(f"{doc['frames']} rendered frames ({render}x{render} px): {doc['frames_dir']} (truth.json holds "
               f"the parameters; `softsbi fit --observed {doc['frames_dir']} --scenario {scenario} "
               f"--observer heatmap --extractor ...` fits them)")


def compare_backends(scenario: str = typer.Option(D.SCENARIO, help="scenario name or file (`softsbi scenarios` "
                                                               "lists them)"),
                     theta: list[str] = typer.Option(None, "--theta",
                                                     help="name=value (repeatable); unset = the shared prior midpoint "
                                                          "(engine-only knobs: each backend's own)"),
                     backends: str = typer.Option(",".join(D.COMPARED_BACKENDS), help="comma-separated simulators"),
                     backend_opt: list[str] = typer.Option(None, "--backend-opt",
                                                           help="backend:option=value, e.g. pybullet-massspring:grid=7"),
                     match: Match = typer.Option(Match.physical, help="match the engines by 'physical' "
                                                                      "parameter values or by 'unit' prior "
                                                                      "positions in [0, 1]"),
                     out: Path = typer.Option(Path("compare"), help="output folder (compare.json + compare.png)"),
                     as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Roll the same scenario out on two engines at the same physical parameters (default: the shared prior
    midpoint); per-frame Chamfer between them says how far the engines disagree."""
    from softsbi.workflows.compare_backends import compare_backends as run  # start-up: the simulation workflow
    from softsbi.scenarios.builtin import make_scenario  # start-up: numpy, the scenario models

    try:
        sc = make_scenario(scenario)
    except ValueError as exc:
        raise SoftsbiError(str(exc)) from None
    opts: dict[str, dict[str, Any]] = {}
    for it in backend_opt or []:
        if ":" not in it:
            raise SoftsbiError(f"--backend-opt '{it}' must look like backend:name=value")
        b, kv = it.split(":", 1)
        opts.setdefault(b, {}).update(parse_kv([kv], "--backend-opt"))
    try:
        rep = run(sc, parse_kv(theta, "--theta"), names([backends], "--backends"), out, backend_options=opts,
                  match=Match(match).value)
    except ValueError as exc:
        raise SoftsbiError(str(exc)) from None
    o = Output(as_json)
    if json_done(o, rep):
        return
    for b, r in rep["backends"].items():
        o.line(f"{b}: status {r['status']}{' (' + r['reason'] + ')' if r['reason'] else ''}, "
               f"{r['n_vertices']} vertices, {r['wall_s']:.2f} s; theta "
               + ", ".join(f"{k}={v:.4g}" for k, v in r["theta"].items()))
    o.line("shared physical parameters: " + (", ".join(rep["shared_params"]) or "(none)"))
    for key, m in rep["mean_chamfer_m"].items():
        mx = rep["max_chamfer_m"][key]
        o.line(f"Chamfer {key}: " + (f"mean {m * 100:.2f} cm, max {mx * 100:.2f} cm over {len(rep['times'])} frames"
                                     if m is not None else "n/a (a rollout failed)"))
    o.line(f"wrote {out / 'compare.json'} and {out / 'compare.png'}")
