"""The analysis of a motion recorded by someone else: from two recordings to the whole payload.

Pure: it takes the two recordings (``recording.motion_csv``) and the arm's kinematics and reads
no file. The steps, each reported in the result:

1. the drives' current-to-torque constants from the controller's own target signals
   (``evaluation.torque_constants``), when the recordings carry them and no gains are given;
2. the loaded run put on the empty run's path (``analysis.motion_alignment``);
3. the ten inertial parameters from loaded − empty (``solvers.full_payload``), with the
   constants' uncertainty in the covariance;
4. the forms a user needs: mass, centre of mass, inertia about the centre of mass, σ of each,
   and whether the tensor is physically possible.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from payload_agent.analysis.motion_alignment import AlignedPair, align, resample
from payload_agent.errors import DataError
from payload_agent.evaluation.torque_constants import TorqueConstants, fit_torque_constants
from payload_agent.evaluation.inertia_support import uncertainty_problem
from payload_agent.model.kinematics import Kinematics
from payload_agent.output.payload_forms import payload_forms
from payload_agent.recording.motion_csv import MotionRecording
from payload_agent.solvers import full_payload
from payload_agent.solvers.dynamic import derivatives

KIND = "recorded-motion"
# The controller's own constant relates its model torque to its commanded current; how well that is the joint's real
# torque per ampere is not in the data. Declared (standard uncertainty, relative), added to each joint's fit σ: on the
# real UR10e pairs (docs/benchmarks.md, "Real data") the mass came out 1.3 % and 1.9 % low with these constants.
CONTROLLER_CONSTANT_REL_STD = 0.015


@dataclass(frozen=True)
class RecordedMotionResult:
    payload: full_payload.FullPayload
    alignment: AlignedPair
    gains_nm_per_unit: tuple[float | None, ...]
    gain_source: str
    constants: TorqueConstants | None
    dropped: dict[str, tuple[str, ...]]
    notes: tuple[str, ...]

    def to_json(self) -> dict:
        p = self.payload
        cog, cog_cov = p.cog()
        inertia, inertia_std = p.inertia_com()
        problem = inertia_problem(inertia, inertia_std)
        notes = list(self.notes) + list(p.notes)
        if problem:
            notes.append(f"no inertia given: {problem} (the estimate is under inertia_unsupported)")
        forms = payload_forms(p.mass_kg, cog, None if problem else inertia)
        return {
            "kind": KIND, "solver": full_payload.NAME, "forms": forms,
            "mass_kg": p.mass_kg, "mass_std_kg": p.mass_std_kg, "mass_ci95_kg": 1.96 * p.mass_std_kg,
            "cog_mm": (1000 * cog).tolist(), "cog_std_mm": (1000 * np.sqrt(np.maximum(np.diag(cog_cov), 0))).tolist(),
            "inertia_com_kgm2": None if problem else inertia.tolist(),
            "inertia_com_std_kgm2": None if problem else inertia_std.tolist(),
            "inertia_unsupported": {"reason": problem, "inertia_com_kgm2": inertia.tolist(),
                                    "inertia_com_std_kgm2": inertia_std.tolist()} if problem else None,
            "theta_si": p.theta.tolist(), "covariance_theta_si": p.cov.tolist(), "parameters": list(full_payload.PARAMS),
            "joints_used": [j + 1 for j in p.joints], "residual_rms_nm": p.residual_rms_nm, "samples": p.samples,
            "condition_number": p.condition_number,
            "gain_source": self.gain_source, "gains_nm_per_unit": list(self.gains_nm_per_unit),
            "torque_constants": self.constants.to_json() if self.constants else None,
            "alignment": self.alignment.to_json(), "dropped_rows": {k: list(v) for k, v in self.dropped.items()},
            "notes": notes,
        }


def inertia_problem(inertia: np.ndarray, std: np.ndarray) -> str | None:
    """Why the data do not support this inertia about the centre of mass, or None: physically possible, and known
    well enough (``inertia_support``)."""
    problem = full_payload.consistency_problem(inertia)
    if problem:
        return f"the data give a tensor that is {problem}"
    return uncertainty_problem(inertia, std)


def controller_constants(recordings: Sequence[MotionRecording]) -> TorqueConstants | None:
    """The constants from every recording that has both target signals and currents, else None."""
    runs = []
    for rec in recordings:
        if rec.current_a is None or rec.target_current_a is None or rec.target_moment_nm is None:
            return None
        if rec.qd is not None:  # the controller's own speed: its sign is what its friction feed-forward used
            runs.append((rec.target_current_a, rec.target_moment_nm, rec.qd))
            continue
        h = float(np.round(rec.period_s, 4))
        grid = np.arange(rec.t[0], rec.t[-1], h)
        qd = derivatives(grid, resample(rec.t, rec.q, grid))[1]
        runs.append((resample(rec.t, rec.target_current_a, grid), resample(rec.t, rec.target_moment_nm, grid), qd))
    return fit_torque_constants(runs)


def analyse_recorded_motion(empty: MotionRecording, loaded: MotionRecording, kin: Kinematics, *,
                            gains_nm_per_unit: Sequence[float] | None = None, gains_rel_std: float = 0.0,
                            gains_source: str = "") -> RecordedMotionResult:
    """The payload from two recordings of one motion. ``gains_nm_per_unit`` (all six) replaces the
    controller's constants (a calibration or the robot YAML: ``gains_source`` says which)."""
    if empty.effort_unit != loaded.effort_unit:
        raise DataError(f"recorded motion: {empty.source} gives effort in {empty.effort_unit}, {loaded.source} in "
                        f"{loaded.effort_unit}: record both the same way")
    notes: list[str] = []
    constants = None
    if gains_nm_per_unit is not None:
        gains = tuple(float(g) for g in gains_nm_per_unit)
        rel = [gains_rel_std] * len(gains)
        source = gains_source or "given"
    elif loaded.effort_unit == "Nm":
        gains, rel, source = (1.0,) * 6, [0.0] * 6, "none needed (the recordings give torque in N·m)"
    else:
        constants = controller_constants([empty, loaded])
        if constants is None:
            raise DataError("recorded motion: the recordings give motor currents but not the controller's "
                            "target_current and target_moment, so the current-to-torque constants are unknown; "
                            "give gains (--gains config uses the robot YAML's effort.gains_nm_per_unit)")
        gains = tuple(k if ok else None for k, ok in zip(constants.k_nm_per_a, constants.determined))
        rel = [float(np.hypot(s / k, CONTROLLER_CONSTANT_REL_STD)) if ok else 0.0
               for k, s, ok in zip(constants.k_nm_per_a, constants.std_nm_per_a, constants.determined)]
        source = constants.source
        for j, why in enumerate(constants.reasons):
            if why:
                notes.append(f"joint {j + 1} left out: its current-to-torque constant is not determined ({why})")
    pair = align(empty, loaded)
    payload = full_payload.solve(pair.t, pair.q, pair.effort_loaded - pair.effort_empty, kin, gains, rel)
    return RecordedMotionResult(payload, pair, gains, source, constants,
                                {"empty": empty.dropped, "loaded": loaded.dropped}, tuple(notes))
