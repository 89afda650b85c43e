"""Scenarios: the task a recording was made in (object, handles and their paths, frames, world)."""
from softsbi.scenarios.builtin import SCENARIOS, make_scenario

__all__ = ["SCENARIOS", "make_scenario"]
