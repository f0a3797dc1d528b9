"""The drive-gain calibration's own response to what its reference run carries besides the reference payload.

Two systematic terms of a calibrated tool run read the calibration's fit of the gains of joints 2 and 3 (and 5):

- the residual friction: a direction asymmetry leaves a constant torque b_k on joint k's rows where it swept in
  both directions; the fit of joint j's scale took ε_jk·b_k of it (relative, per N·m), and every calibrated tool
  run is off by −ε_jk·b_k on joint j's rows (``reference_friction.reference_columns``, both solvers);
- the torque-gain scatter: a joint standing at one angle while another swept carries a gain error ε_c of that
  angle (gear ripple under load); the fit of that joint's scale took the share w_c of it
  (``gain_scatter.absorbed_shares``; the general fit, the wrist and cable terms and the three-step solver).

Both are properties of the calibration's sweeps and its reference payload alone, not of the tool run. Until this
was stored the run computed them on its own sweeps standing in for the calibration's, right only when both
swept the same procedure: after a calibration on j2_quarter and a run on paper_bd (or the reverse) the
friction column was 1.5× off, a joint-3 column invented or missing and joint 3's share 2× off
(docs/benchmarks.md, session 17). ``calibrate`` now measures both on its own sweeps with the same projection
the run used (``general.absorbed_length_error``: the per-joint least-squares fit of ``gain_scales``, each
one-direction moving group's mean removed) and stores them in gains.json (``reference_shares``); a run reads
them and falls back to its own sweeps only for a file without them (its notes say so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.solvers.wls import Group

KEY = "reference_shares"  # gains.json's key
SCALES = "still_cluster_scales"  # its entry of the still clusters' own gain errors (optional)
SIGNED = "still_cluster_signed_scales"  # ... of a never-turning joint's, per sign of the torque (optional)
# said in a result's notes when the run's own sweeps stood in (a calibration stored before this was measured)
STAND_IN_NOTE = ("the calibration's fit taken as the tool run's sweeps would give it (its gains.json predates the "
                 "stored reference_shares; calibrate again to use its own)")


@dataclass(frozen=True)
class ReferenceShares:
    """What the calibration's gain fit took of a constant torque or a still joint's gain error in its reference run.

    ``friction_rel_per_nm``: (fitted joint j, joint k, ε_jk): the relative change of joint j's fitted
    measured/predicted ratio per N·m of a constant torque on joint k's rows where k swept in both directions
    (0-based; a pair absent: 0, joint k never swept both ways there). ``clusters``: (joint, angle rad, w): the share
    of a relative gain error on the rows where that joint stood at that angle, for the fitted joints."""

    friction_rel_per_nm: tuple[tuple[int, int, float], ...]
    clusters: tuple[tuple[int, float, float], ...]
    # (joint, angle rad, ε, σ_ε): the relative gain error the calibration measured for that still cluster against the
    # joint's fitted gain (its own scale, ``gain_scales.own_scales``), which a tool run standing there takes off its
    # rows (``calibration_clusters``); () in files written before it was stored: those rows keep it (today's rule)
    scales: tuple[tuple[int, float, float, float], ...] = ()
    # (joint, angle rad, torque sign ±1, ε, σ_ε): the same for a joint that never turned in the calibration, relative
    # to its gain, for the rows where the reference's torque had that sign (``still_joint_scales``); () before session 26
    signed_scales: tuple[tuple[int, float, int, float, float], ...] = ()

    def friction(self, fitted: Sequence[int], joints: Sequence[int]) -> dict[int, np.ndarray]:
        """Per fitted joint j: (len(joints),) ε_jk for each joint k of ``joints`` (0 where k never swept both ways)."""
        table = {(j, k): e for j, k, e in self.friction_rel_per_nm}
        return {int(j): np.array([table.get((int(j), int(k)), 0.0) for k in joints]) for j in fitted}

    def friction_joints(self) -> list[int]:
        """The joints whose rows in the reference run the fit read a constant torque on."""
        return sorted({k for _, k, _ in self.friction_rel_per_nm})

    def share(self, joint: int, angle_rad: float, tol_rad: float) -> float | None:
        """w of the cluster where ``joint`` stood at ``angle_rad`` (within ``tol_rad``); None: it did not stand there."""
        near = [(abs(a - angle_rad), w) for j, a, w in self.clusters if j == joint and abs(a - angle_rad) <= tol_rad]
        return min(near)[1] if near else None

    def own_scale(self, joint: int, angle_rad: float, tol_rad: float, sign: int = 0) -> tuple[float, float] | None:
        """(ε, σ_ε) of the cluster where ``joint`` stood at ``angle_rad`` (within ``tol_rad``), for a never-turning
        joint where its torque had ``sign`` (0: unknown, none of those); None: none stored."""
        near = [(abs(a - angle_rad), (e, sd)) for j, a, e, sd in self.scales
                if j == joint and abs(a - angle_rad) <= tol_rad]
        near += [(abs(a - angle_rad), (e, sd)) for j, a, sg, e, sd in self.signed_scales
                 if j == joint and sg == sign != 0 and abs(a - angle_rad) <= tol_rad]
        return min(near)[1] if near else None

    def scaled_joints(self) -> list[int]:
        """The joints with a stored per-angle gain error."""
        return sorted({j for j, *_ in self.scales} | {j for j, *_ in self.signed_scales})

    def to_json(self) -> dict[str, Any]:
        """gains.json's ``reference_shares`` (joints 1-based; angles in rad, as ``standing_angles_rad``)."""
        return {"friction_rel_per_nm": [{"fitted_joint": j + 1, "rows_of_joint": k + 1, "value": e}
                                        for j, k, e in self.friction_rel_per_nm],
                "still_clusters": [{"joint": j + 1, "angle_rad": a, "share": w}
                                   for j, a, w in self.clusters],
                **({} if not self.scales else
                   {SCALES: [{"joint": j + 1, "angle_rad": a, "gain_error": e, "std": sd}
                             for j, a, e, sd in self.scales]}),
                **({} if not self.signed_scales else
                   {SIGNED: [{"joint": j + 1, "angle_rad": a, "torque_sign": sg, "gain_error": e, "std": sd}
                             for j, a, sg, e, sd in self.signed_scales]})}

    @classmethod
    def from_json(cls, d: Any) -> "ReferenceShares":
        """Inverse of ``to_json``; ValueError naming the entry when one is malformed."""
        if not isinstance(d, Mapping):
            raise ValueError(f"{KEY} must be an object with friction_rel_per_nm and still_clusters, got {d!r}")
        friction, clusters = [], []
        for where, fields, out in (("friction_rel_per_nm", ("fitted_joint", "rows_of_joint", "value"), friction),
                                   ("still_clusters", ("joint", "angle_rad", "share"), clusters)):
            entries = d.get(where)
            if not isinstance(entries, list):
                raise ValueError(f"{KEY}.{where} must be a list, got {entries!r}")
            for i, e in enumerate(entries):
                try:
                    a, b, v = (e[f] for f in fields)
                    joint, value = int(a), float(v)
                    second = int(b) if where == "friction_rel_per_nm" else float(b)
                except (KeyError, TypeError, ValueError):
                    raise ValueError(f"{KEY}.{where}[{i}] needs numbers {', '.join(fields)}, got {e!r}") from None
                if not (1 <= joint <= 6 and math.isfinite(value) and math.isfinite(second)
                        and (where == "still_clusters" or 1 <= second <= 6)):
                    raise ValueError(f"{KEY}.{where}[{i}]: joints must be 1–6 and values finite, got {e!r}")
                out.append((joint - 1, second - 1, value) if where == "friction_rel_per_nm"
                           else (joint - 1, second, value))
        scales = []
        for i, e in enumerate(d.get(SCALES) or []):
            try:
                joint, row = int(e["joint"]), tuple(float(e[f]) for f in ("angle_rad", "gain_error", "std"))
            except (KeyError, TypeError, ValueError):
                raise ValueError(f"{KEY}.{SCALES}[{i}] needs numbers joint, angle_rad, gain_error, std, "
                                 f"got {e!r}") from None
            if not (1 <= joint <= 6 and all(math.isfinite(v) for v in row) and row[2] >= 0):
                raise ValueError(f"{KEY}.{SCALES}[{i}]: joint must be 1–6, values finite, std ≥ 0, got {e!r}")
            scales.append((joint - 1, *row))
        signed = []
        for i, e in enumerate(d.get(SIGNED) or []):
            try:
                joint, sign = int(e["joint"]), int(e["torque_sign"])
                a, err, sd = (float(e[f]) for f in ("angle_rad", "gain_error", "std"))
            except (KeyError, TypeError, ValueError):
                raise ValueError(f"{KEY}.{SIGNED}[{i}] needs numbers joint, angle_rad, torque_sign, gain_error, std, "
                                 f"got {e!r}") from None
            if not (1 <= joint <= 6 and sign in (-1, 1) and all(math.isfinite(v) for v in (a, err, sd)) and sd >= 0):
                raise ValueError(f"{KEY}.{SIGNED}[{i}]: joint must be 1–6, torque_sign ±1, values finite, std ≥ 0, "
                                 f"got {e!r}")
            signed.append((joint - 1, a, sign, err, sd))
        return cls(tuple(friction), tuple(clusters), tuple(scales), tuple(signed))


def of_reference(reference: Sequence | None) -> ReferenceShares | None:
    """The shares a calibration's reference tuple carries (``GainCalibration.reference``, 6th entry), or None."""
    extra = reference[5] if reference is not None and len(reference) > 5 else None
    return extra if isinstance(extra, ReferenceShares) else None


def both_way_joint(g: Group, d: DeltaSweep) -> str | None:
    """The label of a moving joint's rows in a two-direction combined sweep (the residual-friction term's rows)."""
    return str(g.joint) if g.joint == d.moving and d.key.direction == "both" else None


__all__ = ["KEY", "STAND_IN_NOTE", "ReferenceShares", "of_reference", "both_way_joint"]
