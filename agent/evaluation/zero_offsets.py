"""Joint zero offsets measured by the drive-gain calibration, and how the analysis and the plan use them.

A joint's zero z (controller angle − link angle: encoder zeroing) moves the arm the agent models away from
the arm gravity acts on. In the loaded-minus-empty torque the arm's own weight cancels (both runs stand at
the same reported angles), and what is left is the payload's torque at the link angles:
Δτ_j(q) = k_j·(Y(q − z)·θ)_j ≈ k_j·(Y(q)θ − Σ_i z_i·∂(Y(q)θ)/∂q_i)_j. With a reference payload of known θ
(``payload-agent calibrate``) both parts are known functions of the angle: along a joint-2 sweep the
reference's torque goes as cos(elevation), a gain scales it as cos, a zero shifts it as sin. The
calibration's sweeps can tell them apart as far as their range turns the elevation, so ``fit`` estimates the
gain scales of the fitted joints and the zeros of the joints that turn the payload against gravity
(``CANDIDATES``: joint 1 turns about the vertical and changes no gravity torque) in one weighted least
squares over every fitted joint's rows (a zero acts on all of them), with the declared zero uncertainty
(``robot.kinematics.zero_offset_uncertainty_deg``) as a Gaussian prior: where the sweeps cannot tell a zero
the result is the prior (offset 0, σ declared), and a joint declared exact (0°) is not fitted.

The calibration stores the result (``ZeroOffsets``); ``corrected`` moves every sample of a run to its link
angle q − z before the analysis, and ``declaration`` gives the joint-zero term the measured σ for those joints
(the declared one stays for the others), in the run (``evaluation.analyse``) and in the plan
(``session.target.noise_for`` → ``design``), so that the two predict alike. The whole posterior reaches σ: the
zeros' correlation, and the gains' errors that go with the zeros' errors (``effort_coupling``: the joint-zero
term shifts the angles and changes the efforts together), the gains keeping their σ given the zeros. On the
calibration's 0–55° sweeps the zeros one by one are hardly better than the declared 0.02°, but their effect on a
payload measured with similar sweeps is: the coupled gains cancel most of it (docs/benchmarks.md, issue 22).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.configuration.config import JointSystematicsConfig
from payload_agent.evaluation import still_joint_scales
from payload_agent.evaluation.gain_scales import MIN_SIGNAL_TO_NOISE, own_scales
from payload_agent.model.kinematics import Kinematics
from payload_agent.recording.rundata import SweepData
from payload_agent.solvers import general, wls
from payload_agent.types import SweepKey

# 0-based: joints 2 and 3, whose zeros tilt the reference's whole lever. Joint 1's axis is vertical (no gravity
# torque turns with it); the wrist's zeros turn only the reference's short CoM offset: with 5 kg at (60, 0, 80) mm,
# 5 %, 0–90° their data σ came out 0.035–0.09° against the declared 0.02° (docs/benchmarks.md), so fitting them
# widens the gains' σ and tells nothing
CANDIDATES = (1, 2)
STEP_RAD = 1e-4  # finite-difference step of ∂(Yθ)/∂q_i: small against the lever geometry, large against rounding
MEASURED_SHARE = 0.8  # a zero counts as measured (in the notes) when the data alone give at most 0.8 × the prior's σ


@dataclass(frozen=True)
class ZeroOffset:
    """One joint's zero as the calibration found it (the prior combined with the data)."""

    joint: int  # 0-based
    offset_rad: float  # controller angle − link angle (posterior mean)
    std_rad: float  # posterior standard deviation
    prior_std_rad: float  # the declaration it was combined with
    data_std_rad: float  # what the data alone give (inf: nothing)

    @property
    def measured(self) -> bool:
        return self.data_std_rad <= MEASURED_SHARE * self.prior_std_rad


@dataclass(frozen=True)
class ZeroOffsets:
    """The zeros a calibration measured, and the largest correlation of a zero with a gain scale in that fit."""

    joints: tuple[ZeroOffset, ...]
    max_gain_correlation: float = 0.0
    corr: tuple[tuple[float, ...], ...] | None = None  # the zeros' posterior correlation, in ``joints`` order
    # per zero (``joints`` order): each joint's relative effort change per rad of that joint's angles shifted (the
    # gains' errors that go with the zero's: ``fit``); None: uncoupled
    effort_coupling: tuple[tuple[float, ...], ...] | None = None

    def to_json(self) -> dict[str, Any]:
        """The calibration file's ``zero_offsets`` (joints 1-based; radians, as stored, so that it reads back exactly)."""
        return {"max_gain_correlation": self.max_gain_correlation,
                "joints": [{"joint": z.joint + 1, "offset_rad": z.offset_rad, "std_rad": z.std_rad,
                            "prior_std_rad": z.prior_std_rad,
                            "data_std_rad": z.data_std_rad if np.isfinite(z.data_std_rad) else None,
                            **({} if self.corr is None else {"corr": list(self.corr[i])}),
                            **({} if self.effort_coupling is None else
                               {"effort_per_rad": list(self.effort_coupling[i])})}
                           for i, z in enumerate(self.joints)]}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> "ZeroOffsets":
        """Inverse of ``to_json``; ValueError / KeyError / TypeError on a malformed entry."""
        rows = d["joints"]
        out = []
        for r in rows:
            data = r.get("data_std_rad")
            out.append(ZeroOffset(int(r["joint"]) - 1, float(r["offset_rad"]), float(r["std_rad"]),
                                  float(r["prior_std_rad"]), float("inf") if data is None else float(data)))
        if any(not 0 <= z.joint < 6 or not z.std_rad >= 0 for z in out):
            raise ValueError("zero_offsets: joints must be 1–6 and std_rad not negative")
        corr = [r.get("corr") for r in rows]
        if any(c is not None and len(c) != len(rows) for c in corr):
            raise ValueError("zero_offsets: each corr must have one entry per joint")
        full = None if any(c is None for c in corr) else tuple(tuple(float(v) for v in c) for c in corr)
        eff = [r.get("effort_per_rad") for r in rows]
        if any(e is not None and len(e) != 6 for e in eff):
            raise ValueError("zero_offsets: each effort_per_rad must have 6 entries")
        coupling = None if any(e is None for e in eff) else tuple(tuple(float(v) for v in e) for e in eff)
        return cls(tuple(out), float(d.get("max_gain_correlation", 0.0)), full, coupling)

    def shift_rad(self) -> np.ndarray:
        z = np.zeros(6)
        for o in self.joints:
            z[o.joint] = o.offset_rad
        return z

    def describe(self) -> str:
        return ", ".join(f"j{z.joint + 1} {np.degrees(z.offset_rad):+.4f}±{np.degrees(z.std_rad):.4f}°"
                         + ("" if z.measured else f" (mostly the prior: the data alone ±{np.degrees(z.data_std_rad):.3f}°)")
                         for z in self.joints)


@dataclass(frozen=True)
class JointGainZeroFit:
    """The joint fit: gain scale (fitted / nominal) and its σ per fitted joint, the zeros, the correlations."""

    scale: dict[int, float]
    scale_std: dict[int, float]
    zeros: ZeroOffsets
    # per still cluster with a scale of its own (``gain_scales.own_scales``): (ε, σ_ε), its relative gain error
    # against its joint's fitted gain (the nuisance column's coefficient over the joint's k)
    own: dict[str, tuple[float, float]] = field(default_factory=dict)


def _rows(deltas: Mapping[SweepKey, DeltaSweep], kin: Kinematics, theta: np.ndarray, joints: Sequence[int],
          zero_joints: Sequence[int]) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray, bool, str | None, str | None]]:
    """Per (sweep, fitted joint): (joint, predicted Δτ, measured Δτ, ∂pred/∂q_i per zero joint, needs an offset,
    the still cluster whose own scale it gets or None: ``gain_scales.own_scales``, the cluster whose scale relative to
    the joint's gain it gets or None: ``still_joint_scales``)."""
    sweeps = general.select_sweeps(dict(deltas))
    base = general.build_groups(sweeps, kin, joints)
    apart = own_scales(sweeps, base)
    relative = still_joint_scales.signed_clusters(sweeps, base, theta, MIN_SIGNAL_TO_NOISE)
    shifted = {i: {g.label: g for g in general.build_groups(
        [replace(d, q=d.q + np.eye(6)[i] * STEP_RAD) for d in sweeps], kin, joints)} for i in zero_joints}
    by_name = {d.key.name: d for d in sweeps}
    out = []
    for g, own_scale, rel in zip(base, apart, relative):
        d = by_name[g.sweep]
        pred = g.Y @ theta
        D = np.column_stack([((shifted[i][g.label].Y @ theta) - pred) / STEP_RAD if g.label in shifted[i]
                             else np.zeros(len(pred)) for i in zero_joints]) if zero_joints else np.zeros((len(pred), 0))
        out.append((g.joint, pred, g.y, D, d.key.direction != "both" and g.joint == d.moving, own_scale,
                    None if rel is None else rel[0]))
    return out


def fit(deltas: Mapping[SweepKey, DeltaSweep], kin: Kinematics, theta_ref: Sequence[float], joints: Sequence[int],
        prior_std_rad: float | Sequence[float]) -> JointGainZeroFit:
    """Gain scales of ``joints`` (0-based, the gain fit's fitted ones) and the zeros of ``CANDIDATES`` (prior σ > 0)
    against the reference θ = [m, m·c].

    Each joint's rows are weighted by 1/σ² of its residuals (a first unweighted pass). The uncertainty is the
    Bartlett sandwich per (sweep, joint) as in the gain fit (never below the white-noise one), combined with
    the prior on the zeros. Linearised at k = 1 and refined at the fitted k (a zero's column scales with k).
    """
    theta = np.asarray(theta_ref, float)
    prior = np.broadcast_to(np.asarray(prior_std_rad, float), (6,))
    zj = [i for i in CANDIDATES if prior[i] > 0]
    parts = _rows(deltas, kin, theta, joints, zj)
    jcol = {j: c for c, j in enumerate(joints)}
    offsets = [i for i, p in enumerate(parts) if p[4]]
    own = list(dict.fromkeys(p[5] for p in parts if p[5] is not None))  # the still clusters' own scales
    # a never-turning joint's clusters (``still_joint_scales``): its best-determined one's gain in the joint's column,
    # each other's difference to it in a column of its own
    rel = {j: list(dict.fromkeys(p[6] for p in parts if p[0] == j and p[6] is not None)) for j in joints}
    rel = {j: still_joint_scales.base_first(names, [float(sum(p[1] @ p[1] for p in parts if p[6] == name))
                                                    for name in names]) if names else names
           for j, names in rel.items()}
    rel_names = [name for j in joints for name in rel[j][1:]]
    rel_col = {name: len(joints) + len(offsets) + len(own) + c for c, name in enumerate(rel_names)}
    nk, no, nz = len(joints), len(offsets) + len(own) + len(rel_names), len(zj)
    start = np.concatenate(([0], np.cumsum([len(p[1]) for p in parts])))
    y = np.concatenate([p[2] for p in parts])
    owner = np.concatenate([np.full(len(p[1]), p[0]) for p in parts])
    w = np.ones(len(y))
    k = np.ones(nk)
    for it in range(3):
        X = np.zeros((len(y), nk + no + nz))
        for i, (j, pred, _, D, _, _, _) in enumerate(parts):
            sl = slice(start[i], start[i + 1])
            X[sl, jcol[j]] = pred
            X[sl, nk + no:] = -k[jcol[j]] * D
        for c, i in enumerate(offsets):
            X[start[i]:start[i + 1], nk + c] = 1.0
        for i, p in enumerate(parts):
            if p[5] is not None:
                X[start[i]:start[i + 1], nk + len(offsets) + own.index(p[5])] = p[1]
            if p[6] in rel_col:
                X[start[i]:start[i + 1], rel_col[p[6]]] = p[1]
        Xw = X * w[:, None]
        info = Xw.T @ X
        inv = np.linalg.pinv(info)
        coef = inv @ (Xw.T @ y)
        k = coef[:nk]
        resid = y - X @ coef
        if it == 0:  # each joint's residual σ: its rows' weight from here on
            for j in joints:
                r = resid[owner == j]
                w[owner == j] = 1.0 / max(float(np.sqrt(r @ r / max(len(r) - 1, 1))), wls.SIGMA_FLOOR_NM) ** 2
    B = np.zeros_like(info)
    # the noise: each sweep's residuals without a turning joint's mesh ripple, which averages out of the fit (``wls``)
    noise, lines = (np.concatenate(a) for a in zip(*(wls.without_lines(resid[start[i]:start[i + 1]])
                                                     for i in range(len(parts)))))
    for i in range(len(parts)):
        sl = slice(start[i], start[i + 1])
        r = noise[sl] * w[sl]
        _, lag = wls.autocorrelation_time(noise[sl], max_lag=max(1, int(wls.HAC_MAX_FRACTION * len(r))))
        B += wls.long_run_scores(X[sl] * r[:, None], lag) + wls.line_leftover(X[sl] * w[sl, None], lines[sl])
    dof = max(len(y) - X.shape[1], 1)
    cov = inv @ B @ inv * len(y) / dof
    chi2 = float(noise @ (w * noise)) / dof  # the white-noise covariance, scaled by the fit's own noise
    cov = np.where(np.eye(len(coef), dtype=bool), np.maximum(np.diag(cov), np.diag(inv) * max(chi2, 1.0)), cov)
    # the declared zeros as a Gaussian prior (mean 0): information added to the zero block
    P = np.zeros_like(info)
    zsl = slice(nk + no, nk + no + nz)
    P[zsl, zsl] = np.diag(1.0 / prior[zj] ** 2)
    data_info = np.linalg.pinv(cov)
    post = np.linalg.pinv(data_info + P)
    mean = post @ (data_info @ coef)
    # each never-turning joint's gain: its clusters' information-weighted mean (``still_joint_scales``)
    rel_eps: dict[str, tuple[float, float]] = {}
    for j in joints:
        if rel[j]:
            info = [float(sum(p[1] @ p[1] for p in parts if p[6] == name)) for name in rel[j]]
            a, R = still_joint_scales.relative_map(len(mean), jcol[j], [rel_col.get(name) for name in rel[j]], info)
            e, sd = still_joint_scales.relative_errors(mean, post, None, a, R)
            rel_eps.update({name: (float(e[c]), float(sd[c])) for c, name in enumerate(rel[j])})
            T = np.eye(len(mean))
            T[jcol[j]] = a
            mean, post = T @ mean, T @ post @ T.T
    sd = np.sqrt(np.maximum(np.diag(post), 0.0))
    corr = post / np.outer(sd, sd) if np.all(sd > 0) else np.zeros_like(post)
    data_sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    zeros = tuple(ZeroOffset(i, float(mean[nk + no + c]), float(sd[nk + no + c]), float(prior[i]),
                             float(data_sd[nk + no + c])) for c, i in enumerate(zj))
    rho = float(np.max(np.abs(corr[:nk, zsl]))) if nk and nz else 0.0
    zcorr = tuple(tuple(float(v) for v in row) for row in corr[zsl, zsl])
    # the gains' errors split into the part that goes with the zeros' errors (δk = B·δz, carried by the zero term
    # as a coupled effort change) and the rest (σ of k given the zeros, the gains' own σ): together the whole
    # posterior covariance, with a shifted angle h = −δz and the effort ∝ s = 1/k changing by −δk/k = B·h/k
    k = mean[:nk]
    Czz = post[zsl, zsl]
    Bk = post[:nk, zsl] @ np.linalg.pinv(Czz) if nz else np.zeros((nk, 0))
    cond = post[:nk, :nk] - Bk @ post[zsl, :nk]
    coupling = np.zeros((nz, 6))
    for j, c in jcol.items():
        coupling[:, j] = Bk[c] / k[c]
    # s = 1/k: its σ by the delta method
    scale = {j: 1.0 / float(k[c]) for j, c in jcol.items()}
    scale_std = {j: float(np.sqrt(max(cond[c, c], 0.0))) / float(k[c]) ** 2 for j, c in jcol.items()}
    joint_of = {p[5]: p[0] for p in parts if p[5] is not None}
    col = {name: nk + len(offsets) + c for c, name in enumerate(own)}
    own_eps = {name: (float(mean[col[name]] / k[jcol[joint_of[name]]]),
                      float(np.sqrt(max(post[col[name], col[name]], 0.0)) / abs(k[jcol[joint_of[name]]])))
               for name in own}
    own_eps.update(rel_eps)
    return JointGainZeroFit(scale, scale_std, ZeroOffsets(zeros, rho, zcorr, tuple(tuple(float(v) for v in row)
                                                                                 for row in coupling)), own_eps)


def refit(deltas: Mapping[SweepKey, DeltaSweep], kin: Kinematics, theta_ref: Sequence[float], joints: Sequence[int],
          scale: np.ndarray, scale_std: np.ndarray, prior_std_rad: float | Sequence[float]
          ) -> tuple[np.ndarray, np.ndarray, ZeroOffsets | None, dict[str, tuple[float, float]] | None]:
    """The gain fit's (scale, σ) with the zeros fitted jointly: the joint fit's scales and σ for ``joints``, the
    zeros and the still clusters' own (ε, σ_ε) (``JointGainZeroFit.own``); unchanged, None and None where no zero is
    declared uncertain (nothing to measure)."""
    if not any(np.broadcast_to(np.asarray(prior_std_rad, float), (6,))[i] > 0 for i in CANDIDATES) or not joints:
        return scale, scale_std, None, None
    f = fit(deltas, kin, theta_ref, joints, prior_std_rad)
    scale, scale_std = np.array(scale, float), np.array(scale_std, float)
    for j in joints:
        scale[j], scale_std[j] = f.scale[j], f.scale_std[j]
    return scale, scale_std, f.zeros, f.own


def corrected(sweeps: Mapping[SweepKey, SweepData], zeros: ZeroOffsets | None) -> dict[SweepKey, SweepData]:
    """Every sample moved to its link angle q − z (the measured zeros); unchanged without any."""
    if zeros is None or not zeros.joints:
        return dict(sweeps)
    z = zeros.shift_rad()
    return {k: replace(s, q=np.asarray(s.q, float) - z) for k, s in sweeps.items()}


def declaration(decl: JointSystematicsConfig, zeros: ZeroOffsets | None) -> JointSystematicsConfig:
    """``decl`` with the measured joints' zero σ in place of the declared one (the others keep theirs)."""
    if zeros is None or not zeros.joints:
        return decl
    std = list(np.broadcast_to(np.asarray(decl.zero_offset_std_rad, float), (6,)))
    corr = np.eye(6) if decl.zero_offset_corr is None else np.array(decl.zero_offset_corr, float)
    coupling = np.zeros((6, 6))
    for a, z in enumerate(zeros.joints):
        std[z.joint] = z.std_rad
        for b, o in enumerate(zeros.joints):
            corr[z.joint, o.joint] = (1.0 if a == b else 0.0) if zeros.corr is None else zeros.corr[a][b]
        if zeros.effort_coupling is not None:
            coupling[z.joint] = zeros.effort_coupling[a]
    return replace(decl, zero_offset_std_rad=tuple(float(v) for v in std),
                   zero_offset_corr=tuple(tuple(float(v) for v in row) for row in corr),
                   zero_gain_coupling=None if zeros.effort_coupling is None else
                   tuple(tuple(float(v) for v in row) for row in coupling))


def note(zeros: ZeroOffsets, source: str) -> str:
    """What the result's notes say about the zeros it used."""
    told = [z for z in zeros.joints if z.measured]
    prior = sorted({f"{np.degrees(z.prior_std_rad):.3g}°" for z in zeros.joints})
    return (f"joint zeros from {source}: {zeros.describe()}; the angles corrected by them and their σ in the "
            f"joint-zero term ({len(told)} of {len(zeros.joints)} measured; the declared ±{'/'.join(prior) or '0°'} "
            "is the prior, and stays for the joints the calibration's sweeps cannot tell)")


__all__ = ["CANDIDATES", "ZeroOffset", "ZeroOffsets", "JointGainZeroFit", "fit", "refit", "corrected", "declaration", "note"]
