"""The one analysis recipe, pure: a run's sweeps in, the result out; it reads and writes no file.

``analyse`` is what ``payload-agent run`` / ``solve`` (through ``pipeline.analyse_run``, which reads the run
folder), the report's residual figure and the accuracy benchmark all call, so the three can never drift:

1. the joint zeros a calibration measured are corrected (``zero_offsets``) and the declared joint stiffness is
   compensated in the loaded and the empty run alike, then the baseline is subtracted and the two directions
   combined (``systematics.prepare``), and the still rows standing at the calibration's angles lose its
   per-angle gain errors (``calibration_clusters``);
2. ONE fitted model of those deltas is made (``general.fit_model``: the weighted fit, its per-pose fits
   and the fits with nuisance offsets, each made once) and handed to every consumer;
3. every solver of ``solvers.SOLVERS`` solves on it (the chosen one first), the real arm's systematic
   terms are evaluated on it (``systematics.evaluate``) and widen the estimates of the solvers that carry
   them, and the quality gate checks it (``quality.evaluate``).

Inputs are typed: ``AnalysisOptions`` (what the robot's configuration declares) and ``Gains`` (the drive
gains the efforts were converted with, and what is known about their error).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from payload_agent.configuration.config import Config, JointSystematicsConfig
from payload_agent.errors import DataError
import numpy as np

from payload_agent.evaluation import quality, shared_baseline, systematics, zero_offsets
from payload_agent.evaluation.systematics import compliance
from payload_agent.evaluation.zero_offsets import ZeroOffsets
from payload_agent.model.kinematics import Kinematics
from payload_agent.recording.rundata import SweepData
from payload_agent.solvers import SOLVERS, general, three_step
from payload_agent.solvers.fitted import FittedModel
from payload_agent.solvers.results import Estimate, RunResult
from payload_agent.types import SweepKey


@dataclass(frozen=True)
class AnalysisOptions:
    """What the analysis takes from the robot's configuration."""

    kin: Kinematics
    joints: JointSystematicsConfig  # declared stiffness, zero, friction uncertainties (``robot.joints``)
    length_std_m: float | None  # standard uncertainty of the DH lengths
    solver: str  # the primary solver, a key of ``solvers.SOLVERS``

    @classmethod
    def from_config(cls, config: Config, solver: str | None = None) -> "AnalysisOptions":
        return cls(config.robot.kinematics, config.robot.joints, config.robot.length_uncertainty_m,
                   solver or config.procedure.solver)


@dataclass(frozen=True)
class Gains:
    """The drive gains the efforts are in N·m with, and what is known about their error."""

    nm_per_unit: tuple[float, ...]
    source: str  # recorded as the result's ``gains_source``
    note: str | None = None  # added to the primary estimate's notes
    rel_std: tuple[float, ...] | None = None  # a calibration's relative uncertainty per joint
    reference: tuple | None = None  # (θ_ref, fitted joints[, standing angles]) of the calibration (GainCalibration.reference)
    zeros: ZeroOffsets | None = None  # the joint zeros the calibration measured with the gains (``zero_offsets``)
    # the calibration's reference run was subtracted against this run's own empty baseline: their noise is correlated
    # (``shared_baseline``); False: unknown or another baseline, the two taken as independent
    shared_baseline: bool = False


def prepared_run(loaded: Mapping[SweepKey, SweepData], empty: Mapping[SweepKey, SweepData],
                 declared: JointSystematicsConfig, gains: Gains, commands: Mapping | None = None,
                 mount_rad: Sequence[float] | None = None) -> tuple[systematics.Prepared, JointSystematicsConfig]:
    """Step 1 with the calibration the efforts were converted with: (the prepared run, the joint declaration its
    terms use). The calibration's measured zeros correct every angle and their σ replaces the declared zeros' in the
    joint-zero term; its per-angle gain errors come off the still rows standing at its angles
    (``systematics.prepare``'s ``gain_reference``; the three steps read moving rows only). What ``analyse`` reads,
    and what a benchmark that evaluates one term of a run on its own must read too."""
    # (the cable's rest, mount_rad, is on the wrist joints, whose zeros are not measured)
    joints = zero_offsets.declaration(declared, gains.zeros)
    loaded, empty = zero_offsets.corrected(loaded, gains.zeros), zero_offsets.corrected(empty, gains.zeros)
    return systematics.prepare(loaded, empty, joints, commands, mount_rad, gains.reference), joints


def analyse(loaded: Mapping[SweepKey, SweepData], empty: Mapping[SweepKey, SweepData], options: AnalysisOptions,
            gains: Gains, *, commands: Mapping | None = None, notes: Sequence[str] = (), robot: str = "",
            run_dir: str = "", solvers: Sequence[str] | None = None,
            mount_rad: Sequence[float] | None = None) -> RunResult:
    """Compensate, subtract, combine, fit once, solve, add the systematic terms and check (module docstring).

    ``loaded``/``empty``: the raw sweeps, effort in N·m at ``gains``; ``commands``: the plan's sweep commands
    (constant-speed windows); ``notes``: what loading the sweeps found, added to the primary estimate's notes;
    ``robot``/``run_dir``: recorded in the result as given; ``solvers``: the solvers besides the primary
    (default: every one of ``solvers.SOLVERS``); ``mount_rad``: the joint angles the loaded run started from,
    where the tool was mounted (the rest angles of the tool-cable term; None: not recorded).
    """
    for name in (options.solver, *(solvers or ())):
        if name not in SOLVERS:
            raise DataError(f"unknown solver {name!r}; available: {', '.join(SOLVERS)}")
    prepared, joints = prepared_run(loaded, empty, options.joints, gains, commands, mount_rad)
    kin, deltas = options.kin, prepared.deltas
    model = general.fit_model(deltas, kin, gains.rel_std)
    syst = systematics.evaluate(prepared, kin, joints, gains.rel_std, model=model, gain_reference=gains.reference)
    primary, others = solve_all(model, options, gains, syst, solvers)
    primary, others = _with_shared_baseline(primary, model, gains), [_with_shared_baseline(e, model, gains)
                                                                      for e in others]
    zero_note = [] if gains.zeros is None else [zero_offsets.note(gains.zeros, "the drive-gain calibration")]
    primary = primary.with_notes(*notes, *prepared.notes, *([gains.note] if gains.note else []), *zero_note)
    quality_result = quality.evaluate(deltas, kin, primary, gain_rel_std=gains.rel_std,
                                      length_std_m=options.length_std_m, gain_reference=gains.reference,
                                      others=others, systematics=syst, model=model)
    extra: dict[str, Any] = {"gains_nm_per_unit": [float(g) for g in gains.nm_per_unit], "gains_source": gains.source}
    if gains.rel_std is not None:
        extra["gains_rel_std"] = list(gains.rel_std)
    if gains.zeros is not None:
        extra["zero_offsets"] = gains.zeros.to_json()
    return RunResult(robot, run_dir, primary, others, quality=quality_result, extra=extra)


def solve_all(model: FittedModel, options: AnalysisOptions, gains: Gains, syst: systematics.Systematics,
              solvers: Sequence[str] | None = None) -> tuple[Estimate, list[Estimate]]:
    """The primary solver's estimate, plus every other solver's (of ``solvers``) that can be computed on the data.

    Every solver gets the same inputs (``solvers.Solver``): the fitted model and the uncertainty terms; a
    solver uses what its method can propagate (the three-step solver: the drive gains of joints 2 and 3).
    Those that carry the systematic terms get them added last (a note says so on the others).
    """
    def run(name: str) -> Estimate:
        return SOLVERS[name].solve(model.deltas, model.kin, gain_rel_std=gains.rel_std,
                                   length_std_m=options.length_std_m, gain_reference=gains.reference, model=model)

    main = run(options.solver)
    done, failed = [(options.solver, main)], []
    for name in (SOLVERS if solvers is None else solvers):
        if name == options.solver:
            continue
        try:
            done.append((name, run(name)))
        except DataError as exc:
            failed.append(f"{name} not computed: {exc}")
    done[0] = (options.solver, main.with_notes(*failed))
    out = [_with_systematics(SOLVERS[name].systematics_key, est, syst) for name, est in done]
    return out[0], out[1:]


def _with_shared_baseline(est: Estimate, model: FittedModel, gains: Gains) -> Estimate:
    """The general fit's and the three-step solver's estimate with the correlation of the baseline's noise between
    the calibration and this run (``shared_baseline``) where both used the same empty run; any other as it is."""
    term = {general.NAME: shared_baseline.cross_covariance,
            three_step.NAME: shared_baseline.three_step_cross_covariance}.get(est.solver)
    if (not gains.shared_baseline or gains.reference is None or gains.rel_std is None or est.covariance is None
            or term is None):
        return est
    try:
        extra = term(model, gains.reference[0], gains.reference[1], gains.rel_std)
    except (DataError, np.linalg.LinAlgError):
        return est
    cov = np.asarray(est.covariance, float).copy()
    cov[:4, :4] += extra[:4, :4]
    out = compliance.with_covariance(est, cov)
    return out.with_notes(shared_baseline.note(est.mass_std_kg or 0.0, out.mass_std_kg or 0.0))


def _with_systematics(key: str | None, est: Estimate, syst: systematics.Systematics) -> Estimate:
    """An estimate widened by the systematic terms, with the sensitivities of its solver (``Solver.systematics_key``)."""
    if key is None:
        if syst.terms:
            return est.with_notes(f"the systematic terms ({syst.describe()}) are not in this solver's σ")
        return est
    return syst.apply(est, key)


__all__ = ["AnalysisOptions", "Gains", "prepared_run", "analyse", "solve_all"]
