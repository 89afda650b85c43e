"""Optional executors (plugins registered through the ``softsbi`` entry points).

``ray`` (:mod:`softsbi.executors.ray_executor`) needs ``pip install softsbi[ray]``; its
module imports without Ray so that ``--executor ray`` can say what to install.
"""
