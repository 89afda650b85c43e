"""What the CLI prints, on a terminal and in a pipe.

* Results (tables, verdicts, paths) go to stdout; progress, status lines and engine chatter to
  stderr, so ``softsbi fit ... > log`` or ``| cat`` holds only results.
* On a terminal: rich tables and progress bars. When stdout is not a terminal: plain text, no
  colour, no wrapping of long lines and no truncated table cells (rich with an unbounded width).
* Text is never parsed as rich markup, so units such as ``[cm]`` print as written.
* ``--json``: one JSON document on stdout and nothing else there; errors as
  ``{"error": message, "type": class}`` with a non-zero exit.
"""
from __future__ import annotations

import contextlib
import json
import sys
from typing import Any, Iterator, Sequence

from rich import box
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, \
    TimeRemainingColumn
from rich.table import Table


#: width of a piped console: wide enough that no line wraps and no table cell is cut
PIPE_WIDTH = 100_000


def _console(stream: Any, tty: bool) -> Console:
    if tty:
        return Console(file=stream, markup=False, highlight=False, emoji=False)
    return Console(file=stream, width=PIPE_WIDTH, markup=False, highlight=False, emoji=False, no_color=True,
                   soft_wrap=True, force_terminal=False)


class Output:
    """Printing for one command.

    Args:
        as_json: the command was given ``--json``: human-readable results go to stderr instead of
            stdout, and :meth:`emit_json` writes the single JSON document.
    """

    def __init__(self, as_json: bool = False):
        self.as_json = as_json
        self.tty = sys.stdout.isatty() and not as_json
        self.err_tty = sys.stderr.isatty()
        # human-readable results: stdout, or stderr under --json (stdout holds only the JSON)
        self.out = _console(sys.stderr if as_json else sys.stdout, self.err_tty if as_json else self.tty)
        self.err = _console(sys.stderr, self.err_tty)

    # results ------------------------------------------------------------------------------
    def line(self, text: str = "", style: str | None = None) -> None:
        """A result line (stdout)."""
        self.out.print(text, style=style if self.out.is_terminal else None, soft_wrap=not self.out.is_terminal)

    def rule(self, title: str) -> None:
        """A section heading."""
        if self.out.is_terminal:
            self.out.rule(title)
        else:
            self.out.print(f"== {title} ==")

    def table(self, columns: Sequence[str], rows: Sequence[Sequence[Any]], title: str | None = None) -> None:
        """A table of strings; never truncated in a pipe."""
        t = Table(title=title, box=box.SIMPLE_HEAD if self.out.is_terminal else box.ASCII2,
                  title_justify="left")
        for c in columns:
            t.add_column(str(c), overflow="fold" if self.out.is_terminal else "ignore", no_wrap=not self.out.is_terminal)
        for r in rows:
            t.add_row(*[str(c) for c in r])
        self.out.print(t)

    # progress and messages (stderr) ---------------------------------------------------------
    def message(self, text: str, style: str | None = None) -> None:
        """A progress or status message (stderr)."""
        self.err.print(text, style=style if self.err.is_terminal else None, soft_wrap=not self.err.is_terminal)

    def error(self, text: str) -> None:
        """One error line (stderr), or a JSON error object on stdout under ``--json``."""
        if self.as_json:
            return
        self.err.print(f"error: {text}", style="bold red" if self.err.is_terminal else None, soft_wrap=True)

    @contextlib.contextmanager
    def status(self, text: str) -> Iterator[None]:
        """A spinner on a terminal; one line on stderr otherwise."""
        if self.err.is_terminal:
            with self.err.status(text):
                yield
        else:
            self.err.print(text, soft_wrap=True)
            yield

    def progress(self) -> Progress:
        """Progress bars on stderr (drawn only on a terminal; in a pipe, rich prints nothing)."""
        return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                        TimeRemainingColumn(), console=self.err, transient=False, disable=not self.err.is_terminal)

    # JSON -------------------------------------------------------------------------------------
    def emit_json(self, doc: Any) -> None:
        """Write ``doc`` as the command's one JSON document on stdout (NaN/inf as null)."""
        from softsbi.core.types import jsonable  # start-up: numpy
        sys.stdout.write(json.dumps(jsonable(doc), indent=2) + "\n")
        sys.stdout.flush()


def json_error(exc: BaseException) -> str:
    """The JSON error document of ``exc``."""
    return json.dumps({"error": str(exc), "type": type(exc).__name__}, indent=2)
