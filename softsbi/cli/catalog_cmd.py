"""``softsbi plugins``, ``softsbi scenarios`` and ``softsbi params``: what is installed and what a fit infers."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from softsbi.cli.command import json_done
from softsbi.cli.options import H_BACKEND, H_JSON, names
from softsbi.cli.output import Output
from softsbi.core import defaults as D


def plugins(as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """List installed simulators, effects (with the backends that can apply each and its parameters), observers,
    estimators and executors; a plugin whose code fails is listed as BROKEN, with its fault below the tables."""
    from softsbi.plugins import registry  # start-up: loads every plugin
    from softsbi.plugins.manager import LOAD_ERRORS  # start-up: the plugin manager
    desc = registry().describe()
    if LOAD_ERRORS:
        desc["load_errors"] = dict(LOAD_ERRORS)
    o = Output(as_json)
    if json_done(o, desc):
        return
    broken = []
    # a broken plugin's row holds name, class, package and broken only; every other row holds doc, and an effect's
    # its kind, generic and description (Effect's class attributes) (Registry.describe)
    for kind, rows in desc.items():
        if kind == "load_errors":
            continue
        broken += [r["broken"] for r in rows if "broken" in r]
        if kind == "effects":
            o.table(["name", "kind", "applied by", "parameters [prior] unit", "package", "description"],
                    [[r["name"], "BROKEN", "", "", r["package"], "see below"] if "broken" in r else
                     [r["name"], r["kind"] + (" (generic)" if r["generic"] else ""),
                      ", ".join(r["backends"]) or "none installed",
                      "; ".join(_param_text(p) for p in r["parameters"]), r["package"], r["description"] or r["doc"]]
                     for r in rows], title=kind)
            continue
        o.table(["name", "package", "description"],
                [[r["name"], r["package"], "BROKEN: see below" if "broken" in r else r["doc"] +
                  (f" scenarios: {', '.join(r['scenarios'])}" if r.get("scenarios") else "")] for r in rows],
                title=kind)
    for name, err in LOAD_ERRORS.items():
        o.line(f"plugin '{name}' failed to load: {err}")
    for msg in broken:
        o.line(msg)


def _param_text(p: dict[str, Any]) -> str:
    """``wind_x [-2, 2] m/s`` (``log`` added for a log-uniform prior)."""
    unit = "" if p["unit"] in ("", "1") else f" {p['unit']}"
    return f"{p['name']} [{p['prior'][0]:g}, {p['prior'][1]:g}]{unit}{' log' if p['scale'] == 'log' else ''}"


def _limit_text(limits: list[Any]) -> str:
    lo, hi = ("-inf" if limits[0] is None else f"{limits[0]:g}"), ("inf" if limits[1] is None else f"{limits[1]:g}")
    return f"{lo} to {hi}"


def params(scenario: str = typer.Argument(..., help="scenario name (`softsbi scenarios` lists them), scenario file "
                                                    "(.yaml) or recording folder (its scenario)"),
           effect: list[str] = typer.Option(None, "--effect", help="effects to add (their parameters join the "
                                                                   "backend's)"),
           backend: str = typer.Option(D.BACKEND, help=H_BACKEND),
           as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """Every parameter a fit of SCENARIO infers: unit, prior bounds, scale and physical limits (`fit --bounds` moves
    a prior up to the limits, `fit --fix` holds a parameter)."""
    from softsbi.scenarios import load_scenario  # start-up: numpy, the scenario models
    from softsbi.workflows.fit.run import FitConfig, parameter_table  # start-up: the fit workflow
    from softsbi.workflows.measurement import recording_scenario  # start-up: the recording readers
    effects = names(effect, "--effect")
    sc = recording_scenario(scenario) if Path(scenario).is_dir() else load_scenario(scenario)
    rows = parameter_table(FitConfig(backend=backend, effects=effects), sc)
    o = Output(as_json)
    if json_done(o, {"scenario": sc.name, "backend": backend, "effects": effects, "parameters": rows}):
        return
    o.table(["parameter", "from", "unit", "prior", "scale", "physical limits", "description"],
            [[r["name"], r["source"], r["unit"], f"{r['prior'][0]:g} to {r['prior'][1]:g}", r["scale"],
              _limit_text(r["limits"]), r["description"]] for r in rows],
            title=f"Parameters of a fit of '{sc.name}' on {backend}" + (f" with {', '.join(effects)}" if effects else ""))


def scenarios(as_json: bool = typer.Option(False, "--json", help=H_JSON)) -> None:
    """List the scenarios: the built-in scenario files and those plugins add (softsbi_scenarios hook).
    Any scenario file path works wherever a scenario name does."""
    from softsbi.scenarios import list_scenarios  # start-up: numpy, the scenario models
    rows = list_scenarios()
    o = Output(as_json)
    if json_done(o, rows):
        return
    o.table(["name", "source", "description"], [[r["name"], r["source"], r["description"]] for r in rows],
            title="scenarios")
