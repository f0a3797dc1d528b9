"""Kinematic cross-check: the YAML's forward kinematics against the flange pose the controller reports.

The safety gate computes floor and reach checks with the YAML's DH table. If that table is
wrong (a flipped sign, a zero offset, a unit), the gate approves motions the robot then runs
somewhere else. So before any motion, and at every sweep start, the session compares FK(q)
with the controller's own flange pose and refuses on a mismatch, naming the likely cause by
trying the usual mistakes on the YAML model until one explains the reported pose.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from payload_agent.model.kinematics import Kinematics
from payload_agent.types import FlangePose


@dataclass(frozen=True)
class PoseCheck:
    ok: bool
    position_error_m: float
    rotation_error_rad: float
    fk_position_m: tuple[float, float, float]
    reported_position_m: tuple[float, float, float]
    likely_cause: str = ""

    def describe(self) -> str:
        fk = ", ".join(f"{1000 * v:.1f}" for v in self.fk_position_m)
        rep = ", ".join(f"{1000 * v:.1f}" for v in self.reported_position_m)
        text = (f"flange from the YAML kinematics: [{fk}] mm; reported by the controller: [{rep}] mm; "
                f"difference {1000 * self.position_error_m:.1f} mm, {math.degrees(self.rotation_error_rad):.2f}°")
        if not self.ok:
            text += ". " + (f"Likely cause: {self.likely_cause}." if self.likely_cause else
                            "No single usual mistake explains it: check the DH table against the vendor's, "
                            "the joint zero offsets and the units (mm, degrees).")
        return text

    def to_json(self) -> dict:
        return {"ok": self.ok, "position_error_mm": round(1000 * self.position_error_m, 3),
                "rotation_error_deg": round(math.degrees(self.rotation_error_rad), 4),
                "fk_position_mm": [round(1000 * v, 2) for v in self.fk_position_m],
                "reported_position_mm": [round(1000 * v, 2) for v in self.reported_position_m],
                "likely_cause": self.likely_cause}


def _errors(T: np.ndarray, pose: FlangePose) -> tuple[float, float]:
    dp = float(np.linalg.norm(T[:3, 3] - np.asarray(pose.position_m, float)))
    R = np.asarray(pose.rotation, float)
    c = (np.trace(T[:3, :3].T @ R) - 1.0) / 2.0
    return dp, float(math.acos(max(-1.0, min(1.0, c))))


def compare_pose(kinematics: Kinematics, q: Sequence[float], pose: FlangePose, tol_m: float,
                 tol_rad: float) -> PoseCheck:
    T = kinematics.flange(q)
    dp, dr = _errors(T, pose)
    ok = dp <= tol_m and dr <= tol_rad
    cause = "" if ok else likely_cause(kinematics, q, pose, tol_m, tol_rad)
    return PoseCheck(ok, dp, dr, tuple(float(v) for v in T[:3, 3]), tuple(float(v) for v in pose.position_m), cause)


def _candidates(kin: Kinematics, q: np.ndarray):
    rows = kin.rows
    for j, row in enumerate(rows):
        n = j + 1
        for field, label in (("a_m", "a"), ("d_m", "d")):
            if getattr(row, field) != 0.0:
                new = list(rows)
                new[j] = dataclasses.replace(row, **{field: -getattr(row, field)})
                yield f"the sign of {label}{n} (robot.kinematics.dh[{j}].{label}_mm)", Kinematics(new), q
        for deg in (90.0, -90.0, 180.0):
            new = list(rows)
            new[j] = dataclasses.replace(row, offset_rad=row.offset_rad + math.radians(deg))
            yield (f"the zero offset of joint {n} (robot.kinematics.dh[{j}].offset_deg is off by {deg:+g}°)",
                   Kinematics(new), q)
        q2 = q.copy()
        q2[j] = -q2[j]
        yield f"the direction (sign) of joint {n}", kin, q2
    # pairs of sign flips: copying a DH table between conventions often flips a2 and a3 together
    flips = [(j, f) for j, r in enumerate(rows) for f in ("a_m", "d_m") if getattr(r, f) != 0.0]
    for i, (j1, f1) in enumerate(flips):
        for j2, f2 in flips[i + 1:]:
            new = list(rows)
            new[j1] = dataclasses.replace(new[j1], **{f1: -getattr(new[j1], f1)})
            new[j2] = dataclasses.replace(new[j2], **{f2: -getattr(new[j2], f2)})
            yield (f"the signs of {f1[0]}{j1 + 1} and {f2[0]}{j2 + 1} (robot.kinematics.dh[{j1}] and dh[{j2}]); "
                   "DH tables copied between conventions often differ exactly so", Kinematics(new), q)


def likely_cause(kinematics: Kinematics, q: Sequence[float], pose: FlangePose, tol_m: float, tol_rad: float) -> str:
    """The first usual mistake that, corrected in the YAML model, explains the reported pose."""
    p = np.asarray(pose.position_m, float)
    T = kinematics.flange(q)
    for factor, what in ((1000.0, "units: the controller's pose is in mm where metres were expected (or the DH "
                                  "lengths are in metres where robot.kinematics.dh wants mm)"),
                         (0.001, "units: the DH lengths look 1000 times too large (robot.kinematics.dh in mm?)")):
        if np.linalg.norm(T[:3, 3] * factor - p) <= max(tol_m, 1e-3 * np.linalg.norm(p)):
            return what
    q = np.asarray(q, float)
    for cause, kin, qq in _candidates(kinematics, q):
        dp, dr = _errors(kin.flange(qq), pose)
        if dp <= tol_m and dr <= tol_rad:
            return cause
    return ""
