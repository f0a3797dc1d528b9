"""What a drive-gain calibration's fit did with each DH-length error, and how a tool run's length term reads it.

The regressor uses the nominal DH lengths p; the arm's torques follow its true ones p + δp. The calibration
(``payload-agent calibrate``) fits gain scales and joint zeros against a reference payload on its own sweeps, so
a length error moves them: joint j's scale by ``scale_rel_per_m[k][j]``·s_j·δp_k, the zero of joint i by
``zero_rad_per_m[k][i]``·δp_k. The calibration measures that response on its own sweeps, its own reference
and its own fit (``evaluation.calibration_lengths``) and stores it; a run scaled with those gains and corrected
with those zeros then carries, per length k, besides the regressor's own error ∂Y/∂p_k·θ,

    the scaled efforts:     + scale_rel_per_m[k][j] · (Y·θ)_j           on joint j's rows
    the corrected angles:   + zero_rad_per_m[k][i] · ∂(Y·θ)/∂q_i         (q − z moved by −δz_i)

(``extra_rows``), which ``general.kinematic_sensitivities`` adds in place of the older rule (the tool run's own
sweeps standing in for the calibration's, right only when the calibration swept the same procedure).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from payload_agent.solvers.wls import Group


@dataclass(frozen=True)
class LengthResponse:
    """Per DH length (``lengths``: (row 0-based, "a"|"d"), the order of ``general.length_parameters``): the
    calibration's relative gain-scale change per joint (1/m) and zero change per joint (rad/m)."""

    lengths: tuple[tuple[int, str], ...]
    scale_rel_per_m: tuple[tuple[float, ...], ...]  # [k][j], 6 joints
    zero_rad_per_m: tuple[tuple[float, ...], ...]  # [k][i], 6 joints (0 where no zero was fitted)

    def to_json(self) -> list[dict[str, Any]]:
        """The calibration file's ``length_response`` (DH rows and joints 1-based)."""
        return [{"dh_row": r + 1, "length": f"{w}_m", "scale_rel_per_m": list(s), "zero_rad_per_m": list(z)}
                for (r, w), s, z in zip(self.lengths, self.scale_rel_per_m, self.zero_rad_per_m)]

    @classmethod
    def from_json(cls, d: Sequence[Mapping[str, Any]]) -> "LengthResponse":
        """Inverse of ``to_json``; ValueError / KeyError / TypeError on a malformed entry."""
        lengths, scales, zeros = [], [], []
        for e in d:
            which = str(e["length"])
            if which not in ("a_m", "d_m") or not 1 <= int(e["dh_row"]) <= 6:
                raise ValueError(f"length_response: dh_row must be 1–6 and length a_m or d_m, got {dict(e)}")
            s, z = [float(v) for v in e["scale_rel_per_m"]], [float(v) for v in e["zero_rad_per_m"]]
            if len(s) != 6 or len(z) != 6:
                raise ValueError("length_response: scale_rel_per_m and zero_rad_per_m need 6 entries each")
            lengths.append((int(e["dh_row"]) - 1, which[0]))
            scales.append(tuple(s))
            zeros.append(tuple(z))
        return cls(tuple(lengths), tuple(scales), tuple(zeros))


def of_reference(reference: Sequence | None) -> LengthResponse | None:
    """The response a calibration's reference tuple carries (``GainCalibration.reference``, 5th entry), or None."""
    extra = reference[4] if reference is not None and len(reference) > 4 else None
    return extra if isinstance(extra, LengthResponse) else None


def zero_joints(response: LengthResponse) -> list[int]:
    """The joints (0-based) whose zeros the calibration's fit moved with some length."""
    return [i for i in range(6) if any(abs(z[i]) > 0 for z in response.zero_rad_per_m)]


def extra_rows(response: LengthResponse, params: Sequence[tuple[int, str]], groups: list[Group], theta: np.ndarray,
               dq: Mapping[int, np.ndarray]) -> list[np.ndarray]:
    """Per length of ``params`` (``general.length_parameters``): what the calibration's response adds to the
    run's rows per metre of that length's error (module docstring). ``dq``: ∂(Y·θ)/∂q_i over the stacked rows
    for every joint of ``zero_joints(response)`` (``general.angle_derivatives``). Raises ValueError when the
    response was measured for other lengths (another kinematics: the calibration's fingerprint prevents it)."""
    if tuple(params) != tuple(response.lengths):
        raise ValueError(f"the calibration's length response is for DH lengths {response.lengths}, "
                         f"the kinematics has {tuple(params)}")
    pred = np.concatenate([g.Y @ theta for g in groups])
    joint_of_row = np.repeat([g.joint for g in groups], [len(g.y) for g in groups])
    out = []
    for s, z in zip(response.scale_rel_per_m, response.zero_rad_per_m):
        v = np.asarray(s, float)[joint_of_row] * pred
        for i in zero_joints(response):
            v = v + z[i] * dq[i]
        out.append(v)
    return out


__all__ = ["LengthResponse", "of_reference", "zero_joints", "extra_rows"]
