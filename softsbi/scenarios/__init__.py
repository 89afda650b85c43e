"""Scenarios: the task a recording was made in (object, handles and their paths, frames, world).

Scenarios are data: :func:`load_scenario` reads a scenario file (:mod:`softsbi.scenarios.spec`),
a built-in one (``softsbi/scenarios/files``) or one a plugin adds (``softsbi_scenarios`` hook).
"""
from softsbi.scenarios.builtin import SCENARIOS, make_scenario
from softsbi.scenarios.catalog import builtin_files, list_scenarios, load_scenario

__all__ = ["SCENARIOS", "builtin_files", "list_scenarios", "load_scenario", "make_scenario"]
