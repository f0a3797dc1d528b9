"""Weighted least squares with an autocorrelation-robust covariance: the fitting core of the solvers.

``fit`` stacks the rows of every ``Group`` (one (sweep, joint) pair, or one joint of an
excitation run), fits once unweighted, estimates each group's residual variance σ², and fits
again with weights 1/σ². The samples of one sweep are not independent (interpolation onto a
combined grid, friction ripple, unmodelled slow effects), so the textbook s²·(YᵀWY)⁻¹ is too
optimistic: the covariance is a sandwich A⁻¹·B·A⁻¹ with A = YᵀWY and B the long-run variance
of the weighted scores, estimated sweep by sweep with a Bartlett (Newey–West) kernel whose
bandwidth follows the residuals' own autocorrelation length (``autocorrelation_time``); it
never goes below the independent-noise covariance. Where the rows say how their noise is made
(``Group.noise_map``: the deltas' interpolations of the empty run and of the legs), B comes from
that map at every lag, scaled up where the residuals' kernel estimate shows more
(``modelled_excess``): samples interpolated across one gap of a run's sample stream share one
error, which neither a short kernel nor the residuals (whose mean over a group the fit's offsets
absorb) can see. Before any of that, narrow spectral lines away from zero frequency are taken out of the
residuals (``without_lines``): a periodic-in-angle torque on a turning joint (the gear mesh) averages out of the
estimate, yet a kernel whose bandwidth reaches a quarter of its period reads it as long-run variance. An optional
relative drive-gain
uncertainty per joint is propagated on top (``gain_covariance``).

Used by the general solver, the dynamic baseline, the quality gate (per-pose fits) and the
drive-gain calibration (``long_run_scores`` for the standard error of a gain scale).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from payload_agent.errors import DataError

SIGMA_FLOOR_NM = 1e-9  # noise-free data: keep the weights finite
HAC_WINDOW_C = 5.0  # Sokal's automatic window: smallest lag M with M >= C·τ_int
HAC_MAX_FRACTION = 0.25  # bandwidth at most this fraction of a sweep's samples
LINE_FALSE_ALARM = 1e-4  # chance that white noise shows one spurious line in a whole series
LINE_LOWEST_BIN = 16  # a line must run through at least this many periods over the series to average out
LINE_BACKGROUND_BINS = 16  # least half-width of the running median that gives the spectrum's smooth background
LINE_MAX = 6  # lines taken out of one series at most (the mesh line, its drift, a harmonic)


@dataclass
class Group:
    """The rows of one (sweep, joint) pair."""

    label: str
    sweep: str
    Y: np.ndarray  # (n, p)
    y: np.ndarray  # (n,)
    joint: int = -1  # 0-based joint of these rows (-1: unknown)
    # (n, s) sparse: how the rows' noise is made of independent sample noises (``DeltaSweep.noise_map``)
    noise_map: Any = None


@dataclass(frozen=True)
class FitResult:
    """What ``fit`` returns: the estimate, its covariances and the fit's diagnostics."""

    theta: np.ndarray  # (p,) parameters
    cov: np.ndarray  # (p, p) autocorrelation-robust covariance (+ drive-gain term when asked)
    cov_iid: np.ndarray  # (p, p) textbook s²·(YᵀWY)⁻¹ for independent noise
    sigma_nm: dict[str, float]  # residual σ of each group (first pass), by group label: the weights
    weights: np.ndarray  # (n,) row weights 1/σ²
    normal_inverse: np.ndarray  # (p, p) (YᵀWY)⁻¹, for propagating systematic errors
    residual_rms_nm: dict[str, float]  # final residual RMS of each group, by label
    condition_number: float  # of the column-scaled normal matrix
    s2: float  # weighted residual variance per degree of freedom
    n: int  # rows
    tau: dict[str, float]  # integrated autocorrelation time of each sweep's residuals
    inflation: float  # largest ratio of robust to independent-noise standard deviation
    # σ of each group's noise: its final residuals ``without_lines`` (last, so that positional constructions hold)
    noise_sigma_nm: dict[str, float] = field(default_factory=dict)

    @property
    def std(self) -> np.ndarray:
        """Standard deviation of every parameter (from ``cov``)."""
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))


def autocorrelation_time(x: np.ndarray, *, c: float = HAC_WINDOW_C, max_lag: int | None = None) -> tuple[float, int]:
    """Integrated autocorrelation time τ = 1 + 2·Σρ_k of a series, and the window M it used.

    Sokal's automatic window: the smallest M with M >= c·τ(M). τ ≈ 1 for independent
    samples; a series whose samples come in correlated runs of length L has τ ≈ L, i.e. it
    carries as much information as n/τ independent samples.
    """
    x = np.asarray(x, float) - np.mean(x)
    n = len(x)
    max_lag = n // 2 if max_lag is None else min(max_lag, n - 1)
    var = float(x @ x)
    if n < 3 or var <= 0.0 or max_lag < 1:
        return 1.0, 0
    f = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[: max_lag + 1] / var
    tau = 1.0
    for m in range(1, max_lag + 1):
        tau += 2.0 * acf[m]
        if m >= c * tau:
            return max(tau, 1.0), m
    return max(tau, 1.0), max_lag


def without_lines(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(noise, lines): the residuals less their narrow spectral lines away from zero frequency, which is what the
    long-run variance is of, and those lines.

    What the kernel estimate must count is the residuals' spectral density at zero frequency (the scores' long-run
    variance); a deterministic oscillation of k ≥ ``LINE_LOWEST_BIN`` periods over the series (the mesh ripple of a
    turning joint, periodic in its angle, about 30 periods over a sweep at any speed) has none there: multiplied
    by the smooth sensitivities it averages out of the estimate. A Bartlett kernel whose bandwidth (from the same
    residuals' autocorrelation) reaches a fair part of its period leaks its power into the zero-frequency
    estimate, and its variance inflates the independent-noise level too. A line (``_line``) is a bin of the
    Hann-tapered periodogram above its running median background by more than white noise reaches in one of the
    series' bins but with chance ``LINE_FALSE_ALARM``; it is taken out by least squares as a sinusoid of that
    frequency whose amplitude and phase drift slowly (cos, sin times 1, t, t²: the mesh amplitude follows the
    load torque along the sweep), and the next line is sought, up to ``LINE_MAX``. What a line does leave in the
    estimate (its partial periods) is carried apart, ``line_leftover``. Broad low-frequency power (slow
    unmodelled torques, errors shared across a stream gap, an AR(1) or a random walk) is not a line and stays;
    in white noise nothing is found but by the false-alarm chance. The agent is not told the gear ratio. The
    noise is scaled by √(n/(n − c)) for the c columns taken out, so that its variance stays the noise's (a spurious
    line in a short sweep's white noise would otherwise take 6 of its degrees of freedom, 3 % of 180 samples).
    """
    r = np.asarray(r, float)
    x = r.copy()
    n = len(x)
    t = np.linspace(-1.0, 1.0, n)
    i = np.arange(n)
    columns = 0
    for _ in range(LINE_MAX):
        f = _line(x)
        if f is None:
            break
        phase = 2.0 * np.pi * f * i
        basis = np.column_stack([fn(phase) * t ** d for fn in (np.cos, np.sin) for d in range(3)])
        coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
        x -= basis @ coef
        columns += basis.shape[1]
    if not columns:
        return x, np.zeros(n)
    return x * np.sqrt(n / max(n - columns, 1)), r - x


def line_leftover(S: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """What the lines taken out of the residuals (``without_lines``) leave in the estimate, as a score variance:
    the outer product of Sᵀ·lines, ``S`` (n, p) the estimate's scores per unit residual of each sample.

    A line over k periods averages out of a smooth sensitivity but for its partial periods (order 1/k of its
    amplitude, 0.1–1 % for the mesh ripple over a sweep): that part is an error of the estimate, of the size
    measured here, and stays in σ. The line's own share the fit absorbed is smooth and shows in ``r`` only to
    second order, so the line found in the residuals is the line in the data."""
    d = S.T @ lines
    return np.outer(d, d)


def _line(x: np.ndarray) -> float | None:
    """The frequency (cycles per sample) of the strongest line of ``x`` (see ``without_lines``), or None."""
    from scipy.ndimage import median_filter

    n = len(x)
    taper = np.hanning(n)
    P = np.abs(np.fft.rfft((x - np.mean(x)) * taper)) ** 2
    nb = len(P)
    if nb < LINE_LOWEST_BIN + 2 * LINE_BACKGROUND_BINS:
        return None
    # the running median over ±h bins, h doubling from LINE_BACKGROUND_BINS up to nb/16 but never past zero
    # frequency: a symmetric window's median is the middle value on any monotone slope (an AR(1)'s, a random
    # walk's) and steadier the wider it is, where a window reflected at zero would sit low beside a steep start
    background = np.full(nb, np.inf)  # below the first window: no line sought (LINE_LOWEST_BIN is above it)
    h = LINE_BACKGROUND_BINS
    while True:
        smooth = median_filter(P, size=2 * h + 1, mode="reflect")
        background[h:] = smooth[h:]
        if 2 * h > nb // 16:
            break
        h *= 2
    background /= np.log(2.0)
    ratio = P / np.maximum(background, np.finfo(float).tiny)
    ratio[:LINE_LOWEST_BIN] = 0.0
    ratio[-2:] = 0.0
    k = int(np.argmax(ratio))
    if ratio[k] <= np.log(nb / LINE_FALSE_ALARM):
        return None
    grid = (k + np.linspace(-1.0, 1.0, 41)) / n  # the peak between bins
    power = np.abs(np.exp(-2j * np.pi * np.outer(grid, np.arange(n))) @ ((x - np.mean(x)) * taper)) ** 2
    return float(grid[int(np.argmax(power))])


def long_run_scores(U: np.ndarray, bandwidth: int) -> np.ndarray:
    """Σ_l k(l)·Σ_i u_i u_{i+l}ᵀ (both signs of l) with the Bartlett kernel k(l) = 1 − |l|/(L+1).

    ``U``: (n, p) scores of consecutive samples; the long-run (HAC) variance of their sum.
    """
    B = U.T @ U
    for lag in range(1, bandwidth + 1):
        G = U[lag:].T @ U[:-lag]
        B += (1.0 - lag / (bandwidth + 1.0)) * (G + G.T)
    return B


def modelled_noise(noise_cov: Any, bandwidth: int | None, scores: list[tuple[np.ndarray, float]]) -> np.ndarray:
    """The long-run variance of a sweep's scores from how its samples' noise is made, Σ_j σ_j²·Gᵀ·(K∘N·Nᵀ)·G.

    ``noise_cov``: N·Nᵀ (sparse) of the sweep's (n, s) noise map N (``DeltaSweep.noise_map``): ε = N·e with
    e independent, so Cov(ε) = σ²·N·Nᵀ. ``scores``: per joint, (G = W·Y of its rows, its residual
    variance; σ_j² of one source is that over the mean of diag N·Nᵀ, the loaded and the empty run's
    samples taken as equally noisy). K: the Bartlett kernel of ``bandwidth``, or all ones (None).
    """
    from scipy import sparse

    S = sparse.coo_matrix(noise_cov)
    k = 1.0
    if bandwidth is not None:
        lag = np.abs(S.row - S.col)
        k = np.where(lag <= bandwidth, 1.0 - lag / (bandwidth + 1.0), 0.0)
    D = sparse.csr_matrix((k * S.data, (S.row, S.col)), shape=S.shape)
    mean_gain = float(np.mean(S.diagonal()))
    out = np.zeros((scores[0][0].shape[1],) * 2)
    for G, var in scores:
        out += var / mean_gain * (G.T @ (D @ G))
    return out


def modelled_excess(B_kernel: np.ndarray, noise: Any, bandwidth: int, scores: list[tuple[np.ndarray, float]]
                    ) -> np.ndarray:
    """A sweep's long-run score variance: the noise map's (``modelled_noise``, every lag), scaled up by as much
    as the residuals' kernel estimate ``B_kernel`` exceeds the map's at the same kernel (mean over the
    parameters of their variance ratios; never scaled down).

    The map counts a run of samples interpolated across one stream gap (of the empty run, or of a leg
    under the combination's grid) as the one shared error it is, which a short kernel misses and which
    the residuals cannot show: the fit's offsets absorb each group's mean, so the kernel estimate runs
    low. It stays as the check on what the map does not know (friction ripple, slow unmodelled torques);
    one ratio, not one per direction, so that its own scatter does not widen σ on its own.
    """
    S = noise @ noise.T
    at_kernel = np.diag(modelled_noise(S, bandwidth, scores))
    seen = at_kernel > 1e-12 * max(float(np.max(at_kernel)), 1e-300)
    ratio = float(np.mean(np.diag(B_kernel)[seen] / at_kernel[seen])) if seen.any() else 1.0
    return max(ratio, 1.0) * modelled_noise(S, None, scores)


def weighted_lstsq(Y: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted LS via a column-scaled lstsq; returns θ and (YᵀWY)⁻¹."""
    sw = np.sqrt(w)
    A = Y * sw[:, None]
    b = y * sw
    scale = np.sqrt(np.sum(A ** 2, axis=0))
    scale[scale == 0] = 1.0
    As = A / scale
    theta_s, *_ = np.linalg.lstsq(As, b, rcond=None)
    theta = theta_s / scale
    normal_s = As.T @ As
    inv = np.linalg.pinv(normal_s) / np.outer(scale, scale)
    return theta, inv


def fit(groups: list[Group], gain_rel_std: Iterable[float] | None = None) -> FitResult:
    """Two-pass weighted fit with the autocorrelation-robust covariance (see the module docstring).

    ``gain_rel_std`` (per joint, 0-based, relative): the standard uncertainty of each drive
    gain, added to ``cov`` through ∂θ/∂gain (``gain_covariance``).
    """
    if not groups:
        raise DataError("general: no sweep carries any payload torque (no usable joint rows)")
    Y = np.vstack([g.Y for g in groups])
    y = np.concatenate([g.y for g in groups])
    n, p = Y.shape
    if n <= p:
        raise DataError(f"general: only {n} samples for {p} unknowns")
    idx = np.repeat(np.arange(len(groups)), [len(g.y) for g in groups])

    theta0, _ = weighted_lstsq(Y, y, np.ones(n))
    r0 = y - Y @ theta0
    dof_factor = n / (n - p)
    sigma = np.array([np.sqrt(np.mean(r0[idx == i] ** 2) * dof_factor) for i in range(len(groups))])
    sigma = np.maximum(sigma, SIGMA_FLOOR_NM)
    w = 1.0 / sigma[idx] ** 2

    theta, inv = weighted_lstsq(Y, y, w)
    r_fit = y - Y @ theta
    starts = np.concatenate(([0], np.cumsum([len(g.y) for g in groups])))
    # the noise: each group's residuals without the lines that average out of the estimate (``without_lines``)
    r, lines = (np.concatenate(a) for a in zip(*(without_lines(r_fit[starts[i]:starts[i + 1]])
                                                 for i in range(len(groups)))))
    # each group's noise σ: the first pass's, less the lines' share of its final residuals (the same without lines)
    noise_sigma = np.array([max(sigma[i] * float(np.sqrt(np.sum(r[idx == i] ** 2) / max(np.sum(r_fit[idx == i] ** 2),
                                                                                    1e-300))), SIGMA_FLOOR_NM)
                            for i in range(len(groups))])
    s2 = float(r @ (w * r) / (n - p))
    cov_iid = s2 * inv

    # sandwich: long-run variance of the weighted scores, sweep by sweep (the joints of one
    # sample share its instant, so their scores are summed before the lags are taken; the samples
    # whose noise map is known: from it, and from the residuals only where they show more)
    B = np.zeros((p, p))
    tau: dict[str, float] = {}
    for sweep in dict.fromkeys(g.sweep for g in groups):
        members = [i for i, g in enumerate(groups) if g.sweep == sweep]
        U = sum(groups[i].Y * (w[starts[i]:starts[i + 1]] * r[starts[i]:starts[i + 1]])[:, None] for i in members)
        z = sum(r[starts[i]:starts[i + 1]] / noise_sigma[i] for i in members)  # normalised residual per instant
        m = len(z)
        t, lag = autocorrelation_time(z, max_lag=max(1, int(HAC_MAX_FRACTION * m)))
        tau[sweep] = t
        B_sweep = long_run_scores(U, lag) * dof_factor
        noise = groups[members[0]].noise_map
        if noise is not None and noise.shape[0] == m:
            B_sweep = modelled_excess(B_sweep, noise, lag, [
                (groups[i].Y * w[starts[i]:starts[i + 1], None], noise_sigma[i] ** 2) for i in members])
        rows = np.concatenate([np.arange(starts[i], starts[i + 1]) for i in members])
        B += B_sweep + line_leftover(Y[rows] * w[rows, None], lines[rows])
    cov = inv @ B @ inv
    # never below the independent-noise covariance (the kernel estimate is itself noisy)
    ratio = np.sqrt(np.maximum(np.diag(cov), 0.0) / np.maximum(np.diag(cov_iid), 1e-300))
    if np.any(ratio < 1.0):
        f = np.sqrt(np.maximum(1.0 / ratio, 1.0))
        cov = cov * np.outer(f, f)
    if gain_rel_std is not None:
        cov = cov + gain_covariance(groups, Y, w, inv, theta, gain_rel_std)

    normal = (Y * w[:, None]).T @ Y
    d = 1.0 / np.sqrt(np.diag(normal))
    cond = float(np.linalg.cond(normal * np.outer(d, d)))
    rms = {g.label: float(np.sqrt(np.mean(r_fit[idx == i] ** 2))) for i, g in enumerate(groups)}
    return FitResult(
        theta=theta, cov=cov, cov_iid=cov_iid, sigma_nm=dict(zip([g.label for g in groups], sigma.tolist())),
        weights=w, normal_inverse=inv, residual_rms_nm=rms, condition_number=cond, s2=s2, n=n, tau=tau,
        inflation=float(np.max(np.sqrt(np.diag(cov) / np.maximum(np.diag(cov_iid), 1e-300)))),
        noise_sigma_nm=dict(zip([g.label for g in groups], noise_sigma.tolist())))


def gain_directions(groups: list[Group], Y: np.ndarray, w: np.ndarray, inv: np.ndarray, theta: np.ndarray,
                    gain_rel_std: Iterable[float]) -> dict[int, np.ndarray]:
    """{joint j: σ_j·∂θ/∂ε_j}: the fit's response to one standard uncertainty of each drive gain (joints with a
    declared uncertainty and rows only).

    A relative gain error ε_j multiplies every measured Δτ on joint j by (1 + ε_j), so
    ∂θ/∂ε_j = (YᵀWY)⁻¹·YᵀW·y_j with y_j the measured torques of joint j (0 elsewhere);
    the fitted model's prediction is used for y_j so that noise does not enter twice.
    """
    std = np.asarray(list(gain_rel_std), float)
    pred = Y @ theta
    joint_of_row = np.repeat([g.joint for g in groups], [len(g.y) for g in groups])
    out = {}
    for j, sj in enumerate(std):
        rows = joint_of_row == j
        if sj > 0 and rows.any():
            out[j] = sj * (inv @ (Y[rows].T @ (w[rows] * pred[rows])))
    return out


def gain_covariance(groups: list[Group], Y: np.ndarray, w: np.ndarray, inv: np.ndarray, theta: np.ndarray,
                    gain_rel_std: Iterable[float]) -> np.ndarray:
    """Covariance of θ from independent relative drive-gain uncertainties (one per joint): Σ_j of the outer
    products of ``gain_directions``."""
    return sum((np.outer(d, d) for d in gain_directions(groups, Y, w, inv, theta, gain_rel_std).values()),
               np.zeros((len(theta), len(theta))))


def cog_with_covariance(theta: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """c = θ[1:]/θ[0] and its 3×3 covariance (delta method)."""
    m = theta[0]
    c = theta[1:] / m
    J = np.zeros((3, 4))
    J[:, 0] = -theta[1:] / m ** 2
    J[:, 1:] = np.eye(3) / m
    return c, J @ cov @ J.T
