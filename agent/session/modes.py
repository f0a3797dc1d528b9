"""The kinds of session, one small class each, sharing the skeleton in ``runner.Session``.

A mode decides what the session records (``select``: which phases, from which baseline), what
it needs of the operator at a tool change, and what happens with the recording (``finish``):

- ``Identify`` (`run`): the loaded run, reusing the stored empty-flange baseline when it still fits;
  otherwise (interactive only) the empty run first, which then becomes the baseline;
- ``Baseline`` (`baseline`): the empty-flange run only, stored as the robot's baseline, no analysis;
- ``Calibrate`` (`calibrate`): an identification of a known reference payload whose result fits the
  drive gains; kept out of the history and the tool library, never written to the controller;
- ``Resume`` (`run --resume`): the unfinished sweeps of a stopped run of any of them, into its folder.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from payload_agent.configuration.config import Config
from payload_agent.errors import BaselineError, PayloadAgentError, RobotNotReadyError
from payload_agent.motion.planner import Plan, remaining_plan
from payload_agent.recording.state import RobotState
from payload_agent.session import baseline as baselines
from payload_agent.session.options import RunOptions
from payload_agent.session.resume import ResumeState
from payload_agent.types import ControllerInfo


@dataclass
class Selection:
    """What this session records: (phase, tool mounted, the plan left of it) in order, the stored baseline it
    uses (or None), and whether its own empty run becomes the stored baseline."""

    todo: list[tuple[str, bool, Plan]]
    stored: baselines.BaselineInfo | None
    store_empty: bool

    @property
    def phases(self) -> list[tuple[str, bool]]:
        return [(p, m) for p, m, _ in self.todo]


class Mode:
    """The common rules; a mode overrides what differs."""

    name: ClassVar[str]
    command: ClassVar[str]  # the CLI command, for the robot lock and messages
    uses_calibration: ClassVar[bool] = True  # the stored drive-gain calibration is checked before connecting
    may_apply: ClassVar[bool] = False  # --apply writes the result to the controller
    keeps_results: ClassVar[bool] = True  # the result goes into the history (and, with --tool, the tool library)
    analyses: ClassVar[bool] = True  # a result is computed from the recording
    empties_flange: ClassVar[bool] = False  # the operator removes the tool even when only one phase is recorded
    resumed: ClassVar[bool] = False

    def validate(self, opts: RunOptions) -> None:
        """Refuse options this mode cannot honour, before anything starts."""

    def select(self, config: Config, plan: Plan, opts: RunOptions, state: RobotState,
               current: baselines.BaselineInfo, info: ControllerInfo, out) -> Selection:
        """(phases to record, the stored baseline to use or None, store this session's empty run?)."""
        both = Selection([("empty", False, plan), ("loaded", True, plan)], None, True)
        if opts.fresh_baseline:
            if opts.unattended and config.simulation is None:
                raise RobotNotReadyError("--fresh-baseline needs the tool removed and mounted again, "
                                         "which an unattended run cannot ask for")
            return both
        try:
            stored = baselines.require_valid(state, current, config.storage.baseline_max_age_days,
                                             config.storage.baseline_max_temperature_delta_c)
        except BaselineError as exc:
            if opts.unattended:
                raise
            out(f"{exc}\nThis session records the empty-flange run first and stores it as the new baseline.")
            return both
        temps = ""
        if stored.joint_temperatures_c and current.joint_temperatures_c:
            worst = max(abs(b - a) for a, b in zip(stored.joint_temperatures_c, current.joint_temperatures_c))
            temps = f", joint temperatures within {worst:.1f} °C of then"
        out(f"Using the stored empty-flange baseline of {stored.recorded_utc} ({state.baseline_dir}{temps}); "
            "only the loaded run is recorded.")
        return Selection([("loaded", True, plan)], stored, False)

    def unattended_tool_change(self, phase: str, mounted: bool) -> None:
        """An unattended session cannot ask for a tool change: refuse (a mode whose caller prepared it returns)."""
        raise RobotNotReadyError(f"the {phase} run needs the tool {'mounted' if mounted else 'removed'}, "
                                 "which an unattended run cannot ask for")

    def before_analysis(self, config: Config, opts: RunOptions, state: RobotState, run_dir, out):
        """Anything fitted from the recording before its analysis (the calibration's gains); returns it."""
        return None


class Identify(Mode):
    name, command = "identify", "run"
    may_apply = True


class Baseline(Mode):
    name, command = "baseline", "baseline"
    uses_calibration = False
    keeps_results = False
    analyses = False
    empties_flange = True

    def select(self, config, plan, opts, state, current, info, out) -> Selection:
        return Selection([("empty", False, plan)], None, True)

    def unattended_tool_change(self, phase: str, mounted: bool) -> None:
        return  # `baseline --unattended`: the cell controller has emptied the flange


class Calibrate(Mode):
    name, command = "calibrate", "calibrate"
    uses_calibration = False  # it makes the calibration (the run folder keeps a copy of any stored one)
    keeps_results = False  # a reference payload, not a tool

    def validate(self, opts: RunOptions) -> None:
        if opts.reference is None:
            raise PayloadAgentError("calibrate needs the reference payload (--known-mass, --known-cog)")

    def before_analysis(self, config, opts, state, run_dir, out):
        from payload_agent.evaluation.calibration import fit_gains, save_calibration

        ref = opts.reference
        calibration = fit_gains(config, run_dir, ref.mass_kg, ref.cog_m)
        path = save_calibration(state.ensure(), calibration)
        out("Drive-gain calibration (fitted / nominal): " + ", ".join(
            f"J{j + 1} {calibration.scale[j]:.4f} ± {1.96 * calibration.scale_std[j]:.4f}"
            for j in calibration.fitted_joints) + f"; stored in {path}")
        if calibration.zeros is not None:  # fitted with the gains; every later run corrects its angles by them
            out("Joint zeros (controller − link angle, ±1σ, fitted with the gains; the declared "
                f"robot.kinematics.zero_offset_uncertainty_deg is the prior): {calibration.zeros.describe()}")
        if calibration.reference_friction is not None:  # what a direction asymmetry left in the gains (three-step σ)
            out("Reference run's constant-friction change against the baseline (±1σ; the declared "
                "robot.friction_change_percent is the prior where the data cannot tell): "
                + calibration.reference_friction.describe())
        return calibration


MODES: dict[str, type[Mode]] = {m.name: m for m in (Identify, Baseline, Calibrate)}


class Resume(Mode):
    """The stopped run's own mode, recording only the sweeps that did not finish, into its folder."""

    resumed = True

    def __init__(self, resume: ResumeState):
        self.resume = resume
        self.inner = MODES[resume.mode]()
        self.name, self.command = self.inner.name, self.inner.command + " --resume"
        for flag in ("uses_calibration", "may_apply", "keeps_results", "analyses", "empties_flange"):
            setattr(self, flag, getattr(self.inner, flag))

    def select(self, config, plan, opts, state, current, info, out) -> Selection:
        r = self.resume
        r.check_controller(info)
        todo = [(p, m, remaining_plan(config, plan, done)) for p, m, done in r.phases]
        out(f"Resuming {r.run_dir}: " + "; ".join(
            f"{p} run, {len(sub.sweeps)} of {len(plan.sweeps)} sweeps left" for p, _, sub in todo))
        return Selection(todo, r.stored_info, r.store_empty)

    def unattended_tool_change(self, phase, mounted) -> None:
        self.inner.unattended_tool_change(phase, mounted)

    def before_analysis(self, config, opts, state, run_dir, out):
        return self.inner.before_analysis(config, opts, state, run_dir, out)


def mode_for(opts: RunOptions) -> Mode:
    """The mode ``opts`` names, its options checked."""
    if opts.mode not in MODES:
        raise ValueError(f"unknown mode {opts.mode!r}")
    mode = MODES[opts.mode]()
    mode.validate(opts)
    return mode
