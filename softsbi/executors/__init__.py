"""Optional executors (plugins registered through the ``softsbi`` entry points).

``ray`` (:mod:`softsbi.executors.ray_executor`) needs ``pip install softsbi[ray]``; its
module imports without Ray so that ``--executor ray`` can say what to install.
"""

#: run even a single worker (``workers=1``) in a process of its own, so that a simulator that crashes its process
#: fails that simulation, not the command; the ``softsbi`` command sets it (the Python API runs ``workers=1`` in its
#: own process, the easiest to debug)
ISOLATE_ONE_WORKER = False
