"""A run folder in, its result out: read the sweeps and the drive gains, then the pure ``analyse.analyse``.

``payload-agent solve RUN_DIR`` and ``run`` both come through here, so a recorded
run can always be re-analysed and gives the same answer.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from payload_agent.analysis.run_deltas import check_segmentation, phases_for
from payload_agent.configuration.config import Config
from payload_agent.errors import DataError
from payload_agent.evaluation.analyse import AnalysisOptions, Gains, analyse
from payload_agent.evaluation.baseline_identity import empty_run_source, same_baseline
from payload_agent.evaluation.controller_gains import controller_gains, declared_gains, records_controller_targets
from payload_agent.evaluation.calibration import (RUN_CALIBRATION, effective_calibration, effective_gains,
                                                  run_calibration)
from payload_agent.evaluation.wrist_inertia import identify_or_none
from payload_agent.output.payload_forms import payload_forms
from payload_agent.recording.rundata import load_manifest, load_wrist_moves, mount_angles
from payload_agent.solvers.results import RunResult

__all__ = ["analyse_run", "add_inertia", "run_gains", "check_baseline_segmentation"]


def analyse_run(config: Config, run_dir: Path, solver: str | None = None, baseline_dir: Path | None = None,
                gains: Sequence[float] | None = None) -> RunResult:
    """Segment, subtract, combine, solve and check one run folder; the result is returned, not written.

    Drive gains: the calibration recorded with the run (``RUN_DIR/calibration.json``, copied in when the
    run began, so the live run, ``solve`` and ``--resume`` agree) if there is one, else the robot's valid
    calibration (``state/<robot>/gains.json``; for folders written by other tools; not when ``gains`` are
    given) if there is one; without a calibration, the constants fitted from the controller's own target
    current and target moment where the sweeps recorded them (UR; ``controller_gains``) for the joints they
    determine, else ``gains`` if given (``solve``: the manifest's nominal ones), else the config's nominal
    gains. Which were used goes into the result (``gains_nm_per_unit``, ``gains_source``) and the primary
    estimate's notes. With a
    calibration, its per-joint uncertainty is part of the general solver's covariance; with
    nominal gains the reported uncertainty cannot include the gain error, and a note says so.
    The DH lengths' uncertainty (``robot.kinematics.length_uncertainty_mm``) is always part of it,
    and so are a real arm's systematic errors (``evaluation.systematics``): the declared joint
    stiffness is compensated in both runs before the subtraction, and its uncertainty, the joint
    zeros', the friction the two-direction average leaves and a tool cable's torques on the wrist (a spring
    relaxed where the loaded phase started, ``rundata.mount_angles``, where the manifest records it) go into
    the general solver's covariance and into the quality gate's pose comparison.
    """
    gains_used = run_gains(config, run_dir, gains, baseline_dir)
    notes: list[str] = []
    loaded, empty, commands = phases_for(run_dir, np.asarray(gains_used.nm_per_unit, float), baseline_dir, notes=notes)
    result = analyse(loaded, empty, AnalysisOptions.from_config(config, solver), gains_used, commands=commands,
                     notes=notes, robot=config.robot.name, run_dir=str(run_dir), mount_rad=mount_angles(run_dir))
    return add_inertia(config, result, run_dir, baseline_dir, gains_used)


def add_inertia(config: Config, result: RunResult, run_dir: Path, baseline_dir: Path | None, gains: Gains) -> RunResult:
    """The inertia part (``evaluation.wrist_inertia``) where the run recorded wrist moves, beside the mass and CoM.

    The result gets ``inertia_com_kgm2`` and ``inertia_com_std_kgm2`` (None when refused, with the reason
    in ``inertia.refused`` and the primary estimate's notes) and every controller's form (``forms``).
    A run without wrist moves is returned unchanged.
    """
    g = np.asarray(gains.nm_per_unit, float)
    loaded = load_wrist_moves(run_dir, "loaded", g)
    empty = load_wrist_moves(Path(baseline_dir) if baseline_dir is not None else run_dir, "empty", g)
    p = result.primary
    if p.covariance is None:
        return result
    theta = np.array([p.mass_kg, *(p.mass_kg * np.asarray(p.cog_m))])
    inertia = identify_or_none(loaded, empty, config.robot.kinematics, theta, p.covariance,
                               gain_rel_std=None if gains.rel_std is None else list(gains.rel_std))
    if inertia is None:
        return result
    result.primary = p.with_notes(*inertia.notes())
    result.extra.update(inertia.to_json())
    result.extra["forms"] = payload_forms(p.mass_kg, p.cog_m, inertia.inertia_com_kgm2)
    return result


def run_gains(config: Config, run_dir: Path | None, gains: Sequence[float] | None = None,
              baseline_dir: Path | None = None) -> Gains:
    """The drive gains a run is analysed with, and what is known about their error (see ``analyse_run``).

    ``run_dir`` None: the gains a run started now would use (the stored calibration, else the controller's
    constants as the stored baseline's sweeps give them, else, when the driver records the controller's target
    signals, nominal ones with the constants' declared σ, else nominal), which is what ``plan --target-std``
    predicts with. With a calibration and a run folder: whether the run subtracts the empty run the calibration
    subtracted (``baseline_dir``: the run's baseline if not its own; ``Gains.shared_baseline``)."""
    gain_rel_std = gain_reference = None
    # the copy the session made when the run began: solve uses the same
    cal = run_calibration(run_dir) if run_dir is not None else None
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
    fitted = None
    if cal is None and config.effort.unit == "A":
        # a run started now fits them from its own sweeps; before it, the stored baseline's are the estimate;
        # none stored: the declared uncertainty when the driver records the signals, else nominal gains
        signals = run_dir if run_dir is not None else _stored_baseline(config)
        fitted = controller_gains(gains_arr, signals) if signals is not None else None
        if fitted is None and run_dir is None and records_controller_targets(config.driver_type):
            fitted = declared_gains(gains_arr)
    if fitted is not None:  # no calibration: the controller's own constants (UR target signals) over nominal ones
        return Gains(fitted.nm_per_a, fitted.source, f"drive gains: {fitted.source}", fitted.rel_std)
    if cal is not None:
        gain_rel_std = cal.gain_rel_std()
        gain_reference = cal.reference
        source = note
    elif gains is not None:
        source = "given by the caller"
    else:
        source = "nominal (effort.gains_nm_per_unit of the config)"
        note = ("drive gains are nominal: the reported uncertainty does not include their error (a few % "
                "on most arms); run `payload-agent calibrate` with a known reference payload")
    return Gains(tuple(float(g) for g in gains_arr), source, note,
                 None if gain_rel_std is None else tuple(float(v) for v in gain_rel_std),
                 None if gain_reference is None else (tuple(float(v) for v in gain_reference[0]),
                                                      tuple(int(j) for j in gain_reference[1]), *gain_reference[2:]),
                 None if cal is None else cal.zeros,
                 shared_baseline=(cal is not None and run_dir is not None
                                  and same_baseline(cal.baseline_source, empty_run_source(run_dir, baseline_dir))))


def _stored_baseline(config: Config) -> Path | None:
    """The stored empty-flange baseline's folder, or None when none is stored."""
    from payload_agent.recording.state import RobotState

    folder = RobotState.for_config(config).baseline_dir
    return folder if (folder / "manifest.json").is_file() else None


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
