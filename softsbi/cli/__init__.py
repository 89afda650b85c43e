"""Command-line interface: the ``softsbi`` command (``softsbi --help`` lists its commands). The typer app is
:mod:`softsbi.cli.app`; each command lives in a ``*_cmd`` module, what they share in :mod:`softsbi.cli.options`
and :mod:`softsbi.cli.command`."""
from softsbi.cli.app import app, main
from softsbi.cli.fit_cmd import print_fit_report as _print_report  # noqa: F401 - the name the fit report's tests import

__all__ = ["app", "main"]
