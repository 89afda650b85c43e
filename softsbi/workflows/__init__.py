"""The application: what a user runs, in named steps (fit, check, diagnose, compare, view, demo).

Workflows resolve simulators, observers, estimators and executors by name through the plugin
registry and never import a backend directly.
"""
