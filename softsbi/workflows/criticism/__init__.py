"""Model criticism: whether a fitted model can produce its recording (``check``, calibrated against replicates of
a trained task), which effect it lacks (screening, the candidates' evidence, the decision, ``diagnose``) and the
error before and after adding it (``compare``).

The Monte-Carlo and misspecification statistics it rests on are pure functions of arrays in
:mod:`~softsbi.workflows.criticism.statistics`; :mod:`~softsbi.workflows.criticism.stats` applies them to a run.
"""
