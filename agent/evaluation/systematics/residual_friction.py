"""The friction the two-direction average leaves, measured from the run: one nuisance offset per moving joint (issue 22).

A Coulomb direction asymmetry a_j leaves a_j·Δt_j on every two-direction row of joint j's sweeps, Δt_j the change
of the Coulomb level between the empty and the loaded run (``friction``): the same constant in every sweep of the
joint, while the payload's torque varies along each sweep as cos/sin of the link angle. So the general fit with one
nuisance offset per moving joint (``residual_joint``) and one nuisance gain column per still (joint, angle)
cluster (``offsets_fit``, made once per model; why the gain columns: there) measures b_j = a_j·Δt_j directly,
b̂ ~ N(b, C). Until session 19 the term declared it, b_j of standard deviation σ_a·√E[Δt_j²] with σ_a the declared asymmetry (``robot.friction_asymmetry_percent``): on the hard arm at 1 % sweeps
an asymmetry at the edge of its range (|a| = 1.5–1.7 σ_a) moved the mass by 10 g where the term said 6 g, and on an
arm without asymmetry the declared term was the whole mass σ.

The declared form stays as the prior, and the data decide where they can (``posterior``): the unknowns are
x = (b, a) per joint, jointly normal under the prior (a ~ N(0, σ_a²), b = a·Δt with Δt ~ N(μt, st²) as measured:
Var b = σ_a²(μt² + st²), Cov(a, b) = σ_a²·μt), observed through b̂. Where C is large against the prior (short or
fast sweeps) the posterior is the prior and the term the declared one; where C is small it is the measured
residual. a matters where a drive-gain calibration's reference run left a_j·Δr_j in the gains
(``reference_friction``): the same asymmetry acts there, read through the gains (R_j), so the measured b̂ also
tells a_j and with it the reference run's part. The offsets are read through those gains as well:
b̂ ~ N(b + Q·diag(μr)·a, C + Q·diag(σ_a²·sr²)·Qᵀ) (``through_gains``); where both runs' friction changed alike the
gains take back part of b (on test_reference_friction's arm 57 % on joint 2, 61 % on joint 3), which read as
b̂ ~ N(b, C) gave too small an asymmetry and a three-step σ of half the shift (docs/benchmarks.md, session 20).

The shift of θ is S·b + R·diag(μr)·a + R·diag(a)·(Δr − μr) (S: the plain fit's response to a constant torque on
the joint's rows, ``offsets.offset_sensitivities``; R: through the gains, zero without a calibration). Its second
moment given the data, what the term puts into σ (``columns``): L·(μμᵀ + P)·Lᵀ with L = [S, R·diag(μr)] and the
posterior (μ, P) of x, plus R_j²·E[a_j²]·sr_j². Without a measurement (C → ∞) it is σ_a²·[(S·μt + R·μr)² + S²·st² +
R²·sr²] per joint, the declared term of sessions 13–18 (``reference_friction.shared_asymmetry``).

What the offsets also take up: any slowly varying torque on the moving joint's rows that is not the payload's,
e.g. the load-dependent part of gear ripple once per output turn, whose projection on a constant is part of b̂. Where
that makes b̂_j larger than the friction residual can be (``consistent``: the prior predictive), the joint's offset is
not used and the declared form decides there; a smaller share rides along in the term as if it were friction
(docs/benchmarks.md, session 19). That share is why the posterior mean of the shift stays in σ rather than coming off
θ̂: on the hard arm with no asymmetry at all b̂ of joint 2 is 0.10–0.12 N·m (5 σ, within ``consistent``), the ripple's
projection on a constant, which moves θ far less than S·b̂; taken off θ̂ (tried in session 22) it moved the hard arm's
general mass by up to 8 g, rms error 4.2 → 5.4 g over 24 cases (docs/benchmarks.md, session 22).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.errors import DataError
from payload_agent.evaluation.systematics import friction, offsets, wrist
from payload_agent.solvers.fitted import ALL, FittedModel
from payload_agent.solvers.wls import Group, fit

CHECK_CHI2 = 10.83  # χ²₁ at 1 − 0.001: an offset beyond it is not the friction residual alone (``consistent``)


def residual_joint(group: Group, sweep: DeltaSweep) -> str | None:
    """One offset per moving joint over all its two-direction sweeps (the rows that joint's friction residual
    a_j·Δt_j is on), named as the residual-friction term names its joints (0-based)."""
    if group.joint == sweep.moving and sweep.key.direction == "both":
        return str(group.joint)
    return None


@dataclass(frozen=True)
class Measured:
    """The offsets b̂ (N·m) the fit beside θ found on the joints it could separate, and their covariance."""

    joints: tuple[int, ...]  # 0-based
    offsets_nm: np.ndarray  # (k,)
    cov: np.ndarray  # (k, k)


@dataclass(frozen=True)
class ThroughGains:
    """How a drive-gain calibration's reference run reaches the measured offsets: the same asymmetry left a_k·Δr_k
    in its rows, the gains took a share of it, and the tool data read through them move b̂ by Q·(a∘Δr)
    (``through_gains``). Where both runs' friction changed alike this takes back part of b = a·Δt (read as
    b̂ ~ N(b, C) until session 20, the posterior found too small an asymmetry there: tests/test_reference_friction.py).
    The part of (Δr − μr) is in b̂'s noise and in the term's last columns, their correlation left out."""

    response: np.ndarray  # (k, p) Q: b̂ of the measured joints per N·m on each term joint's reference-run rows
    mean_nm: np.ndarray  # (p,) μr, the reference run's Coulomb change as the calibration measured it
    std_nm: np.ndarray  # (p,) sr


@dataclass(frozen=True)
class Posterior:
    """x = (b_1..b_p, a_1..a_p) of the term's joints given b̂: mean and covariance, and the prior's std of b."""

    joints: tuple[int, ...]
    mean: np.ndarray  # (2p,)
    cov: np.ndarray  # (2p, 2p)
    prior_std_nm: np.ndarray  # (p,) σ_a·√(μt² + st²): the declared form's size of b
    measured: Measured | None
    expected_var_nm2: np.ndarray | None = None  # (k,) the prior's variance of b̂ (without C), per measured joint

    def expected(self, joint: int) -> float:
        """The prior's variance of the measured offset of ``joint`` (the prior predictive's, less C)."""
        if self.expected_var_nm2 is not None:
            return float(self.expected_var_nm2[self.measured.joints.index(joint)])
        return float(self.prior_std_nm[self.joints.index(joint)] ** 2)

    def used(self, joint: int) -> bool:
        """Whether joint's offset is one a friction residual of the declared size can leave (``consistent``)."""
        return self.measured is not None and joint in self.measured.joints and consistent(
            self.measured, joint, self.expected(joint))

    def decided(self) -> list[int]:
        """The term's joints (0-based) where the measurement is at least as precise as the prior."""
        if self.measured is None:
            return []
        var = dict(zip(self.measured.joints, np.diag(self.measured.cov)))
        return [j for j in self.joints if j in var and var[j] <= self.expected(j) and self.used(j)]

    def a_second_moment(self) -> np.ndarray:
        """(p,) E[a_j²] given the data: what the reference run's uncertain change multiplies."""
        p = len(self.joints)
        return self.mean[p:] ** 2 + np.diag(self.cov)[p:]


def offsets_fit(model: FittedModel, gain_reference: tuple | None = None) -> tuple[offsets.OffsetFit, int]:
    """(fit, k): the general fit of ``model``'s rows with the k offsets ``residual_joint`` names (its columns 4 to 4 + k)
    and, after them, one nuisance gain column per still (joint, angle) cluster of joints 1–3 (``wrist.columns``, with
    the share a drive-gain calibration ``gain_reference`` absorbed of each cluster on its joint's other rows); made
    once per model.

    Why the gain columns: without them θ̂ is pinned by the still rows, and b̂ takes up any gain error of a standing
    angle (the frozen gear-mesh ripple, ±1 % of the payload torque there; docs/benchmarks.md, session 24) as if it
    were a constant on the moving rows: a 1 % scale of joints 2 and 3's still rows moved b̂ of joint 2 by 0.21 N·m,
    12 σ (tests/test_three_step_rows.py), and the calibration's per-angle correction of those rows
    (``calibration_clusters``, ≤ 1 %) moved it on hard 1 % case 6 from −0.199 to −0.030 N·m. With them a still
    cluster's scale cannot be read as an offset, and b̂'s covariance holds what that costs (docs/benchmarks.md,
    session 25). Always, not where a test finds a scatter: a still angle's gain is not its joint's moving rows' on a
    geared arm (the ripple), nor after a calibration that fits them apart (its moving-row gains carry the reference
    run's friction residue, ``through_gains``, its still angles their own ε̂); and a test's threshold would switch
    b̂ between two readings of the same rows."""
    def make() -> tuple[offsets.OffsetFit, int]:
        sweeps, groups = list(model.sweeps), list(model.groups)
        base = groups[0].Y.shape[1] if groups else 4
        aug, labels = offsets.augment(sweeps, groups, residual_joint)
        with_gains, wrist_labels = wrist.columns(sweeps, groups, model.fit(ALL).theta[:4], True, gain_reference)
        extra = base + len(wrist_labels)  # wrist.columns' own wrist-offset columns are left out
        aug = [replace(a, Y=np.hstack([a.Y, w.Y[:, extra:]])) for a, w in zip(aug, with_gains)]
        gain = None if model.gain_rel_std is None else list(model.gain_rel_std)
        return offsets.OffsetFit(fit(aug, gain), labels, aug), len(labels)

    return model.cached(("residual-friction offsets", gain_reference is not None), make)


def measure(model: FittedModel, gain_reference: tuple | None = None) -> Measured | None:
    """The offsets, one per moving joint's two-direction rows, fitted beside θ and the still clusters' gains on
    ``model``'s rows (``offsets_fit``); None where they cannot be separated from the payload's torque."""
    try:
        found, k = offsets_fit(model, gain_reference)
    except (DataError, np.linalg.LinAlgError):
        return None
    r = found.result
    b, cov = np.asarray(r.theta[4:4 + k], float), np.asarray(r.cov[4:4 + k, 4:4 + k], float)
    if not k or not np.all(np.isfinite(cov)):
        return None
    return Measured(tuple(int(lab) for lab in found.labels), b, cov)


def through_gains(model: FittedModel, eps: Mapping[int, np.ndarray], ref_mean_nm: np.ndarray, ref_std_nm: np.ndarray,
                  gain_reference: tuple | None = None) -> ThroughGains | None:
    """Q (k, p): how the offsets ``measure`` fits move per N·m of constant torque on each of the term's p labels' rows
    of the calibration's reference run, with that run's change (μr, sr) as the calibration measured it. The gains
    took ε_jk of it (``three_step_response.reference_offset_shares``), so the tool data on joint j's rows are off by
    −ε_jk·b_k relatively; the offsets' fit reads that as θ's does
    (``reference_friction.reference_columns``): Q = −Σ_j G_j·ε_jᵀ, G_j the offsets' response to a relative gain error
    of joint j. None where the offsets cannot be fitted."""
    try:
        found, k = offsets_fit(model, gain_reference)  # the fit ``measure`` made (cached)
    except (DataError, np.linalg.LinAlgError):
        return None
    r = found.result
    joint_of_row = np.repeat([g.joint for g in found.groups], [len(g.y) for g in found.groups])
    Y = np.vstack([g.Y for g in found.groups])
    Q = np.zeros((k, len(ref_mean_nm)))
    for j, e in eps.items():
        rows = joint_of_row == j
        Q -= np.outer((r.normal_inverse @ (Y[rows].T @ (r.weights[rows] * (Y[rows] @ r.theta))))[4:4 + k], e)
    return ThroughGains(Q, np.asarray(ref_mean_nm, float), np.asarray(ref_std_nm, float))


def consistent(measured: Measured, joint: int, prior_var: float) -> bool:
    """Whether joint's offset is one a friction residual of the declared size can leave: b̂_j²/(``prior_var`` + C_jj),
    ``prior_var`` the prior's variance of b̂_j (Var b_j, and the reference run's part through the gains), within
    the 1 − ``CHECK_ALPHA`` quantile of χ²₁ (the prior predictive). An offset far beyond it holds another torque the
    payload model lacks (on the hard arm 0.1–0.2 N·m on joint 2 with the asymmetry switched off, likely the
    load-dependent gear ripple once per output turn; the residual there is at most tens of mN·m), and the linear update would read it
    as an asymmetry far beyond any plausible one (|a| > 1 through a small Δt); the declared form decides there."""
    i = measured.joints.index(joint)
    var = float(prior_var) + float(measured.cov[i, i])
    return bool(var > 0.0 and measured.offsets_nm[i] ** 2 / var <= CHECK_CHI2)


def posterior(asym_std: float, tool: Sequence[friction.CoulombChange], joints: Sequence[int],
              measured: Measured | None, gains: ThroughGains | None = None) -> Posterior:
    """The residual b_j = a_j·Δt_j and the asymmetry a_j of ``joints`` given the measured offsets (linear normal update
    of the declared prior: a ~ N(0, σ_a²) per joint, independent; Δt_j ~ N(μt, st²) as ``tool[j]`` measured it).
    b̂ ~ N(b + Q·diag(μr)·a, C + Q·diag(σ_a²·sr²)·Qᵀ): with a calibration (``gains``) the reference run's part of the
    same asymmetry moves b̂ too; without one b̂ ~ N(b, C)."""
    p = len(joints)
    mu_t = np.array([c.mean_nm for c in tool], float)
    sd_t = np.array([c.std_nm for c in tool], float)
    s2 = float(asym_std) ** 2
    P0 = np.zeros((2 * p, 2 * p))
    idx = np.arange(p)
    P0[idx, idx] = s2 * (mu_t ** 2 + sd_t ** 2)
    P0[p + idx, p + idx] = s2
    P0[idx, p + idx] = P0[p + idx, idx] = s2 * mu_t
    mean, cov, expected = np.zeros(2 * p), P0, None
    if measured is not None:
        k = len(measured.joints)
        H = np.zeros((k, 2 * p))  # b̂ of every measured joint on x (a joint outside ``joints``: zero row)
        for i, j in enumerate(measured.joints):
            if j in joints:
                H[i, joints.index(j)] = 1.0
        noise = np.array(measured.cov, float)
        if gains is not None:
            H[:, p:] = gains.response * gains.mean_nm
            noise = noise + (gains.response * (s2 * gains.std_nm ** 2)) @ gains.response.T
        expected = np.diag(H @ P0 @ H.T) + np.diag(noise) - np.diag(measured.cov)
        rows = [i for i, j in enumerate(measured.joints) if j in joints
                and consistent(measured, j, float(expected[i]))]
        if rows:
            Hs = H[rows]
            S = Hs @ P0 @ Hs.T + noise[np.ix_(rows, rows)]
            K = np.linalg.solve(S, Hs @ P0).T  # P0·Hᵀ·S⁻¹ (S symmetric)
            mean = K @ measured.offsets_nm[rows]
            cov = P0 - K @ Hs @ P0
            cov = 0.5 * (cov + cov.T)
    return Posterior(tuple(joints), mean, cov, np.sqrt(np.diag(P0)[:p]), measured, expected)


def columns(post: Posterior, calib: Mapping[str, np.ndarray], ref_mean_nm: np.ndarray, ref_std_nm: np.ndarray
            ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(std, sens) of the term: the shift's second moment given the data as unit-σ columns, L·μ, L·P^½ (L = [S,
    R·diag(μr)]) and R_j with std √E[a_j²]·sr_j. ``calib``: {fit: (4, 2p)}, the tool run's columns S then the
    reference run's R (``reference_friction.reference_columns``; R zero without a calibration)."""
    p = len(post.joints)
    vals, vecs = np.linalg.eigh(post.cov)
    root = vecs * np.sqrt(np.clip(vals, 0.0, None))
    keep = vals > 1e-12 * max(float(vals.max()), 1e-300)
    sens = {}
    for which, A in calib.items():
        L = np.hstack([A[:, :p], A[:, p:] * ref_mean_nm])
        sens[which] = np.hstack([(L @ post.mean)[:, None], L @ root[:, keep], A[:, p:]])
    std = np.concatenate([[1.0], np.ones(int(keep.sum())), np.sqrt(post.a_second_moment()) * ref_std_nm])
    return std, sens


def describe(post: Posterior, asym_std: float) -> str:
    """What the data decided and where the declared asymmetry stays the prior, for the result's note."""
    m = post.measured
    if m is None:
        return (f"declared asymmetry ±{100 * asym_std:.3g} % alone (the offsets beside the fit could not be "
                "separated from the payload's torque)")
    decided = post.decided()

    def one(j: int) -> str:
        i = m.joints.index(j)
        return f"j{j + 1} {m.offsets_nm[i]:+.3f}±{np.sqrt(m.cov[i, i]):.3f}"

    found = ", ".join(one(j) for j in post.joints if j in m.joints)
    beyond = [f"j{j + 1}" for j in post.joints if j in m.joints and not post.used(j)]
    prior = [f"j{j + 1}" for j in post.joints if j not in decided]
    out = f"measured as one offset per moving joint beside the fit ({found} N·m)"
    if beyond:
        out += (f"; {', '.join(beyond)} beyond what the declared asymmetry × the change allows (another torque on "
                "those rows), not used")
    if prior:
        out += (f"; the declared asymmetry ±{100 * asym_std:.3g} % × the change decides where the data cannot tell "
                f"({', '.join(prior)})")
    return out


__all__ = ["CHECK_CHI2", "residual_joint", "Measured", "offsets_fit", "measure", "through_gains", "consistent",
           "ThroughGains", "Posterior", "posterior", "columns", "describe"]
