"""The drive gains' scales against a reference payload: one least-squares fit per loaded joint, with a verdict each.

``calibration`` (``payload-agent calibrate``) uses it; the maths is in its module docstring: the measured
loaded-minus-empty torque at nominal gain is regressed on the torque the known reference predicts,
Δτ_meas = k_j·Δτ_pred, and the gain scale is s_j = 1/k_j with a sandwich (per sweep, autocorrelation-corrected)
standard error. A scale outside 0.8–1.25 is a wrong reference, not a drive. Where joint j stands in a sweep and
moves in another, that sweep's rows get a scale of their own, one per standing angle (``own_scales``): a standing strain-wave
gear's load-dependent mesh ripple is a gain error of that angle alone, so k_j comes from the rows where j turns. A joint
that turns in no sweep gets one scale per (standing angle, sign of the reference's torque) relative to its gain, the
clusters' information-weighted mean (``still_joint_scales``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError, QualityGateError
from payload_agent.model.kinematics import Kinematics
from payload_agent.evaluation import still_joint_scales
from payload_agent.evaluation.systematics import gain_scatter
from payload_agent.solvers import general, wls
from payload_agent.solvers.wls import Group
from payload_agent.types import SweepKey

SCALE_MIN, SCALE_MAX = 0.8, 1.25  # a drive gain this far off nominal is a wrong reference, not a drive
MIN_SIGNAL_TO_NOISE = 5.0  # a joint is fitted when its largest |Δτ_pred| is this many residual σ
MAX_SCALE_STD = 0.01  # ... and its scale comes out to better than 1 %
# what an unfitted joint's nominal gain is assumed to be good for (datasheet torque constants and
# "rated torque / 100" conversions are typically within a few per cent): enters the uncertainty
UNFITTED_GAIN_REL_STD = 0.03
MIN_SAMPLES = 50  # per joint, over all sweeps
IMPLAUSIBLE_Z = 3.0  # a scale this many σ outside SCALE_MIN–SCALE_MAX is a wrong reference, not noise


def own_scales(sweeps: list[DeltaSweep], groups: list[Group]) -> list[str | None]:
    """Per group: the (joint, standing angle) cluster whose own scale the calibration fits it (``general.stands_apart``;
    ``gain_scatter.clusters``: the same angle in several sweeps is one cluster, one mesh phase), None for the rows
    that carry the joint's drive gain."""
    names = gain_scatter.clusters(sweeps, groups)
    return [name if apart else None for name, apart in zip(names, general.stands_apart(sweeps, groups))]


def _groups_by_joint(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics,
                     theta: np.ndarray) -> dict[int, list[tuple[np.ndarray, np.ndarray, bool, str | None, str | None]]]:
    """Per joint: (predicted Δτ, measured Δτ, needs an offset, the cluster whose own scale it gets or None, the
    cluster whose scale relative to the joint's gain it gets or None: ``still_joint_scales``) for every sweep
    carrying that joint."""
    sweeps = general.select_sweeps(deltas)
    groups = general.build_groups(sweeps, kin)
    by_name = {d.key.name: d for d in sweeps}
    out: dict[int, list[tuple[np.ndarray, np.ndarray, bool, str | None, str | None]]] = {}
    relative = still_joint_scales.signed_clusters(sweeps, groups, theta, MIN_SIGNAL_TO_NOISE)
    for g, own, rel in zip(groups, own_scales(sweeps, groups), relative):
        d = by_name[g.sweep]
        # a moving joint in a one-direction sweep keeps friction the baseline did not remove
        offset = d.key.direction != "both" and g.joint == d.moving
        out.setdefault(g.joint, []).append((g.Y @ theta, g.y, offset, own, None if rel is None else rel[0]))
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
    # per still cluster with a scale of its own (``own_scales``): (name, ε, σ_ε), its relative gain error against
    # this joint's fitted gain (the nuisance column's coefficient over k)
    own: tuple[tuple[str, float, float], ...] = ()

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
        pred = np.concatenate([p[0] for p in parts])
        meas = np.concatenate([p[1] for p in parts])
        n = len(pred)
        offset_parts = [i for i, p in enumerate(parts) if p[2]]
        own = list(dict.fromkeys(p[3] for p in parts if p[3] is not None))  # the still clusters' own scales
        # a never-turning joint's clusters: the best-determined one's gain in column 0, each other's difference to it
        rel = list(dict.fromkeys(p[4] for p in parts if p[4] is not None))
        if rel:
            rel = still_joint_scales.base_first(rel, [float(sum(p[0] @ p[0] for p in parts if p[4] == name))
                                                      for name in rel])
        rel_col = {name: 1 + len(offset_parts) + len(own) + c - 1 for c, name in enumerate(rel) if c > 0}
        X = np.zeros((n, 1 + len(offset_parts) + len(own) + max(len(rel) - 1, 0)))
        X[:, 0] = pred
        start = np.concatenate(([0], np.cumsum([len(p[0]) for p in parts])))
        for col, i in enumerate(offset_parts, 1):
            X[start[i]:start[i + 1], col] = 1.0
        for i, p in enumerate(parts):
            if p[3] is not None:
                col = 1 + len(offset_parts) + own.index(p[3])
                X[start[i]:start[i + 1], col] = pred[start[i]:start[i + 1]]
            if p[4] in rel_col:
                X[start[i]:start[i + 1], rel_col[p[4]]] = pred[start[i]:start[i + 1]]
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
        # the noise: each sweep's residuals without a turning joint's mesh ripple, which averages out of k (``wls``)
        noise, lines = (np.concatenate(a) for a in zip(*(wls.without_lines(resid[start[i]:start[i + 1]])
                                                         for i in range(len(parts)))))
        for i in range(len(parts)):
            sl = slice(start[i], start[i + 1])
            r = noise[sl]
            _, lag = wls.autocorrelation_time(r, max_lag=max(1, int(wls.HAC_MAX_FRACTION * len(r))))
            B += wls.long_run_scores(X[sl] * r[:, None], lag) + wls.line_leftover(X[sl], lines[sl])
        # each coefficient's variance: the sandwich, never below the white-noise one
        sandwich, white = XtX_inv @ B @ XtX_inv * n / dof, XtX_inv * float(noise @ noise / dof) * n / dof
        var = np.maximum(np.diag(sandwich), np.diag(white))
        k_var = float(var[0])
        rel_eps: tuple[tuple[str, float, float], ...] = ()
        if rel:  # the joint's gain: the clusters' information-weighted mean (``still_joint_scales``)
            info = [float(sum(p[0] @ p[0] for p in parts if p[4] == name)) for name in rel]
            a, R = still_joint_scales.relative_map(len(coef), 0, [rel_col.get(name) for name in rel], info)
            e, sd = still_joint_scales.relative_errors(coef, sandwich, white, a, R)
            k, k_var = float(a @ coef), float(max(a @ sandwich @ a, a @ white @ a))
            rel_eps = tuple((name, float(e[c]), float(sd[c])) for c, name in enumerate(rel))
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
        own_eps = tuple((name, float(coef[c] / k), float(np.sqrt(var[c])) / k)
                        for c, name in enumerate(own, 1 + len(offset_parts)))
        fits.append(JointFit(j, status, n, s, s_std, peak, sigma, own_eps + rel_eps))
    return fits


def own_cluster_errors(fits: Sequence[JointFit]) -> dict[str, tuple[float, float]]:
    """Every fitted joint's still clusters' (ε, σ_ε) by cluster name (``JointFit.own``)."""
    return {name: (e, sd) for f in fits if f.status == "fitted" for name, e, sd in f.own}


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


__all__ = ["SCALE_MIN", "SCALE_MAX", "MIN_SIGNAL_TO_NOISE", "MAX_SCALE_STD", "UNFITTED_GAIN_REL_STD", "MIN_SAMPLES",
           "IMPLAUSIBLE_Z", "JointFit", "CalibrationFailed", "own_scales", "own_cluster_errors", "fit_joint_scales", "fit_gains_from_deltas"]
