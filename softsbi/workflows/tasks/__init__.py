"""Training a task once for every later recording of it (``softsbi task train``: the amortised posterior of the
model and of each candidate effect, with its calibration report and the check's replicates) and the
simulation-based calibration of an estimator (``softsbi calibrate``).

The keyed store the trained models live in is the fit's (:mod:`softsbi.workflows.fit.task_store`): a fit reads and
writes it.
"""
