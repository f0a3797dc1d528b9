"""Everything after the recorder: segment, subtract the baseline, combine directions, solve, check.

``payload-agent solve RUN_DIR`` and ``run`` both come through here, so a recorded
run can always be re-analysed and gives the same answer.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from payload_agent.evaluation import quality, systematics
from payload_agent.evaluation.calibration import (RUN_CALIBRATION, effective_calibration, effective_gains,
                                                  run_calibration)
from payload_agent.analysis.delta import DeltaSweep
from payload_agent.analysis.run_deltas import check_segmentation, deltas_for, phases_for
from payload_agent.configuration.config import Config
from payload_agent.errors import DataError
from payload_agent.model.kinematics import Kinematics
from payload_agent.types import SweepKey
from payload_agent.recording.rundata import load_manifest
from payload_agent.solvers.results import Estimate, RunResult
from payload_agent.solvers import SOLVERS, general, three_step

POSE_AGREEMENT_Z = quality.POSE_AGREEMENT_Z  # kept for callers that imported it from here
__all__ = ["deltas_for", "solve_all", "quality_checks", "analyse_run", "check_baseline_segmentation",
           "POSE_AGREEMENT_Z"]


def solve_all(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, primary: str,
              gain_rel_std: Sequence[float] | None = None, length_std_m: float | None = None,
              gain_reference: tuple[Sequence[float], Sequence[int]] | None = None
              ) -> tuple[Estimate, list[Estimate]]:
    """The primary solver's estimate, plus every other solver's that can be computed on the same data.

    ``gain_rel_std`` (relative drive-gain uncertainty per joint, from a calibration) and
    ``length_std_m`` (standard uncertainty of the DH lengths; ``gain_reference``: the calibration's
    reference θ and fitted joints, see ``general.kinematic_covariance``) go into the general
    solver's covariance; the three-step solver takes the drive-gain term of joints 2 and 3.
    """
    if primary not in SOLVERS:
        raise DataError(f"unknown solver {primary!r}; available: {', '.join(SOLVERS)}")

    def run(name: str) -> Estimate:
        if name == general.NAME and (gain_rel_std is not None or length_std_m):
            return general.solve(deltas, kin, gain_rel_std=gain_rel_std, length_std_m=length_std_m,
                                 gain_reference=gain_reference)
        if name == three_step.NAME and gain_rel_std is not None:
            return three_step.solve(deltas, kin, gain_rel_std=gain_rel_std)
        return SOLVERS[name](deltas, kin)

    main = run(primary)
    others = []
    for name in SOLVERS:
        if name == primary:
            continue
        try:
            others.append(run(name))
        except DataError as exc:
            main.notes.append(f"{name} not computed: {exc}")
    return main, others


def quality_checks(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, primary: Estimate,
                   gain_rel_std: Sequence[float] | None = None, length_std_m: float | None = None,
                   gain_reference: tuple[Sequence[float], Sequence[int]] | None = None,
                   others: Sequence[Estimate] = (), syst: systematics.Systematics | None = None) -> dict[str, Any]:
    """Redundant checks recorded beside the result; ``payload_agent.evaluation.quality.require_passed`` enforces them.

    The uncertainty terms are those the primary estimate was solved with (see ``solve_all``): the
    pose-agreement check propagates the same drive-gain and DH-length uncertainty through both poses.
    The primary estimate is checked whichever solver made it, against ``others`` too.
    """
    return quality.evaluate(deltas, kin, primary, gain_rel_std=gain_rel_std, length_std_m=length_std_m,
                            gain_reference=gain_reference, others=others, systematics=syst)


def analyse_run(config: Config, run_dir: Path, solver: str | None = None, baseline_dir: Path | None = None,
                gains: Sequence[float] | None = None) -> RunResult:
    """Segment, subtract, combine, solve and check one run folder; the result is returned, not written.

    Drive gains: the calibration recorded with the run (``RUN_DIR/calibration.json``, copied in when the
    run began, so the live run, ``solve`` and ``--resume`` agree) if there is one, else ``gains`` if given
    (``solve``: the manifest's), else the robot's valid calibration (``state/<robot>/gains.json``; for
    folders written by other tools) if there is one, else the config's nominal gains. Which were used goes into the result
    (``gains_nm_per_unit``, ``gains_source``) and the primary estimate's notes. With a
    calibration, its per-joint uncertainty is part of the general solver's covariance; with
    nominal gains the reported uncertainty cannot include the gain error, and a note says so.
    The DH lengths' uncertainty (``robot.kinematics.length_uncertainty_mm``) is always part of it,
    and so are a real arm's systematic errors (``evaluation.systematics``): the declared joint
    stiffness is compensated in both runs before the subtraction, and its uncertainty, the joint
    zeros', the friction the two-direction average leaves and constant wrist torques go into the
    general solver's covariance and into the quality gate's pose comparison.
    """
    gain_rel_std = gain_reference = None
    cal = run_calibration(run_dir)  # the copy the session made when the run began: solve uses the same
    if cal is not None:
        gains_arr = np.asarray(cal.gains_nm_per_unit, float)
        note = (f"drive gains from the calibration of {cal.created_utc[:10]} recorded with the run "
                f"({RUN_CALIBRATION}, reference {cal.reference_mass_kg:.3f} kg; joints "
                f"{', '.join(str(j + 1) for j in cal.fitted_joints)} fitted, others nominal)")
    elif gains is not None:
        gains_arr, note = np.asarray(gains, float), None
    else:
        gains_arr, note = effective_gains(config)
        cal = effective_calibration(config) if note is not None else None
    if cal is not None:
        gain_rel_std = cal.gain_rel_std()
        m_ref = cal.reference_mass_kg
        gain_reference = ([m_ref, *(m_ref * np.asarray(cal.reference_cog_m))], cal.fitted_joints)
        source = note
    elif gains is not None:
        source = "given by the caller"
    else:
        source = "nominal (effort.gains_nm_per_unit of the config)"
        note = ("drive gains are nominal: the reported uncertainty does not include their error (a few % "
                "on most arms); run `payload-agent calibrate` with a known reference payload")
    notes: list[str] = []
    loaded, empty, commands = phases_for(run_dir, gains_arr, baseline_dir, notes=notes)
    decl = config.robot.joints
    prepared = systematics.prepare(loaded, empty, decl, commands)
    notes.extend(prepared.notes)
    deltas = prepared.deltas
    kin = config.robot.kinematics
    primary, others = solve_all(deltas, kin, solver or config.procedure.solver, gain_rel_std,
                                config.robot.length_uncertainty_m, gain_reference)
    syst = systematics.evaluate(prepared, kin, decl, gain_rel_std)
    primary, others = _with_systematics(primary, syst), [_with_systematics(e, syst) for e in others]
    primary.notes.extend(notes)
    if note:
        primary.notes.append(note)
    quality_result = quality_checks(deltas, kin, primary, gain_rel_std, config.robot.length_uncertainty_m,
                                    gain_reference, others, syst)
    extra = {"gains_nm_per_unit": [float(g) for g in gains_arr], "gains_source": source}
    if gain_rel_std is not None:
        extra["gains_rel_std"] = list(gain_rel_std)
    return RunResult(config.robot.name, str(run_dir), primary, others, quality=quality_result, extra=extra)


def _with_systematics(est: Estimate, syst: systematics.Systematics) -> Estimate:
    """The general solver's estimate widened by the systematic terms (evaluated on its fit); others unchanged."""
    if est.solver != general.NAME:
        if syst.terms:
            est.notes.append(f"the systematic terms ({syst.describe()}) are in the general solver's σ only")
        return est
    return syst.apply(est)


def check_baseline_segmentation(config: Config, run_dir: Path) -> None:
    """Raise DataError unless every sweep of the run's empty phase is complete and segments.

    A baseline is stored only after this passes, so a broken empty run never becomes the
    reference of later identifications. The windows come from the run's plan, as every later
    analysis will take them (``analysis.run_deltas.check_segmentation``).
    """
    manifest = load_manifest(run_dir)
    entries = manifest.get("phases", {}).get("empty", {}).get("sweeps", [])
    bad = [e.get("name", "?") for e in entries if e.get("status") != "complete"]
    if not entries or bad:
        raise DataError(f"{run_dir}: the empty-flange run is not complete (sweeps {', '.join(bad) or 'none'}); "
                        "it was not stored as the baseline")
    check_segmentation(run_dir, "empty")  # DataError naming every sweep without a verified window
