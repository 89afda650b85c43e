"""The public Python API (re-exported as ``softsbi.fit``, ``softsbi.open_run``, ``softsbi.simulate``,
``softsbi.load_recording``, ``softsbi.load_scenario``): the same workflows and defaults as the CLI.

    import softsbi
    rec = softsbi.load_recording("../shared/data/diffcloud_lift/lift_tan")
    run = softsbi.fit(rec, out="runs/tan", rounds=4, sims_per_round=150)
    post = softsbi.open_run("runs/tan").posterior          # physical units
    theta = post.sample(100); post.log_prob(theta); post.mean; post.interval(0.9)
    roll = softsbi.simulate("lift", dict(zip(post.names, theta[0])))

``fit``, ``check``, ``diagnose`` and ``compare`` show their progress as the CLI does in a pipe: one line on stderr
when a phase of simulations begins and one when it ends (:class:`~softsbi.workflows.reporting.LineReporter`);
``progress=False`` keeps them silent.
"""
from __future__ import annotations

import json
import warnings
from dataclasses import fields, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from pydantic import TypeAdapter, ValidationError

from softsbi.core.errors import ParameterError, SoftsbiError, SoftsbiWarning, as_path, closest
from softsbi.core.types import Recording, Rollout, Scenario
from softsbi.data.validation import validation_line
from softsbi.plugins import check_options, registry
from softsbi.scenarios.builtin import make_scenario
from softsbi.core.results.comparison import CompareResult
from softsbi.core.results.joint import JointDiagnosis
from softsbi.core.results import CheckResult, Diagnosis
from softsbi.workflows.tasks.calibrate import calibrate_run
from softsbi.workflows.criticism.check import check_run
from softsbi.workflows.criticism.compare import compare_runs
from softsbi.workflows.criticism.diagnose import diagnose_run
from softsbi.workflows.criticism.joint import diagnose_runs
from softsbi.workflows.fit.run import FitCallbacks, FitConfig, FitResult, run_fit
from softsbi.workflows.measurement import load_recording
from softsbi.workflows.reporting import fit_callbacks, say, shown_unless_shown
from softsbi.workflows.fit.runs import Run, open_run
from softsbi.core.defaults import CheckSettings, DiagnoseSettings, split_settings
from softsbi.workflows.lock import check_out_apart
from softsbi.workflows.measurement import default_values, rollout_space


def load_scenario(name_or_path: str | Path, recording: str | Path | None = None, **kwargs: Any) -> Scenario:
    """A scenario by built-in name (``lift``, ``wipe``, ``winding``, ``fling``; ``softsbi scenarios`` lists
    them and those plugins add) or scenario file path (``my_fold.yaml``,
    :mod:`softsbi.scenarios.spec`); ``lift`` from a DiffCloud recording folder when ``recording`` is given.

    Raises:
        SoftsbiError: an unknown name (the message lists the valid ones), an invalid scenario file (one
            line naming the file, the field and the fix) or a malformed recording.
    """
    try:
        return make_scenario(str(name_or_path), recording, **kwargs)
    except ValueError as exc:
        raise SoftsbiError(str(exc)) from None


def fit(recording: Recording | str | Path, out: str | Path, config: FitConfig | None = None,
        callbacks: FitCallbacks | None = None, plots: bool = True, progress: bool = True,
        **settings: Any) -> FitResult:
    """Fit the posterior over a simulator's physical parameters to ``recording`` (resumable).

    Args:
        recording: a :class:`~softsbi.core.types.Recording` (:func:`load_recording`, or a simulated
            one from :func:`softsbi.workflows.measurement.simulate_recording`), or the path of a recording
            folder, read as ``softsbi fit --observed PATH`` reads it (``n_points`` and ``seed`` from the settings).
        out: run directory (``run.zarr``, ``report.json``, figures); an existing run with the same
            settings resumes.
        config: settings; default :class:`FitConfig` (the CLI's defaults).
        settings: :class:`FitConfig` fields overriding ``config``, e.g. ``backend="mujoco-flex"``,
            ``estimator="rkhs"``, ``rounds=4``, ``effects=["wind"]``.
        callbacks: progress callbacks of your own (then ``progress`` is not used).
        progress: one line on stderr when each round's simulations begin and end (module docstring).

    Returns:
        :class:`~softsbi.workflows.fit.run.FitResult`; :func:`open_run` ``(out).posterior`` gives the
        posterior in physical units.

    Raises:
        ParameterError: a setting that is not a :class:`FitConfig` field (names the closest one), or a value
            that is not of the field's type (e.g. ``rounds="two"``, ``effects="wind"`` for ``["wind"]``,
            ``bounds={"stretch": 5}`` for ``{"stretch": (low, high)}``); ``recording`` neither a Recording nor a path;
            ``out`` not a path (e.g. None).
        RunDirError: ``out`` is the recording folder or lies inside another run's directory
            (:func:`~softsbi.workflows.lock.check_out_apart`).
        Everything :func:`~softsbi.workflows.fit.run.run_fit` raises.
    """
    names = [f.name for f in fields(FitConfig)]
    bad = [k for k in settings if k not in names]
    if bad:
        raise ParameterError(f"unknown fit setting {bad[0]!r}.{closest(bad[0], names)} Settings: {', '.join(names)}")
    if config is not None and not isinstance(config, FitConfig):
        raise ParameterError(f"fit(config=...) takes a softsbi.FitConfig, got {type(config).__name__}")
    cfg = typed_config(replace(config or FitConfig(), **settings))
    out = as_path(out, "fit(out)", 'softsbi.fit(rec, out="runs/tan")')
    check_out_apart(out, "fit", run=out, recording=recording if isinstance(recording, (str, Path)) else None)
    if isinstance(recording, (str, Path)):
        recording = load_recording(recording, n_points=cfg.n_points, seed=cfg.seed)
    elif not isinstance(recording, Recording):
        raise ParameterError(f"fit(recording=...) takes a Recording (softsbi.load_recording(PATH)) or the path of a "
                             f"recording folder, got {type(recording).__name__}")
    with shown_unless_shown(progress and callbacks is None):
        return run_fit(out, recording, cfg, callbacks=callbacks or fit_callbacks("fit"), make_plots=plots)


def typed_config(cfg: FitConfig) -> FitConfig:
    """``cfg`` with every setting checked against its declared type (:class:`FitConfig`'s annotations) and
    converted where that is lossless (``"4"`` -> 4, a ``[low, high]`` list -> a tuple).

    Raises:
        ParameterError: one line naming the first setting of the wrong type, its value and the fix.
    """
    try:
        return TypeAdapter(FitConfig).validate_python({f.name: getattr(cfg, f.name) for f in fields(FitConfig)})
    except ValidationError as exc:
        raise ParameterError(validation_line("fit setting", exc, "help(softsbi.FitConfig)")) from None


def simulate(scenario: str | Scenario, theta: Mapping[str, float] | None = None, backend: str = "mujoco-flex",
             effects: Sequence[str] = (), seed: int = 0, **backend_options: Any) -> Rollout:
    """One rollout of ``scenario`` at ``theta`` (physical units; unset parameters as
    :func:`~softsbi.workflows.measurement.default_values` sets them: ``scale`` at the scenario's object size, the
    others at their prior midpoint) on a simulator plugin.

    Returns:
        :class:`~softsbi.core.types.Rollout` (``vertices (T, N, 3)`` m, ``gripper``, ``times``, status).

    Raises:
        PluginNotFound: unknown backend or effect. ParameterError: unknown parameter or a value outside its physical limits,
            or a backend option the backend does not have (or text where it expects a number); a ``scenario``,
            ``effects`` or ``theta`` of the wrong type (a string where a list of effect names is expected).
    """
    if not isinstance(scenario, (str, Path, Scenario)):
        raise ParameterError(f"simulate(scenario=...) takes a scenario name, a scenario file path or a Scenario, got "
                             f"{type(scenario).__name__}")
    if isinstance(effects, str) or not all(isinstance(e, str) for e in effects):
        raise ParameterError(f"simulate(effects=...) takes a list of effect names, e.g. [{str(effects)!r}], got "
                             f"{type(effects).__name__} {effects!r}"[:300])
    if theta is not None and not isinstance(theta, Mapping):
        raise ParameterError(f"simulate(theta=...) takes a mapping {{name: value}}, got {type(theta).__name__}")
    sc = load_scenario(scenario) if isinstance(scenario, (str, Path)) else scenario
    reg = registry()
    check_options(reg.simulator(backend), backend_options, f"simulator '{backend}' (backend_options)")
    sim = reg.simulator(backend)(**backend_options)
    space = rollout_space(sim, sc, effects)
    values = default_values(space, sc)
    values.update(dict(theta or {}))
    return sim.simulate(sc, space.check(values, within="limits"), effects=list(effects), seed=int(seed))


def check(run: str | Path, progress: bool = True, *, out_dir: str | Path | None = None,
          **settings: Any) -> CheckResult:
    """``softsbi check RUN``: the posterior predictive check of a finished fit
    (:func:`~softsbi.workflows.criticism.check.check_run`; ``settings``: ``n_eval``, ``alpha``, ``max_null``, ``workers``,
    ``effects``, ``recompute``, ``out_dir``, ...). Returns the :class:`~softsbi.core.results.CheckResult` (also in
    ``RUN/check.json``, or ``out_dir/check.json``). ``progress``: one line on stderr per phase of simulations (module
    docstring).

    A run keeps one check: a ``check.json`` computed with other settings (another ``effects`` family, ``n_eval``,
    ``alpha`` ...) is replaced, and a :class:`~softsbi.core.errors.SoftsbiWarning` says so, naming the settings that
    changed; ``out_dir`` writes the new check beside the run's and keeps that one.
    """
    check_settings, rest = split_settings(CheckSettings, settings)
    path = Path(out_dir or run) / "check.json"
    before = _stored_key(path)
    with shown_unless_shown(progress):
        result = check_run(run, check_settings, out_dir=out_dir, **rest)
    after = _stored_key(path)
    if before is not None and after is not None and before != after:
        changed = ", ".join(f"{k} {before.get(k)!r} -> {after.get(k)!r}" for k in after if before.get(k) != after.get(k))
        warnings.warn(SoftsbiWarning(f"replaced {path}, which held the check of other settings ({changed}); pass "
                                     f"out_dir=... to keep both"), stacklevel=2)
    return result


def _stored_key(path: Path) -> dict[str, Any] | None:
    """The settings a stored ``check.json`` was computed with (its ``key``); None when there is none or it cannot be
    read."""
    try:
        key = json.loads(path.read_text())["key"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return key if isinstance(key, dict) else None


def diagnose(run: str | Path | Sequence[str | Path], effects: Sequence[str] | None = None,
             out: str | Path | None = None, progress: bool | Callable[[str], None] = True,
             **settings: Any) -> Diagnosis | JointDiagnosis:
    """``softsbi diagnose RUN``: is an effect missing, and which (:func:`~softsbi.workflows.criticism.diagnose.diagnose_run`;
    ``settings``: ``alpha``, ``k_se``, ``confirm``, ``refit_rounds``, ``refit_sims``, ``workers``, ...). Returns the
    :class:`~softsbi.core.results.Diagnosis` (also in ``OUT/diagnosis.json``; ``out``, as ``diagnose --out``: the
    folder of the diagnosis, its check and its refits, default ``run``). ``progress``: one line on stderr per phase of
    simulations, the refits' rounds included, and per step (detect, each refit) as the CLI prints them (module
    docstring); a callable gets the step lines instead.

    ``run`` a list of three or more runs (fits of one task's recordings; ``softsbi diagnose RUN RUN ... --out
    DIR``): one verdict for the task (:func:`~softsbi.workflows.criticism.joint.diagnose_runs`), returned as the
    :class:`~softsbi.core.results.joint.JointDiagnosis` and written to ``out/joint-diagnosis.json`` (``out`` required).

    Raises:
        SoftsbiError: ``effects`` given as one string (name them in a list), and everything ``diagnose_run`` (or
            ``diagnose_runs``) raises.
    """
    if isinstance(effects, str):
        raise SoftsbiError(f"effects must be a list of effect names, e.g. effects=[{effects!r}]")
    steps = progress if callable(progress) else say if progress else None
    diagnose_settings, rest = split_settings(DiagnoseSettings, settings)
    with shown_unless_shown(bool(progress)):
        if isinstance(run, (list, tuple)):
            return diagnose_runs(run, effects=effects, out_dir=out, progress=steps, settings=diagnose_settings,
                                 **rest)
        return diagnose_run(run, effects=effects, out_dir=out, progress=steps, settings=diagnose_settings, **rest)


def compare(run_a: str | Path, run_b: str | Path, out: str | Path | None = None, progress: bool = True,
            **settings: Any) -> CompareResult:
    """``softsbi compare A B``: two fits of one measurement side by side
    (:func:`~softsbi.workflows.criticism.compare.compare_runs`; the runs and ``out`` as ``str`` or ``Path``; the figure and JSON go to ``out``, default ``run_b``; ``settings``:
    ``n_eval``, ``alpha`` (the level of both checks), ``max_null``, ``workers``, ``recompute``). Returns the
    :class:`~softsbi.core.results.comparison.CompareResult`. ``progress``: one line on stderr per phase of simulations
    (module docstring)."""
    check_settings, rest = split_settings(CheckSettings, settings)
    with shown_unless_shown(progress):
        return compare_runs(run_a, run_b, run_b if out is None else out, check_settings, **rest)


__all__ = ["FitConfig", "FitResult", "Run", "calibrate_run", "check", "compare", "diagnose", "fit", "load_scenario",
           "open_run", "simulate"]
