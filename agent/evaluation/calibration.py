"""Drive-gain calibration with a known reference payload (``payload-agent calibrate``).

The controller reports effort in its own unit; ``effort.gains_nm_per_unit`` turns it into
N·m. Those gains are nominal (rated torque / 100, a datasheet torque constant) and on a
real arm off by a few per cent per joint — and a gain error of 3 % is a mass error of 3 %,
which no amount of averaging removes. With a payload of known mass and centre of mass on
the flange, the loaded-minus-empty torque on every joint is known exactly,
Δτ_pred = Y(q, q̇)·θ_ref, so one run of the normal procedure (empty + loaded) measures each
joint's true gain:

    Δτ_meas (at nominal gain) = k_j · Δτ_pred   ⇒   gain_j = nominal_j · s_j,  s_j = 1/k_j

k_j is fitted by least squares over the constant-speed samples of every sweep (noise is in
the measurement, so the measurement is regressed on the prediction, which keeps the fit
unbiased); bidirectional combined sweeps ("both") are preferred, since friction odd in
velocity cancels there. Where only one direction was recorded, each (sweep, joint) group
on the moving joint gets its own offset to absorb the friction the baseline left.

Only joints that carry enough of the payload's torque are fitted (in ``paper_bd``: joints 2 and 3, sometimes 5);
the others keep their nominal gain. A scale outside 0.8–1.25 is refused (a wrong reference mass, or no tool mounted).
The fitted gains are then refitted jointly with the zeros of joints 2 and 3 (``zero_offsets``: a zero shifts the
reference's torque along a sweep where a gain scales it), which are stored with them and corrected by every run.
The reference run's friction change against the baseline is measured per joint and stored too
(``systematics.reference_friction``): a direction asymmetry leaves it in the gains, where the three-step solver
reads it.
The result lives in ``state/<robot>/gains.json`` and is valid only for the configuration
it was fitted on (robot name, effort unit, nominal gains, kinematics): ``load_calibration``
refuses it otherwise, rather than silently applying stale gains."""

from __future__ import annotations

import hashlib
import math
import json
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from payload_agent.configuration.config import Config, JointSystematicsConfig
from payload_agent.analysis.run_deltas import phases_for
from payload_agent.evaluation import calibration_lengths, calibration_shares, systematics, zero_offsets
from payload_agent.evaluation.baseline_identity import empty_run_source
from payload_agent.evaluation.reference_shares import KEY as REFERENCE_SHARES, ReferenceShares
from payload_agent.evaluation.systematics import gain_scatter, reference_friction
from payload_agent.errors import DataError
from payload_agent.recording.rundata import SweepData
from payload_agent.solvers.length_response import LengthResponse
from payload_agent.types import SweepKey
from payload_agent.recording.state import RobotState, write_json_atomic
# the gain-scale fit itself (``gain_scales``), named here too: callers know it as the calibration's
from payload_agent.evaluation.gain_scales import (  # noqa: F401
    IMPLAUSIBLE_Z, MAX_SCALE_STD, MIN_SAMPLES, MIN_SIGNAL_TO_NOISE, SCALE_MAX, SCALE_MIN, UNFITTED_GAIN_REL_STD,
    CalibrationFailed, JointFit, fit_gains_from_deltas, fit_joint_scales, own_cluster_errors)

FORMAT = "payload-agent-gains/1"


@dataclass(frozen=True)
class SweptProcedure:
    """The procedure a calibration swept: how much of the arm's DH-length errors its gains and zeros absorb for a
    tool run depends on it (``length_response``; nearly all when the run sweeps the same procedure and range)."""

    name: str  # a bundled procedure's name or a procedure file's path, as the calibration's config gave it
    fingerprint: str  # the procedure file's (``Procedure.fingerprint``)
    sweep_deg: tuple[float, float]
    speed_percent: float

    @classmethod
    def of(cls, config: Config) -> "SweptProcedure":
        from payload_agent.configuration.procedure import load_procedure

        pc = config.procedure
        return cls(pc.name, load_procedure(pc.name).fingerprint, (pc.sweep_from_deg, pc.sweep_to_deg), pc.speed_percent)

    def describe(self) -> str:
        return f"{self.name}, {self.sweep_deg[0]:g}–{self.sweep_deg[1]:g}°, sweep {self.speed_percent:g} %"

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "fingerprint": self.fingerprint, "sweep_deg": list(self.sweep_deg),
                "speed_percent": self.speed_percent}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> "SweptProcedure":
        lo, hi = (float(v) for v in d["sweep_deg"])
        return cls(str(d["name"]), str(d["fingerprint"]), (lo, hi), float(d["speed_percent"]))


@dataclass(frozen=True)
class GainCalibration:
    """Per-joint drive gains fitted with a reference payload, and what they are valid for."""

    gains_nm_per_unit: tuple[float, ...]  # full vector: fitted joints replaced, others = config's
    fitted_joints: tuple[int, ...]  # 0-based
    scale: tuple[float, ...]  # fitted / nominal per joint (1.0 for unfitted)
    scale_std: tuple[float, ...]  # standard uncertainty of each scale (0 for unfitted)
    reference_mass_kg: float
    reference_cog_m: tuple[float, float, float]
    robot: str
    effort_unit: str
    nominal_fingerprint: str  # calibration_fingerprint(config) of the config it was fitted on
    run_dir: str
    created_utc: str
    # (joint 0-based, angle rad) where joints stood while others swept (``gain_scatter.standing_angles``): which
    # still-joint gain errors the calibration absorbed; None in files written before it was recorded
    standing_angles: tuple[tuple[int, float], ...] | None = None
    zeros: zero_offsets.ZeroOffsets | None = None  # joint zeros fitted with the gains (None: not measured)
    # the reference run's constant-friction change against the baseline per joint, measured (``reference_friction``);
    # None in files written before it was: a tool run's three-step σ then keeps the declared change
    reference_friction: reference_friction.ReferenceFriction | None = None
    # the folder whose empty-flange run the calibration subtracted (``baseline_identity``): a tool run against the
    # same one shares its noise (``shared_baseline``); None: not recorded (files from before, or not known)
    baseline_source: str | None = None
    # the fit's own change of its scales and zeros per metre of each DH length's error (``calibration_lengths``);
    # None in files written before it was measured: a run's length term then keeps the older rule
    length_response: LengthResponse | None = None
    procedure: SweptProcedure | None = None  # what it swept; None in files written before it was recorded
    # what its gain fit took of a constant torque on each swept joint's rows and of each still cluster's gain error,
    # measured on its own sweeps (``calibration_shares``); None in files written before: a run's friction and
    # torque-gain scatter terms then let the tool run's sweeps stand in, and say so
    reference_shares: ReferenceShares | None = None

    @property
    def reference(self) -> tuple:
        """(θ_ref = [m, m·c], fitted joints[, standing angles[, reference friction[, length response[, reference
        shares]]]]): what the analysis subtracts the absorption with, and what the reference run's friction changed
        by (written only with the standing angles, which every calibration since both were recorded has)."""
        theta = [self.reference_mass_kg, *(self.reference_mass_kg * np.asarray(self.reference_cog_m))]
        base = (theta, self.fitted_joints)
        if self.standing_angles is None:
            return base
        stood = (*base, self.standing_angles)
        if self.reference_shares is not None:  # 6th entry (``reference_shares.of_reference``)
            return (*stood, self.reference_friction, self.length_response, self.reference_shares)
        if self.length_response is not None:  # 5th entry (``length_response.of_reference``)
            return (*stood, self.reference_friction, self.length_response)
        return stood if self.reference_friction is None else (*stood, self.reference_friction)

    @property
    def nominal_gains(self) -> tuple[float, ...]:
        """The config gains the calibration was fitted against (fitted / scale)."""
        return tuple(g / s for g, s in zip(self.gains_nm_per_unit, self.scale))

    def gain_rel_std(self, unfitted: float = UNFITTED_GAIN_REL_STD) -> tuple[float, ...]:
        """Relative standard uncertainty of every joint's gain: the fit's for fitted joints, else ``unfitted``."""
        return tuple(s if j in self.fitted_joints else unfitted for j, s in enumerate(self.scale_std))

    def to_json(self) -> dict[str, Any]:
        return {"format": FORMAT, "robot": self.robot, "effort_unit": self.effort_unit,
                "gains_nm_per_unit": list(self.gains_nm_per_unit), "fitted_joints": [j + 1 for j in self.fitted_joints],
                "scale": list(self.scale), "scale_std": list(self.scale_std),
                "reference_mass_kg": self.reference_mass_kg,
                "reference_cog_mm": [1000.0 * v for v in self.reference_cog_m],
                "nominal_fingerprint": self.nominal_fingerprint, "run_dir": self.run_dir,
                "created_utc": self.created_utc,
                **({} if self.standing_angles is None else
                   {"standing_angles_rad": [[j + 1, float(a)] for j, a in self.standing_angles]}),
                **({} if self.zeros is None else {"zero_offsets": self.zeros.to_json()}),
                **({} if self.reference_friction is None else
                   {"reference_friction": self.reference_friction.to_json()}),
                **({} if self.baseline_source is None else {"baseline_source_run": self.baseline_source}),
                **({} if self.length_response is None else {"length_response": self.length_response.to_json()}),
                **({} if self.procedure is None else {"procedure": self.procedure.to_json()}),
                **({} if self.reference_shares is None else {REFERENCE_SHARES: self.reference_shares.to_json()})}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "GainCalibration":
        """Inverse of ``to_json`` (joints are 1-based and the centre of mass in mm in the file)."""
        if d.get("format") != FORMAT:
            raise ValueError(f"format is {d.get('format')!r}, expected {FORMAT!r}")
        gains = tuple(float(v) for v in d["gains_nm_per_unit"])
        scale = tuple(float(v) for v in d["scale"])
        scale_std = tuple(float(v) for v in d["scale_std"])
        if not len(gains) == len(scale) == len(scale_std):
            raise ValueError("gains_nm_per_unit, scale and scale_std differ in length")
        cog = tuple(float(v) / 1000.0 for v in d["reference_cog_mm"])
        if len(cog) != 3:
            raise ValueError("reference_cog_mm must have 3 components")
        stood = d.get("standing_angles_rad")
        angles = None if stood is None else tuple((int(j) - 1, float(a)) for j, a in stood)
        zeros = None if d.get("zero_offsets") is None else zero_offsets.ZeroOffsets.from_json(d["zero_offsets"])
        fric = d.get("reference_friction")
        fric = None if fric is None else reference_friction.ReferenceFriction.from_json(fric)
        source = d.get("baseline_source_run")
        if source is not None and not isinstance(source, str):
            raise ValueError(f"baseline_source_run must be a folder name, got {source!r}")
        lengths = None if d.get("length_response") is None else LengthResponse.from_json(d["length_response"])
        swept = None if d.get("procedure") is None else SweptProcedure.from_json(d["procedure"])
        shares = None if d.get(REFERENCE_SHARES) is None else ReferenceShares.from_json(d[REFERENCE_SHARES])
        return cls(gains, tuple(int(j) - 1 for j in d["fitted_joints"]), scale, scale_std,
                   float(d["reference_mass_kg"]), cog, str(d["robot"]), str(d["effort_unit"]),
                   str(d["nominal_fingerprint"]), str(d["run_dir"]), str(d["created_utc"]), angles, zeros, fric, source,
                   lengths, swept, shares)


def calibration_fingerprint(config: Config) -> str:
    """16 hex digits over the nominal gains, effort unit and kinematics a calibration depends on."""
    data = {"unit": config.effort.unit,
            "gains": [repr(float(g)) for g in config.effort.gains_nm_per_unit],
            "dh": [[repr(float(v)) for v in (r.a_m, r.d_m, r.alpha_rad, r.offset_rad)] for r in config.robot.dh]}
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def fit_gains(config: Config, run_dir: Path, known_mass_kg: float, known_cog_m: Sequence[float],
              baseline_dir: Path | None = None) -> GainCalibration:
    """Fit drive gains on a recorded run (empty + loaded with the reference payload) at nominal gains
    (``fit_from_sweeps`` on the run folder's phases)."""
    nominal = np.asarray(config.effort.gains_nm_per_unit, float)
    loaded, empty, commands = phases_for(Path(run_dir), nominal, baseline_dir)
    cal = fit_from_sweeps(loaded, empty, config, known_mass_kg, known_cog_m, commands=commands, run_dir=str(run_dir))
    return replace(cal, baseline_source=empty_run_source(Path(run_dir), baseline_dir))


def fit_from_sweeps(loaded: Mapping[SweepKey, SweepData], empty: Mapping[SweepKey, SweepData], config: Config,
                    known_mass_kg: float, known_cog_m: Sequence[float], *, joints: JointSystematicsConfig | None = None,
                    commands: Mapping | None = None, run_dir: str = "") -> GainCalibration:
    """The calibration of a reference run's sweeps (``loaded``, effort in N·m at the config's nominal gains) against
    the empty baseline's, pure: what ``fit_gains`` does on a run folder and the accuracy benchmark on its simulated
    reference run, so that the benchmark measures what ``calibrate`` stores.

    1. the declared joint stiffness is compensated in both runs (``systematics.prepare``), as in every
       identification the gains are then used for;
    2. the gain scales of the loaded joints (``gain_scales``), then refitted with the zeros of joints 2 and 3
       (``zero_offsets``);
    3. the reference run's constant-friction change against the baseline per joint, measured with the prior of
       the declared change (``systematics.reference_friction``): what a direction asymmetry left in the gains;
    4. the fit's own response to each DH length's error (``calibration_lengths``: steps 2 on shifted torques);
    5. what the gain fit took of a constant torque on each swept joint's rows and of each still cluster's gain
       error (``calibration_shares``), which a tool run's friction and torque-gain scatter terms read, and the still
       clusters' own gain errors (the joint fit's, else the gain fit's), which a tool run standing at the same angles
       takes off those rows (``calibration_clusters``).

    ``joints``: the declared systematics (default the config's ``robot.joints``); ``commands``: the plan's sweep
    commands (constant-speed windows); ``run_dir``: recorded as given."""
    decl = config.robot.joints if joints is None else joints
    nominal = np.asarray(config.effort.gains_nm_per_unit, float)
    prepared = systematics.prepare(loaded, empty, decl, commands)
    deltas, kin = prepared.deltas, config.robot.kinematics
    c = tuple(float(v) for v in known_cog_m)
    theta_ref = [known_mass_kg, *(known_mass_kg * np.asarray(c))]

    scale, scale_std, fitted = fit_gains_from_deltas(deltas, kin, nominal, known_mass_kg, known_cog_m)
    scale, scale_std, zeros, own = zero_offsets.refit(deltas, kin, theta_ref, fitted, scale, scale_std,
                                                      decl.zero_offset_std_rad)
    if own is None:  # no zeros fitted: the still clusters' own gain errors as the gain fit alone measured them
        own = own_cluster_errors(fit_joint_scales(deltas, kin, known_mass_kg, known_cog_m))
    shift = lambda z: np.zeros(len(nominal)) if z is None else z.shift_rad()  # noqa: E731

    def refitted(ds):  # the same fit of the same joints on shifted torques: (scales, zero shifts)
        s, s_std, _ = fit_gains_from_deltas(ds, kin, nominal, known_mass_kg, known_cog_m)
        s = np.where(np.isin(np.arange(len(nominal)), fitted), s, scale)
        s, _, z, _ = zero_offsets.refit(ds, kin, theta_ref, fitted, s, s_std, decl.zero_offset_std_rad)
        return s, shift(z)

    lengths = calibration_lengths.measure(deltas, kin, theta_ref, refitted, (scale, shift(zeros)))
    fric = reference_friction.measure(prepared.loaded, prepared.empty, deltas, commands, decl.friction_change_std)
    return GainCalibration(
        gains_nm_per_unit=tuple(float(v) for v in nominal * scale), fitted_joints=fitted,
        scale=tuple(float(v) for v in scale), scale_std=tuple(float(v) for v in scale_std),
        reference_mass_kg=float(known_mass_kg), reference_cog_m=(c[0], c[1], c[2]),
        robot=config.robot.name, effort_unit=config.effort.unit,
        nominal_fingerprint=calibration_fingerprint(config), run_dir=run_dir,
        created_utc=datetime.now(timezone.utc).isoformat(timespec="seconds"),
        standing_angles=gain_scatter.standing_angles(deltas, kin), zeros=zeros, reference_friction=fric,
        length_response=lengths, procedure=SweptProcedure.of(config),
        reference_shares=calibration_shares.measure(deltas, kin, theta_ref, fitted, own))


def save_calibration(state: RobotState, cal: GainCalibration) -> Path:
    """Write ``state/<robot>/gains.json`` atomically; returns its path."""
    write_json_atomic(state.gains_path, cal.to_json())
    return state.gains_path


def load_calibration(state: RobotState, config: Config) -> GainCalibration | None:
    """The stored calibration if there is one and it fits ``config``; None if there is none.

    Raises DataError naming the file when it cannot be read or was fitted on another
    configuration (robot, effort unit, nominal gains or kinematics changed).
    """
    path = state.gains_path
    if not path.exists():
        return None
    redo = (f"run `payload-agent calibrate --robot {config.source} --known-mass KG --known-cog X,Y,Z` again, "
            f"or delete {path} to use the nominal gains")
    try:
        cal = GainCalibration.from_json(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DataError(f"{path}: cannot read the drive-gain calibration ({exc}); {redo}") from None
    problems = []
    if cal.robot != config.robot.name:
        problems.append(f"it is for robot {cal.robot!r}, the config is {config.robot.name!r}")
    if cal.effort_unit != config.effort.unit:
        problems.append(f"it was fitted for effort unit {cal.effort_unit!r}, the config says {config.effort.unit!r}")
    nominal = np.asarray(config.effort.gains_nm_per_unit, float)
    if len(cal.nominal_gains) != len(nominal) or not np.allclose(cal.nominal_gains, nominal, rtol=1e-9, atol=0):
        problems.append(f"effort.gains_nm_per_unit changed since (was {[round(g, 6) for g in cal.nominal_gains]}, "
                        f"now {list(config.effort.gains_nm_per_unit)})")
    if not problems and cal.nominal_fingerprint != calibration_fingerprint(config):
        problems.append("the kinematics (DH parameters) changed since" + _dh_changes(cal.run_dir, config)
                        + " (an edit by mistake: undo it; a deliberate one: calibrate again)")
    if problems:
        raise DataError(f"{path}: the drive-gain calibration of {cal.created_utc} does not match "
                        f"{config.source}: {'; '.join(problems)}. {redo[0].upper()}{redo[1:]}.")
    return cal


def _dh_changes(run_dir: str, config: Config) -> str:
    """``: robot.kinematics.dh[1].a_mm 418 then, -418 now`` from the calibration run's manifest, so that the
    DH edit itself is named (the mistake to look at), not only the calibration it invalidated; "" if unreadable."""
    try:
        then = json.loads((Path(run_dir) / "manifest.json").read_text(encoding="utf-8"))["config"]["robot"][
            "kinematics"]["dh"]
        then_rows = [[float(r.get(k, 0.0)) for k in ("a_mm", "d_mm", "alpha_deg", "offset_deg")] for r in then]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return ""
    now_rows = [[1000 * r.a_m, 1000 * r.d_m, math.degrees(r.alpha_rad), math.degrees(r.offset_rad)]
                for r in config.robot.dh]
    changes = [f"robot.kinematics.dh[{i}].{k} {a:g} then, {b:g} now" for i, (ra, rb) in enumerate(zip(then_rows, now_rows))
               for k, a, b in zip(("a_mm", "d_mm", "alpha_deg", "offset_deg"), ra, rb) if abs(a - b) > 1e-9]
    return (": " + "; ".join(changes)) if changes else ""


RUN_CALIBRATION = "calibration.json"  # the copy of the calibration a run was recorded with, in its folder


def run_calibration(run_dir: Path) -> GainCalibration | None:
    """The drive-gain calibration a run folder was recorded with (copied in when the run began), or None."""
    path = Path(run_dir) / RUN_CALIBRATION
    if not path.exists():
        return None
    try:
        return GainCalibration.from_json(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DataError(f"{path}: cannot read the run's drive-gain calibration ({exc})") from None


def effective_gains(config: Config) -> tuple[np.ndarray, str | None]:
    """The gains the analysis should use (calibrated if a valid calibration exists) and a note saying so."""
    state = RobotState.for_config(config)
    cal = load_calibration(state, config)
    if cal is None:
        return np.asarray(config.effort.gains_nm_per_unit, float), None
    joints = ", ".join(str(j + 1) for j in cal.fitted_joints)
    note = (f"drive gains from calibration of {cal.created_utc[:10]} ({state.gains_path}, reference "
            f"{cal.reference_mass_kg:.3f} kg; joints {joints} fitted, others nominal)")
    return np.asarray(cal.gains_nm_per_unit, float), note


def effective_calibration(config: Config) -> GainCalibration | None:
    """The valid stored calibration for ``config`` or None (for the uncertainty of the gains)."""
    return load_calibration(RobotState.for_config(config), config)
