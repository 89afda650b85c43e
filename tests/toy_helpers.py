"""Shared test helpers (importable from every test module: pytest puts ``tests/`` on ``sys.path``
through the root ``conftest.py``): paths and the toy plugin's recording."""
from pathlib import Path

#: this folder, the repository and ../shared/data beside it (never copied into the project)
TESTS_DIR = Path(__file__).resolve().parent
REPO = TESTS_DIR.parent
DATA = REPO.parent / "shared" / "data"
FAULT_ENV = TESTS_DIR / "fault_env"


def toy_measurement(truth=(0.3, -0.4), T=3, seed=5):
    """A recording of the toy-gauss simulator (tests/plugins/softsbi_toy) at ``truth`` = (a, b)."""
    from softsbi_toy import plugin as toy

    from softsbi.workflows.measurement import simulate_recording
    sc = toy.toy_scenario(T)
    return simulate_recording("toy-gauss", sc, {"a": truth[0], "b": truth[1]}, n_points=16, n_dense=64, seed=seed)


def copy_lift_recording(tmp_path, lift_dir=DATA / "diffcloud_lift"):
    """A writable copy of the real lift_tan recording in DiffCloud's layout (the parent folder holds
    ``lift_traj.npy`` and the default ``lift_real2sim.yaml``); returns the ``lift_tan`` folder."""
    import shutil
    dst = tmp_path / "diffcloud_lift"
    dst.mkdir()
    for f in ("lift_traj.npy", "lift_real2sim.yaml"):
        shutil.copy(lift_dir / f, dst / f)
    shutil.copytree(lift_dir / "lift_tan", dst / "lift_tan")
    return dst / "lift_tan"


def printed_fit_report(rep, out, capsys):
    """What ``fit`` prints for report.json ``rep`` of run directory ``out`` (``softsbi.cli._print_report``), checked
    to be, line for line, what :mod:`softsbi.report.fit_text` renders (its wording is tested there, in
    tests/report): the posterior table (title, header, one row per parameter, each cell as rendered), then every
    sentence under it. Returns ``(table, lines)``: :func:`~softsbi.report.fit_text.posterior_table` and
    :func:`~softsbi.report.fit_text.fit_report_lines` of ``rep``."""
    from softsbi.cli import _print_report
    from softsbi.cli.output import Output
    from softsbi.report.fit_text import fit_report_lines, posterior_table
    from softsbi.workflows.fit.prior_widening import widening_sentence
    capsys.readouterr()  # what was printed before
    _print_report(Output(), rep, out)
    printed = capsys.readouterr().out.splitlines()
    table = posterior_table(rep)
    lines = fit_report_lines(rep, out, [widening_sentence(w) for w in rep.get("widened") or []])
    assert printed[0] == table.title and printed[-len(lines):] == lines, printed
    cells = [[c.strip() for c in row.strip().strip("|").split("|")] for row in printed[1:-len(lines)]
             if row.startswith("|")]
    assert cells == [list(table.columns)] + [list(r) for r in table.rows], printed
    return table, lines
