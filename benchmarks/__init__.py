"""softsbi's benchmark suites: ``python -m benchmarks list | run SUITE [--full] [options] | render``.

The runner and the declared suites are in :mod:`benchmarks.runner`; each suite's results are stored in
``benchmarks/results/SUITE.json`` and rendered into ``docs/benchmarks.md``. One-off studies, each with its
conclusion at the top, are in :mod:`benchmarks.studies`.
"""
