"""Torque-gain scatter between the angles a joint stands at: measured from the data, put into σ.

Why. A strain-wave gear's torque ripple grows with the torque through the gear (``fakes.effects.
TorqueRipple``: A + L·|τ|, times sin of the motor-side angle). On a joint that *moves* during a
sweep the mesh part oscillates many times and averages out. On a joint that *stands still* while
another one sweeps it does not: the ripple factor s = sin(2N·q + φ) is frozen at the angle the joint
stands at, and the payload's share of the gear torque, Δτ, comes with an extra L·s·Δτ. The loaded
minus empty difference on that joint is (1 + ε)·Δτ with ε = ±L·s, a *gain error* of up to ±L
(≈ 1 %) that is the same through the whole sweep and differs from one standing angle to the next.
No white-noise or autocorrelation-robust (HAC) covariance can see it: within a sweep it is
perfectly smooth and proportional to the signal, so the fit absorbs part of it and the rest looks
like a tiny, slow residual. A drive-gain calibration fits each still cluster of a joint that also turns a
scale of its own and stores its ε̂, a never-turning joint's relative to its gain (``still_joint_scales``); a tool run
standing there has it taken off (``calibration_clusters``), and the cluster keeps σ_ε² in place of τ² (``corrected_prior``).

Measured in the benchmark (realistic + ripple, 20 payloads, same noise with and without the ripple): of the
ripple's CoM error, the gain-like part on still joints is 0.20 mm rms per (sweep, joint) group, the moving
joint's once-per-turn part 0.17 mm, the mesh part that HAC sees 0.002 mm.

What. Every (joint, standing angle) pair k is a *cluster*: the still-joint rows of every sweep in
which joint j stands at that angle (the wrist stands at one angle through all sweeps of a pose;
joint 3 may stand at the same angle in two poses). The model allows each cluster its own relative
gain error ε_k, random with variance τ²:

    Δτ_g = (1 + ε_k)·Y_g·θ  for each still-joint group g of cluster k.

``measure`` fits θ together with one column Y_g·θ̂ per cluster (linearised gain), giving ε̂ and its
autocorrelation-robust covariance C. τ² is the maximum-likelihood variance of ε̂ ~ N(0, C + τ²·I)
(``scatter_variance``), 0 when the scatter is within noise. The likelihood weighs clusters by their
precision: a wrist joint carrying a few tenths of a N·m gives an ε̂ of tens of per cent either way
and must not decide τ (a moment estimate let it, ×3 too large on some payloads). Each ε_k moves the
plain fit by s_k = (YᵀWY)⁻¹·Σ_{g∈k} Y_gᵀW_g·Y_gθ̂. The moving joints carry no ε column: they anchor θ (a
gain column on every group would make the overall scale unidentifiable); their slow once-per-turn ripple
(0.1 of the mesh part) is left out.

What goes into σ. τ > 0 (the likelihood-ratio test) says a scatter is there. Each cluster's error is then
known as well as the data tell it: given its measurement ε̂_k ~ N(ε_k, C) and the scatter ε ~ N(0, τ²·I),
ε has the posterior mean ε̃ = τ²·(C + τ²·I)⁻¹·ε̂ and covariance P = C − C·(C + τ²·I)⁻¹·C
(``ScatterTerm.posterior``), and S·(ε̃ε̃ᵀ + P)·Sᵀ goes into σ (S = [s_k]): the realised effect where a cluster
is measured far better than τ (joints 2 and 3, ε̂ to ±0.1 %), the scatter's own size τ² where it is not (the
still wrist: a few N·m of payload torque give ε̂ to ±0.5–2 %, against a ripple of ±0.7 %). Under the model
E[ε̃ε̃ᵀ] + P = τ²·I, so the term is the true effect's size on average, neither shrunk nor counted twice.
The form before (until session 14; docs/benchmarks.md, sessions 13 and 15) put the measured effect β̂ = S·ε̂
in whole, shrunk by one factor for all clusters, s² = max(q − r, 0)/q, q = β̂ᵀ(S·C·Sᵀ)⁻¹β̂: the well-measured clusters of joints 2
and 3 passed the shrink, and with them the wrist clusters' noise, read as effect (realistic+ripple, 10 %:
σ_y 0.8–1.5 mm of "scatter" against errors the clean arm has too, rms(err/σ) of y 0.61). The random-effects
size τ²·Σ_k s_k s_kᵀ alone ignores what ε̂ says: without a calibration (ripple on joints 1–3 of a
simulated sim-ec66, 4 kg) it left a 14 g error at 2.4 σ.

After a drive-gain calibration the scatter's effect is another one. The reference run stands at the
same angles and carries the same ε_k (it scales the gear torque, and the reference payload's torque has
the sign of the tool's), so the calibration's scale of joint j absorbed the share w_jk of ε_k that cluster
k has in its fit (``absorbed_shares``: ⟨Y_jθ_ref on the cluster's rows⟩ over joint j's, the same form as the
DH lengths' absorption in ``solvers.general``, on the calibration's own sweeps as it stored them,
``reference_shares``; older calibrations: the tool run's sweeps stand in, for clusters where it stood). The calibrated data then carry ε_k on the cluster's rows and −w_jk·ε_k on every row of
joint j, the moving ones included, and θ moves by s_k − w_jk·g_j (g_j: the fit's response to a gain error
of all of joint j's rows). Measured in the benchmark's ripple ablation (default procedure, 6 payloads): the
plain s_k put 3–6 g into the mass σ against ripple errors of 0.4–1.4 g; the absorbed form 0.5–1.7 g; on
noise-free data it predicts the calibrated fit's shift to 1 % where the plain s_k was 17× off. And
the three-step solver, which reads joints 2 and 3 only where they move, gets −w_jk times its own response
to a gain error of joint j (``three_step_response.gain_response``): its ripple bias (10 g mean) was exactly
that, the still-joint ripple carried by the calibration into the moving rows. Its clusters are measured with that
share in their columns (``measure(absorb_joints=...)``, ``three_step_scatter``): the plain ones give part of ε_k
(0.69 of it for joint 3 at 0°).

The term is derived from the data alone: nothing about the gear is declared. It is zero for an arm
whose still joints agree with the model within noise.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Iterable, Mapping, Sequence

import numpy as np

from payload_agent.analysis.delta import DeltaSweep
from payload_agent.evaluation import calibration_clusters, reference_shares
from payload_agent.model.kinematics import Kinematics
from payload_agent.solvers import general
from payload_agent.solvers.fitted import ALL, FittedModel
from payload_agent.solvers.wls import FitResult, Group, fit
from payload_agent.types import SweepKey

SAME_ANGLE_RAD = 2e-3  # two still groups of one joint within this share a cluster (compensation moves q by τ/k)
LR_CRITICAL = 5.412  # 1 % level of the boundary likelihood-ratio test (½χ²₀ + ½χ²₁: the 98 % χ²₁ quantile)
MIN_CLUSTER_PEAK_NM = 1e-6  # a cluster whose modelled torque stays below this carries no gain information


@dataclass(frozen=True)
class GainScatter:
    """What the data say about gain errors between standing angles."""

    labels: list[str]  # cluster names, "j<joint>@<angle>°"
    eps: np.ndarray  # (k,) fitted relative gain error of each cluster
    eps_cov: np.ndarray  # (k, k) their covariance (autocorrelation-robust)
    tau: float  # standard deviation of the scatter beyond noise (relative), 0 if none
    sensitivities: np.ndarray  # (k, 4) ∂θ̂/∂ε_k of the plain fit

    @property
    def covariance(self) -> np.ndarray:
        """τ²·Σ_k s_k s_kᵀ: the covariance of θ = [m, m·c] this scatter adds."""
        return self.tau ** 2 * (self.sensitivities.T @ self.sensitivities)


def clusters(sweeps: list[DeltaSweep], groups: list[Group], tol_rad: float = SAME_ANGLE_RAD) -> list[str | None]:
    """Cluster name of every group: (joint, standing angle) for still-joint groups, None for moving ones."""
    by_name = {d.key.name: d for d in sweeps}
    still: dict[int, list[tuple[float, int]]] = {}
    for i, g in enumerate(groups):
        d = by_name[g.sweep]
        if g.joint != d.moving:
            still.setdefault(g.joint, []).append((float(np.median(d.q[:, g.joint])), i))
    out: list[str | None] = [None] * len(groups)
    for j, items in still.items():
        items.sort()
        runs: list[list[tuple[float, int]]] = [[items[0]]]
        for item in items[1:]:
            if item[0] - runs[-1][-1][0] > tol_rad:
                runs.append([])
            runs[-1].append(item)
        for run in runs:
            label = f"j{j + 1}@{np.degrees(0.5 * (run[0][0] + run[-1][0])):.2f}°"
            for _, i in run:
                out[i] = label
    return out


def standing_angles(deltas: Mapping[SweepKey, DeltaSweep], kin: Kinematics) -> tuple[tuple[int, float], ...]:
    """(joint, angle in rad) of every still-joint cluster of a run: where its joints stood while others swept.

    A drive-gain calibration records them (``calibration.GainCalibration.standing_angles``), so that a tool run
    knows which of its clusters' gain errors the calibration absorbed (``absorbed_shares``)."""
    sweeps = general.select_sweeps(dict(deltas))
    groups = general.build_groups(sweeps, kin) if sweeps else []
    by_name = {d.key.name: d for d in sweeps}
    out: dict[str, list[tuple[int, float]]] = {}
    for g, name in zip(groups, clusters(sweeps, groups)):
        if name is not None:
            out.setdefault(name, []).append((g.joint, float(np.median(by_name[g.sweep].q[:, g.joint]))))
    return tuple((v[0][0], float(np.mean([a for _, a in v]))) for v in out.values())


def scatter_variance(eps: np.ndarray, cov: np.ndarray) -> float:
    """Maximum-likelihood τ² ≥ 0 of ε̂ ~ N(0, C + τ²·I): the gain errors' variance beyond their noise.

    0 unless the likelihood-ratio test rejects τ² = 0 at 1 % (``LR_CRITICAL``): with white noise the
    robust C is itself a little optimistic (ε̂/se has an rms of 1.1–1.3 in the unit tests), and a small
    τ² moves θ a lot (the still joints 2 and 3 carry tens of N·m), so chance scatter must not count.

    The likelihood weighs each cluster by its precision, so a cluster whose payload torque is tiny (its ε̂
    is a ratio of two small numbers, tens of per cent either way) cannot inflate τ the way a simple
    moment estimate lets it; clusters with a clear gain error decide.
    """
    k = len(eps)
    if k == 0:
        return 0.0

    def nll(t2: float) -> float:
        a = cov + t2 * np.eye(k)
        sign, logdet = np.linalg.slogdet(a)
        if sign <= 0:
            return np.inf
        return float(logdet + eps @ np.linalg.lstsq(a, eps, rcond=None)[0])

    top = max(float(eps @ eps) / k, 1e-12)
    grid = np.concatenate(([0.0], top * np.logspace(-8, 0, 161)))
    vals = [nll(t2) for t2 in grid]
    i = int(np.argmin(vals))
    if i == 0:
        return 0.0
    lo, hi = grid[i - 1], grid[min(i + 1, len(grid) - 1)]
    for _ in range(60):  # golden-section refinement inside the bracketing grid cells
        a, b = lo + 0.382 * (hi - lo), lo + 0.618 * (hi - lo)
        lo, hi = (lo, b) if nll(a) < nll(b) else (a, hi)
    t2 = 0.5 * (lo + hi)
    # only a scatter the data show: the likelihood-ratio test of τ² = 0 (on the boundary, so half χ²₁)
    return t2 if nll(0.0) - nll(t2) > LR_CRITICAL else 0.0


def sensitivities(sweeps: list[DeltaSweep], groups: list[Group], res: FitResult, theta: np.ndarray,
                  labels: Sequence[str], tol_rad: float = SAME_ANGLE_RAD,
                  absorbed: Mapping[str, tuple[int, float]] | None = None,
                  names: Sequence[str | None] | None = None) -> np.ndarray:
    """(4, k) ∂θ̂/∂ε_k of the fit ``res`` of ``groups`` to a relative gain error ε_k of cluster ``labels[k]``.

    The error scales the payload torque of the cluster's rows, ε_k·Y_g·θ (``theta``: the best estimate of
    the true θ, e.g. the combined fit's), so θ̂ moves by (YᵀWY)⁻¹·Σ_{g∈k} Y_gᵀW_g·Y_gθ per unit ε_k.
    ``absorbed``: cluster -> (joint j, w) of a drive-gain calibration (``absorbed_shares``), which scaled all
    of joint j's rows by −w·ε_k: θ̂ moves by that much less of the response to joint j's gain.
    ``names``: each group's label (None: in no cluster) when not the (joint, standing angle) ``clusters``.
    """
    names = clusters(sweeps, groups, tol_rad) if names is None else list(names)
    starts = np.concatenate(([0], np.cumsum([len(g.y) for g in groups])))
    S = np.zeros((4, len(labels)))
    joint_response: dict[int, np.ndarray] = {}
    for i, (g, name) in enumerate(zip(groups, names)):
        wi = res.weights[starts[i]:starts[i + 1]]
        s = res.normal_inverse[:4, :4] @ (g.Y[:, :4].T @ (wi * (g.Y[:, :4] @ theta)))
        joint_response[g.joint] = joint_response.get(g.joint, 0.0) + s
        if name in labels:
            S[:, list(labels).index(name)] += s
    for k, label in enumerate(labels):
        j, w = (absorbed or {}).get(label, (None, 0.0))
        if j is not None and w:
            S[:, k] -= w * joint_response.get(j, np.zeros(4))
    return S


def absorbed_shares(sweeps: list[DeltaSweep], groups: list[Group], labels: Sequence[str],
                    reference: tuple[Iterable[float], Iterable[int]] | None,
                    tol_rad: float = SAME_ANGLE_RAD, names: Sequence[str | None] | None = None
                    ) -> dict[str, tuple[int, float]]:
    """Cluster -> (joint j, w_jk): the relative gain change a drive-gain calibration on the reference
    payload made per unit ε_k (module docstring), for the joints it fitted; {} without one.

    ``reference`` = (θ_ref, fitted joints) as in ``general.kinematic_sensitivities``; the calibration's fit
    of joint j's scale is the DH lengths' ``general.absorbed_length_error`` with the "length derivative"
    Y·θ_ref on the cluster's rows only. ``names``: as in ``sensitivities``.

    ``reference[2]``, when given: the (joint, angle) pairs the calibration stood at (``standing_angles``); a cluster
    the calibration did not stand at gets no share (its error was not in the reference run). Without it the
    calibration is taken to have run the tool run's procedure, as the DH lengths' absorption assumes.

    A calibration that stored its own shares (``reference_shares``, measured on its own sweeps by this function)
    gives each cluster the share of the cluster it stood at, at the same joint and angle; the ``sweeps`` and
    ``groups`` given then only name the clusters. Without them these sweeps stand in for the calibration's.
    """
    if reference is None:
        return {}
    names = clusters(sweeps, groups, tol_rad) if names is None else list(names)
    joint_of = {name: g.joint for g, name in zip(groups, names) if name is not None}
    fitted = {int(j) for j in reference[1]}
    stood = list(reference[2]) if len(reference) > 2 else None  # type: ignore[arg-type]
    by_name = {d.key.name: d for d in sweeps}
    angle_of: dict[str, list[float]] = {}
    for g, name in zip(groups, names):
        if name is not None:
            angle_of.setdefault(name, []).append(float(np.median(by_name[g.sweep].q[:, g.joint])))
    stored = reference_shares.of_reference(reference)
    if stored is not None:
        found = {label: (joint_of.get(label), stored.share(joint_of.get(label, -1),
                                                           float(np.mean(angle_of.get(label, [np.inf]))), tol_rad))
                 for label in labels}
        return {label: (int(j), float(w)) for label, (j, w) in found.items() if j in fitted and w is not None}
    indicator = np.repeat(np.array(names, dtype=object), [len(g.y) for g in groups])
    Y = np.vstack([g.Y[:, :4] for g in groups])
    dY = [Y * (indicator == label)[:, None] for label in labels]
    eps = general.absorbed_length_error(sweeps, [replace(g, Y=g.Y[:, :4]) for g in groups], dY, reference)
    out = {}
    for k, label in enumerate(labels):
        j = joint_of.get(label)
        if stood is not None and not any(jj == j and abs(a - float(np.mean(angle_of.get(label, [np.inf])))) <= tol_rad
                                         for jj, a in stood):
            continue  # the calibration did not stand there: it absorbed none of this cluster's error
        if j in fitted and j in eps:
            out[label] = (j, float(eps[j][k]))
    return out


def measure(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics,
            gain_rel_std: Iterable[float] | None = None, tol_rad: float = SAME_ANGLE_RAD,
            model: FittedModel | None = None, gain_reference: tuple | None = None,
            absorb_joints: Iterable[int] = ()) -> GainScatter:
    """The gain scatter between standing angles in these deltas (see the module docstring).

    ``model``: the analysis' fitted model of these deltas (its combined fit is the plain fit here).
    ``gain_reference`` and ``absorb_joints`` (0-based): the drive-gain calibration the data were scaled with; for
    the clusters of these joints its scale absorbed the share w_jk of ε_k (``absorbed_shares``), so every row of
    joint j, the moving ones included, carries −w_jk·ε_k and the cluster's column gets −w_jk·Y_gθ̂ there (as the
    wrist term's nuisance columns, ``wrist.columns``): ε̂_k is then the cluster's error itself, where the plain
    column measures it partly against the calibrated moving rows (0.69·ε_k for joint 3 standing at 0° in the
    benchmark's ripple rows). Not for a cluster whose column would vanish: w = 1 and no other row of its joint in
    this run (the joint stood only there, in the calibration as here). After a calibration on another procedure
    w = 1 with other rows is common (j2_quarter never moves joint 3 off 0°; a paper_bd run does): every other row of
    the joint then carries −ε_k, and the column measures it there.
    Default: none, the plain columns.
    """
    gain = None if gain_rel_std is None else list(gain_rel_std)
    if model is None:
        model = general.fit_model(deltas, kin, gain)
    sweeps, groups = list(model.sweeps), list(model.groups)
    plain = model.fit(ALL)
    theta = plain.theta
    names = clusters(sweeps, groups, tol_rad)
    labels: list[str] = []
    for g, name in zip(groups, names):
        if name is not None and name not in labels and np.max(np.abs(g.Y @ theta)) > MIN_CLUSTER_PEAK_NM:
            labels.append(name)
    if not labels:
        return GainScatter([], np.zeros(0), np.zeros((0, 0)), 0.0, np.zeros((0, 4)))
    absorb = set(int(j) for j in absorb_joints)
    shares = {} if gain_reference is None or not absorb else {
        c: (j, w) for c, (j, w) in absorbed_shares(sweeps, groups, labels, gain_reference, tol_rad).items()
        if j in absorb and (w < 1.0 or any(g.joint == j and name != c for g, name in zip(groups, names)))}
    aug = []
    for g, name in zip(groups, names):
        extra = np.zeros((len(g.y), len(labels)))
        if name in labels:
            extra[:, labels.index(name)] = g.Y @ theta
        for c, (j, w) in shares.items():
            if g.joint == j:
                extra[:, labels.index(c)] -= w * (g.Y @ theta)
        aug.append(replace(g, Y=np.hstack([g.Y, extra])))
    res = fit(aug, gain)
    k = slice(4, 4 + len(labels))
    eps, eps_cov = res.theta[k], res.cov[k, k]
    tau2 = scatter_variance(eps, eps_cov)
    S = sensitivities(sweeps, groups, plain, theta, labels, tol_rad)
    return GainScatter(labels, eps, eps_cov, float(np.sqrt(tau2)), S.T)


def note(gs: GainScatter) -> str:
    return (f"torque-gain scatter of {100 * gs.tau:.2g} % between the angles joints stand at "
            f"({len(gs.labels)} (joint, angle) pairs, from the data; gear ripple under load) in σ")


def of_model(model: FittedModel) -> GainScatter:
    """``measure`` on the analysis' fitted model (its deltas and drive-gain uncertainty), made once per model:
    the torque-gain term and the wrist term (which fits nuisance gain columns only where this finds a
    scatter) share it."""
    gain = None if model.gain_rel_std is None else list(model.gain_rel_std)
    return model.cached(("gain scatter",), lambda: measure(model.deltas, model.kin, gain, model=model))


@dataclass(frozen=True)
class ScatterTerm:
    """The scatter as ``evaluation.systematics`` uses it: what was measured and how each fit responds."""

    scatter: GainScatter
    labels: list[str]  # the clusters, in the order of ``sens``' columns
    shares: dict[str, tuple[int, float]]  # cluster -> (joint, w): what the drive-gain calibration absorbed
    sens: dict[str, np.ndarray]  # fit -> (4, k) ∂θ̂/∂ε_k, less the calibration's absorption
    note: str
    combined: str  # the key of the combined fit in ``sens``
    # per cluster (``labels`` order): the prior variance of its error, τ² except where the calibration's per-angle gain
    # error was taken off its rows (``calibration_clusters``: σ_ε² of that ε̂); None: τ² for all
    prior_var: np.ndarray | None = None

    def posterior(self) -> tuple[np.ndarray, np.ndarray]:
        """(ε̃, P): the clusters' gain errors given their measurement ε̂ ~ N(ε, C) and the scatter ε ~ N(0, τ²·I),
        posterior mean τ²·(C + τ²·I)⁻¹·ε̂ and covariance C − C·(C + τ²·I)⁻¹·C (module docstring)."""
        C = np.asarray(self.scatter.eps_cov, float)
        V = np.diag(self.scatter.tau ** 2 * np.ones(len(C)) if self.prior_var is None else self.prior_var)
        G = np.linalg.solve(C + V, np.eye(len(C)))
        P = C - C @ G @ C
        return V @ (G @ self.scatter.eps), 0.5 * (P + P.T)

    def effect_columns(self) -> np.ndarray:
        """(k, 1 + k): ε̃ and a square root of P side by side, unit-σ columns whose sum of squares is ε̃ε̃ᵀ + P
        (through a fit's S they put S·(ε̃ε̃ᵀ + P)·Sᵀ into its covariance)."""
        mean, P = self.posterior()
        w, V = np.linalg.eigh(P)
        return np.hstack([mean[:, None], V * np.sqrt(np.maximum(w, 0.0))])


def term(deltas: dict[SweepKey, DeltaSweep], kin: Kinematics, gain_rel_std: Iterable[float] | None,
         fits: Mapping[str, tuple[list[Group], FitResult]], combined: str, model: FittedModel | None = None,
         gain_reference: tuple[Iterable[float], Iterable[int]] | None = None) -> ScatterTerm | None:
    """The scatter as one systematic term for ``evaluation.systematics``; None: no scatter beyond noise.

    ``fits``: every fit the term must reach (the combined one under the key ``combined``, each pose's
    own), as (its groups, its result); each gets its own response to the same cluster errors, so a
    comparison between fits counts only the part that moves them apart.
    ``model``: the analysis' fitted model of these deltas (made here if None). ``gain_reference``: (θ_ref,
    fitted joints) of the drive-gain calibration the data were scaled with (None: nominal gains).
    """
    gs = of_model(model) if model is not None else measure(deltas, kin, gain_rel_std)
    labels = list(gs.labels)
    sweeps, groups = general.select_sweeps(deltas) if model is None else list(model.sweeps), list(fits[combined][0])
    prior, gs = corrected_prior(gs, sweeps, groups, gain_reference)
    if gs.tau <= 0.0 and prior is None:
        return None
    theta = fits[combined][1].theta[:4]
    shares = calibration_clusters.uncorrected(absorbed_shares(sweeps, groups, labels, gain_reference), sweeps, groups,
                                              clusters(sweeps, groups), gain_reference)  # corrected: in no gain
    sens = {which: sensitivities(sweeps, groups, res, theta, labels, absorbed=shares)
            for which, (groups, res) in fits.items()}
    how = "" if reference_shares.of_reference(gain_reference) is not None else f"; {reference_shares.STAND_IN_NOTE}"
    text = note(gs) + (f" (less what the drive-gain calibration absorbed{how})" if shares else "") + (
        "" if prior is None else "; clusters the calibration's per-angle errors corrected: its σ, not the scatter")
    return ScatterTerm(gs, labels, shares, sens, text, combined, prior)


def corrected_prior(gs: GainScatter, sweeps: list[DeltaSweep], groups: list[Group], gain_reference: tuple | None
                    ) -> tuple[np.ndarray | None, GainScatter]:
    """(prior variance per cluster, ``gs`` with τ of the others) where the calibration's ε̂ was taken off some clusters'
    rows (``calibration_clusters``): their error is what ε̂ missed, σ_ε², not τ²; (None, ``gs``) where none was."""
    stood = calibration_clusters.matches(sweeps, gain_reference)
    fixed = {name: stood[(g.sweep, g.joint)][1] for g, name in zip(groups, clusters(sweeps, groups))
             if (g.sweep, g.joint) in stood}
    if not any(label in fixed for label in gs.labels):
        return None, gs
    rest = [i for i, label in enumerate(gs.labels) if label not in fixed]
    gs = replace(gs, tau=float(np.sqrt(scatter_variance(gs.eps[rest], gs.eps_cov[np.ix_(rest, rest)]))))
    return np.array([fixed[label] ** 2 if label in fixed else gs.tau ** 2 for label in gs.labels]), gs


__all__ = ["GainScatter", "SAME_ANGLE_RAD", "clusters", "sensitivities", "absorbed_shares", "measure",
           "of_model", "standing_angles", "ScatterTerm", "note", "term", "corrected_prior"]
