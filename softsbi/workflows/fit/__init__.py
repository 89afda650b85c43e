"""The fit engine: a fit's settings, its rounds of simulation and training, resume, the simulation bank, the jobs
that simulate and observe, prior widening, the best fit, the run store's reading and the stored tasks (the keyed
first rounds a fit reads and writes).

It imports nothing from :mod:`softsbi.workflows.criticism` or :mod:`softsbi.workflows.tasks` (the layer contract in
pyproject.toml).
"""
