"""One-off studies: each answered one question, stated with its conclusion at the top of its module, and is kept to
be run again when its question opens again (``python -m benchmarks.studies.NAME --help``). They are not suites: no
results JSON, no section of docs/benchmarks.md.
"""
