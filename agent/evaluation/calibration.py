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
The result lives in ``state/<robot>/gains.json`` and is valid only for the configuration
it was fitted on (robot name, effort unit, nominal gains, kinematics): ``load_calibration``
refuses it otherwise, rather than silently applying stale gains."""

from __future__ import annotations

import hashlib
import math
import json
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.analysis.delta import DeltaSweep
from payload_agent.analysis.run_deltas import phases_for
from payload_agent.evaluation import systematics, zero_offsets
from payload_agent.evaluation.systematics import gain_scatter
from payload_agent.errors import DataError, QualityGateError
from payload_agent.model.kinematics import Kinematics
from payload_agent.types import SweepKey
from payload_agent.solvers import general, wls
from payload_agent.recording.state import RobotState, write_json_atomic

FORMAT = "payload-agent-gains/1"
SCALE_MIN, SCALE_MAX = 0.8, 1.25  # a drive gain this far off nominal is a wrong reference, not a drive
MIN_SIGNAL_TO_NOISE = 5.0  # a joint is fitted when its largest |Δτ_pred| is this many residual σ
MAX_SCALE_STD = 0.01  # ... and its scale comes out to better than 1 %
# what an unfitted joint's nominal gain is assumed to be good for (datasheet torque constants and
# "rated torque / 100" conversions are typically within a few per cent): enters the uncertainty
UNFITTED_GAIN_REL_STD = 0.03
MIN_SAMPLES = 50  # per joint, over all sweeps
IMPLAUSIBLE_Z = 3.0  # a scale this many σ outside SCALE_MIN–SCALE_MAX is a wrong reference, not noise


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

    @property
    def reference(self) -> tuple:
        """(θ_ref = [m, m·c], fitted joints[, standing angles]): what the analysis subtracts the absorption with."""
        theta = [self.reference_mass_kg, *(self.reference_mass_kg * np.asarray(self.reference_cog_m))]
        base = (theta, self.fitted_joints)
        return base if self.standing_angles is None else (*base, self.standing_angles)

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
                **({} if self.zeros is None else {"zero_offsets": self.zeros.to_json()})}

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
        return cls(gains, tuple(int(j) - 1 for j in d["fitted_joints"]), scale, scale_std,
                   float(d["reference_mass_kg"]), cog, str(d["robot"]), str(d["effort_unit"]),
                   str(d["nominal_fingerprint"]), str(d["run_dir"]), str(d["created_utc"]), angles, zeros)


def calibration_fingerprint(config: Config) -> str:
    """16 hex digits over the nominal gains, effort unit and kinematics a calibration depends on."""
    data = {"unit": config.effort.unit,
            "gains": [repr(float(g)) for g in config.effort.gains_nm_per_unit],
            "dh": [[repr(float(v)) for v in (r.a_m, r.d_m, r.alpha_rad, r.offset_rad)] for r in config.robot.dh]}
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def _groups_by_joint(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics,
                     theta: np.ndarray) -> dict[int, list[tuple[np.ndarray, np.ndarray, bool]]]:
    """Per joint: (predicted Δτ, measured Δτ, needs an offset) for every sweep carrying that joint."""
    sweeps = general.select_sweeps(deltas)
    out: dict[int, list[tuple[np.ndarray, np.ndarray, bool]]] = {}
    for g, d in ((g, d) for d in sweeps for g in general.build_groups([d], kin)):
        # a moving joint in a one-direction sweep keeps friction the baseline did not remove
        offset = d.key.direction != "both" and g.joint == d.moving
        out.setdefault(g.joint, []).append((g.Y @ theta, g.y, offset))
    return out


@dataclass(frozen=True)
class JointFit:
    """One joint's gain fit against the reference payload, whether or not it was used."""

    joint: int  # 0-based
    status: str  # "fitted", "implausible", "too uncertain", "too little torque", "too few samples"
    samples: int
    scale: float | None = None  # fitted / nominal gain
    scale_std: float | None = None
    peak_torque_nm: float | None = None  # largest predicted payload torque on this joint
    noise_nm: float | None = None  # residual σ of the fit

    def to_json(self) -> dict[str, Any]:
        return {"joint": self.joint + 1, "status": self.status, "samples": self.samples, "scale": self.scale,
                "scale_std": self.scale_std, "peak_torque_nm": self.peak_torque_nm, "noise_nm": self.noise_nm}

    def describe(self) -> str:
        if self.scale is not None and self.scale_std is not None:
            return f"joint {self.joint + 1}: scale {self.scale:.4f} ± {self.scale_std:.4f} ({self.status})"
        if self.peak_torque_nm is not None:
            return (f"joint {self.joint + 1}: payload torque at most {self.peak_torque_nm:.3g} N·m against "
                    f"{self.noise_nm:.2g} N·m noise ({self.status})")
        return f"joint {self.joint + 1}: {self.samples} samples ({self.status})"


class CalibrationFailed(QualityGateError):
    """The calibration run cannot give drive gains; ``fits`` holds what every joint's fit found.

    The numbers travel with the error so that a failed calibration's report can show them.
    """

    def __init__(self, message: str, fits: Sequence[JointFit], reference_mass_kg: float,
                 reference_cog_m: Sequence[float]):
        super().__init__(message)
        self.fits = tuple(fits)
        self.reference_mass_kg = float(reference_mass_kg)
        self.reference_cog_m = tuple(float(v) for v in reference_cog_m)

    def to_json(self) -> dict[str, Any]:
        return {"error": str(self), "reference_mass_kg": self.reference_mass_kg,
                "reference_cog_mm": [1000.0 * v for v in self.reference_cog_m],
                "joints": [f.to_json() for f in self.fits]}


def fit_joint_scales(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, known_mass_kg: float,
                     known_cog_m: Sequence[float]) -> list[JointFit]:
    """Every loaded joint's gain scale against the reference payload, with a verdict each.

    The verdict order matters: a scale far outside the plausible range is a wrong reference
    (``implausible``) however uncertain it is, since a wrong mass scales the uncertainty too.
    """
    c = np.asarray(known_cog_m, float)
    theta = np.concatenate(([known_mass_kg], known_mass_kg * c))
    fits: list[JointFit] = []
    for j, parts in sorted(_groups_by_joint(deltas, kin, theta).items()):
        pred = np.concatenate([p for p, _, _ in parts])
        meas = np.concatenate([m for _, m, _ in parts])
        n = len(pred)
        offset_parts = [i for i, (_, _, off) in enumerate(parts) if off]
        X = np.zeros((n, 1 + len(offset_parts)))
        X[:, 0] = pred
        start = np.concatenate(([0], np.cumsum([len(p) for p, _, _ in parts])))
        for col, i in enumerate(offset_parts, 1):
            X[start[i]:start[i + 1], col] = 1.0
        if n < MIN_SAMPLES + X.shape[1]:
            fits.append(JointFit(j, "too few samples", n))
            continue
        coef, *_ = np.linalg.lstsq(X, meas, rcond=None)
        resid = meas - X @ coef
        dof = n - X.shape[1]
        sigma = float(np.sqrt(resid @ resid / dof))
        k = float(coef[0])
        # standard error of k with correlated residuals: Bartlett sandwich over each sweep
        XtX_inv = np.linalg.pinv(X.T @ X)
        B = np.zeros((X.shape[1], X.shape[1]))
        for i in range(len(parts)):
            sl = slice(start[i], start[i + 1])
            r = resid[sl]
            _, lag = wls.autocorrelation_time(r, max_lag=max(1, int(wls.HAC_MAX_FRACTION * len(r))))
            B += wls.long_run_scores(X[sl] * r[:, None], lag)
        k_var = max(float((XtX_inv @ B @ XtX_inv)[0, 0]), float(XtX_inv[0, 0]) * sigma ** 2) * n / dof
        peak = float(np.max(np.abs(pred)))
        if peak < MIN_SIGNAL_TO_NOISE * max(sigma, 1e-12) or not k > 0:
            fits.append(JointFit(j, "too little torque", n, peak_torque_nm=peak, noise_nm=sigma))
            continue
        s, s_std = 1.0 / k, float(np.sqrt(k_var)) / k ** 2
        outside = max(SCALE_MIN - s, s - SCALE_MAX, 0.0)
        if outside > IMPLAUSIBLE_Z * s_std:
            status = "implausible"
        elif s_std > MAX_SCALE_STD:
            status = "too uncertain"
        elif outside > 0:
            status = "implausible"
        else:
            status = "fitted"
        fits.append(JointFit(j, status, n, s, s_std, peak, sigma))
    return fits


def fit_gains_from_deltas(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, nominal_gains: Sequence[float],
                          known_mass_kg: float, known_cog_m: Sequence[float]
                          ) -> tuple[np.ndarray, np.ndarray, tuple[int, ...]]:
    """Per-joint gain scale (true / nominal), its standard uncertainty, and the joints fitted.

    ``deltas`` must have been converted to N·m with ``nominal_gains``. Joints without enough
    payload torque keep scale 1 and std 0. Raises CalibrationFailed (a QualityGateError, with
    every joint's numbers) when a scale is implausible (outside 0.8–1.25: a wrong reference
    mass or centre of mass, or the reference was not mounted) or no joint can be fitted.
    """
    nominal = np.asarray(nominal_gains, float)
    if not known_mass_kg > 0:
        raise DataError(f"the reference mass must be positive, got {known_mass_kg} kg")
    c = np.asarray(known_cog_m, float)
    fits = fit_joint_scales(deltas, kin, known_mass_kg, c)
    ref = f"{known_mass_kg:.3f} kg reference at {1000 * c[0]:.1f}, {1000 * c[1]:.1f}, {1000 * c[2]:.1f} mm"
    bad = [f for f in fits if f.status == "implausible"]
    if bad:
        which = "; ".join(f"joint {f.joint + 1} would need {f.scale:.3f} ± {f.scale_std:.3f} × its nominal "
                          "drive gain" for f in bad)
        implied = known_mass_kg / float(np.median([f.scale for f in bad]))
        raise CalibrationFailed(
            f"calibration: {which} (plausible {SCALE_MIN:g}–{SCALE_MAX:g}). Drive gains are not that far off: "
            f"the measured payload torque does not match a {ref}; it fits about {implied:.3f} kg there. "
            f"Check --known-mass and --known-cog (kg; mm in the flange frame), and that the reference payload "
            "was mounted for the loaded run and removed for the empty one.",
            fits, known_mass_kg, c)
    fitted = [f for f in fits if f.status == "fitted"]
    if not fitted:
        skipped = "; ".join(f.describe() for f in fits) or "no usable sweep"
        raise CalibrationFailed(
            "calibration: no joint carried enough of the reference payload's torque to fit its gain "
            f"({skipped}). Use a heavier reference payload (a few kg) and check that it was mounted for "
            "the loaded run.", fits, known_mass_kg, c)
    scale = np.ones(len(nominal))
    scale_std = np.zeros(len(nominal))
    for f in fitted:
        scale[f.joint], scale_std[f.joint] = f.scale, f.scale_std
    return scale, scale_std, tuple(f.joint for f in fitted)


def fit_gains(config: Config, run_dir: Path, known_mass_kg: float, known_cog_m: Sequence[float],
              baseline_dir: Path | None = None) -> GainCalibration:
    """Fit drive gains on a recorded run (empty + loaded with the reference payload) at nominal gains.

    The declared joint stiffness is compensated in both phases first (``systematics.prepare``), as
    in every identification the gains are then used for.
    """
    nominal = np.asarray(config.effort.gains_nm_per_unit, float)
    loaded, empty, commands = phases_for(Path(run_dir), nominal, baseline_dir)
    deltas = systematics.prepare(loaded, empty, config.robot.joints, commands).deltas
    scale, scale_std, fitted = fit_gains_from_deltas(deltas, config.robot.kinematics, nominal,
                                                     known_mass_kg, known_cog_m)
    c = tuple(float(v) for v in known_cog_m)  # then the zeros of joints 2, 3 with the gains (``zero_offsets``)
    scale, scale_std, zeros = zero_offsets.refit(deltas, config.robot.kinematics, [known_mass_kg, *(
        known_mass_kg * np.asarray(c))], fitted, scale, scale_std, config.robot.joints.zero_offset_std_rad)
    return GainCalibration(
        gains_nm_per_unit=tuple(float(v) for v in nominal * scale), fitted_joints=fitted,
        scale=tuple(float(v) for v in scale), scale_std=tuple(float(v) for v in scale_std),
        reference_mass_kg=float(known_mass_kg), reference_cog_m=(c[0], c[1], c[2]),
        robot=config.robot.name, effort_unit=config.effort.unit,
        nominal_fingerprint=calibration_fingerprint(config), run_dir=str(run_dir),
        created_utc=datetime.now(timezone.utc).isoformat(timespec="seconds"),
        standing_angles=gain_scatter.standing_angles(deltas, config.robot.kinematics), zeros=zeros)


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
