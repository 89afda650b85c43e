"""``python -m benchmarks``: list the suites, run one (then render the page), or render the page.

    python -m benchmarks list
    python -m benchmarks run SUITE [--full] [suite options]   # python -m benchmarks run SUITE --help
    python -m benchmarks render [--check]
"""
from __future__ import annotations

import argparse
import sys

from benchmarks import runner


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="the declared suites")
    r = sub.add_parser("run", help="run a suite, store its results JSON and render the page", add_help=False)
    r.add_argument("suite", choices=sorted(runner.SUITES), metavar="SUITE")
    r.add_argument("args", nargs=argparse.REMAINDER, help="the suite's options (SUITE --help lists them)")
    g = sub.add_parser("render", help="write docs/benchmarks.md from benchmarks/results/*.json")
    g.add_argument("--check", action="store_true", help="exit 1 if docs/benchmarks.md differs from the results")
    a = ap.parse_args(argv)
    if a.cmd == "list":
        for s in runner.SUITES.values():
            print(f"{s.name:17s} {s.group}: {s.title}")
        return 0
    if a.cmd == "run":
        runner.run(a.suite, a.args)
        print(f"wrote {runner.RESULTS.relative_to(runner.REPO)}/{a.suite}.json and "
              f"{runner.DOC.relative_to(runner.REPO)}")
        return 0
    if a.check:
        current = runner.DOC.read_text() if runner.DOC.exists() else ""
        if current != runner.render_text():
            print(f"{runner.DOC.relative_to(runner.REPO)} is not what the results render: run "
                  "`python -m benchmarks render`", file=sys.stderr)
            return 1
        return 0
    runner.render()
    print(f"wrote {runner.DOC.relative_to(runner.REPO)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
