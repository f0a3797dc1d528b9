"""Is the reported σ calibrated? rms(error/σ) for the mass and each CoM axis, and 95 % coverage (issue 22).

Not a test: it prints numbers. The accuracy benchmark's main table pools the three CoM axes into one
rms(err/σ); issue 22 asks for each axis on its own (an axis whose σ is too narrow can hide behind two that
are too wide). One row per (scenario, procedure, method) of one or more ``benchmarks.accuracy --json`` files:

    .venv/bin/python -m benchmarks.calibration benchmarks/results/sigma-after.json [MORE.json ...]

A cell is "in band" when rms(err/σ) is in [0.7, 1.3] and the 95 % coverage (mass: |err| ≤ 1.96 σ; CoM: inside
the 95 % ellipsoid) is at least 0.9, the issue's target; cells outside are marked with *.

With 24 cases a cell is a small sample: a σ that is exactly right (errors N(0, 1) in σ units) leaves a cell out of
that band about 30 % of the time (the rms of 24 draws is 1 ± 0.14; 3 misses of 24, coverage 0.88, come 12 % of the
time). So each cell also gets the chance, under an exactly right σ, of a result as far out as this one (two-sided
for each rms, χ²_n; one-sided for too many misses, binomial(n, 0.05); Bonferroni over the six), and the table ends
with how many cells such a σ would leave out of band on average at these sample sizes (drawn, fixed seed).

With several sensor-noise draws per case (``benchmarks.accuracy --noise-draws``) the draws of one case share its
systematic error, so they are worth fewer independent cases than their count: column n gives the count and, in
brackets, the effective number of cases of the mass and CoM axes (``effective_sizes``), on which the chance and the
"out by chance" count are computed.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

RMS_BAND = (0.7, 1.3)
MIN_COVERAGE = 0.9


def rows_of(paths: list[Path]) -> list[dict]:
    """Every case row (errors and z-scores) of the given benchmark JSON files, failed cases left out."""
    out: list[dict] = []
    for path in paths:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
        out.extend(r for r in data["cases"] if "error" not in r and r.get("z_mass") is not None)
    return out


def cell(rows: list[dict]) -> dict:
    """rms(err/σ) of mass, x, y, z and the 95 % coverage of mass and CoM over one cell's cases, and the cases'
    effective number per quantity (``effective_sizes``)."""
    zm = np.array([r["z_mass"] for r in rows], float)
    zc = np.array([r["z_cog"] for r in rows if r.get("z_cog") is not None], float).reshape(-1, 3)
    cc = [r["cog_in_ci95"] for r in rows if r.get("cog_in_ci95") is not None]
    return {"n": len(rows), "rms_m": float(np.sqrt(np.mean(zm ** 2))),
            "rms_xyz": [float(v) for v in np.sqrt(np.mean(zc ** 2, axis=0))] if len(zc) else [np.nan] * 3,
            "in95_m": float(np.mean(np.abs(zm) <= 1.959964)), "in95_c": float(np.mean(cc)) if cc else np.nan,
            "mean_abs_m_g": float(np.mean(np.abs([r["mass_err_g"] for r in rows]))),
            "mean_c_mm": float(np.mean([r["cog_err_mm"] for r in rows])), **effective_sizes(rows)}


def draw_correlation(z: np.ndarray, case: np.ndarray) -> float:
    """The correlation of one quantity's z between noise draws of the same case (the share of its variance that
    the arm, the payload and the drifts fix: the systematic part), from the spread of the case means against the
    spread within cases; 0 for one draw per case."""
    groups = [z[case == k] for k in np.unique(case)]
    groups = [g for g in groups if len(g) > 1]
    if not groups:
        return 0.0
    within = float(np.mean([np.var(g, ddof=1) for g in groups]))
    draws = float(np.mean([len(g) for g in groups]))
    between = float(np.var([np.mean(g) for g in groups], ddof=1)) - within / draws if len(groups) > 1 else 0.0
    return max(between, 0.0) / (max(between, 0.0) + within) if within + max(between, 0.0) > 0 else 0.0


def effective_sizes(rows: list[dict]) -> dict:
    """The number of independent cases a cell's z-scores are worth, per quantity (n_m, n_xyz) and for the CoM
    coverage (n_c). Noise draws of one case (``benchmarks.accuracy --noise-draws``) share its systematic error:
    with R draws of correlation ρ, the mean of z² over n cases has the variance of n / (1 + (R − 1)·ρ²)
    independent ones (Cov(z₁², z₂²) = 2ρ²); a miss indicator is taken as correlated by ρ itself (more than the
    bivariate normal gives: the chance errs towards "could be right")."""
    case = np.array([r.get("payload", k) for k, r in enumerate(rows)])
    draws = len(rows) / max(len(np.unique(case)), 1)
    zm = np.array([r["z_mass"] for r in rows], float)
    with_c = [r for r in rows if r.get("z_cog") is not None]
    zc = np.array([r["z_cog"] for r in with_c], float).reshape(-1, 3)
    case_c = np.array([r.get("payload", k) for k, r in enumerate(with_c)])
    rho_m = draw_correlation(zm, case)
    rho_xyz = [draw_correlation(zc[:, k], case_c) for k in range(3)] if len(zc) else [0.0] * 3

    def size(n: int, inflation: float) -> float:
        return n / (1.0 + (draws - 1.0) * inflation)

    return {"n_m": size(len(zm), rho_m ** 2), "n_xyz": [size(len(zc), r ** 2) for r in rho_xyz],
            "n_cover_m": size(len(zm), rho_m), "n_cover_c": size(len(zc), float(np.mean(rho_xyz))),
            "draws": draws}


def chance(c: dict) -> float:
    """The probability, under an exactly right σ, of a cell at least as far from calibrated as ``c`` (the least
    of its six tests' p-values, times six, at most 1), each test on the cell's effective number of cases."""
    from scipy import stats

    ps = []
    for rms, n in zip((c["rms_m"], *c["rms_xyz"]), (c["n_m"], *c["n_xyz"])):
        if np.isfinite(rms) and n > 0:
            cdf = float(stats.chi2.cdf(n * rms ** 2, n))
            ps.append(2.0 * min(cdf, 1.0 - cdf))
    for cover, n in ((c["in95_m"], c["n_cover_m"]), (c["in95_c"], c["n_cover_c"])):
        if np.isfinite(cover) and n > 0:
            # misses on the effective sample, the binomial's survival function continued to non-integer counts
            ps.append(float(stats.beta.cdf(0.05, max(n * (1.0 - cover), 1e-9), n * cover + 1.0)))
    return min(1.0, len(ps) * min(ps)) if ps else float("nan")


def out_of_band_by_chance(sizes: list[int], draws: int = 4000) -> float:
    """How many of cells with these sample sizes an exactly right σ leaves out of band, on average (drawn:
    independent N(0, 1) errors per quantity; mass coverage |z| ≤ 1.96, CoM coverage inside the 95 % ellipsoid)."""
    rng = np.random.default_rng(20261127)
    total = 0.0
    for n in sizes:
        z = rng.standard_normal((draws, n, 4))
        rms = np.sqrt(np.mean(z ** 2, axis=1))
        ok = np.all((rms >= RMS_BAND[0]) & (rms <= RMS_BAND[1]), axis=1)
        ok &= np.mean(np.abs(z[:, :, 0]) <= 1.959964, axis=1) >= MIN_COVERAGE
        ok &= np.mean(np.sum(z[:, :, 1:] ** 2, axis=2) <= 7.814728, axis=1) >= MIN_COVERAGE
        total += 1.0 - float(np.mean(ok))
    return total


def in_band(c: dict) -> bool:
    rms = [c["rms_m"], *c["rms_xyz"]]
    return all(RMS_BAND[0] <= v <= RMS_BAND[1] for v in rms) and min(c["in95_m"], c["in95_c"]) >= MIN_COVERAGE


def table(rows: list[dict]) -> str:
    keys = list(dict.fromkeys((r["scenario"], r["procedure"], r["method"]) for r in rows))
    lines = ["| scenario | procedure | method | n | mean \\|Δm\\| g | mean Δc mm | rms(err/σ) m / x / y / z | "
             "in 95 % m / c | in band | chance under a right σ |", "|---|---|---|---|---|---|---|---|---|---|"]
    cells = []
    for key in keys:
        c = cell([r for r in rows if (r["scenario"], r["procedure"], r["method"]) == key])
        cells.append(c)
        proc = key[1] if key[1] in ("default", "excitation") else f"{key[1]} %"
        rms = " / ".join(f"{v:.2f}" for v in (c["rms_m"], *c["rms_xyz"]))
        sizes = (c["n_m"], *c["n_xyz"])
        n = f"{c['n']}" if c["draws"] == 1 else f"{c['n']} ({min(sizes):.0f}–{max(sizes):.0f})"
        lines.append(f"| {key[0]} | {proc} | {key[2]} | {n} | {c['mean_abs_m_g']:.1f} | {c['mean_c_mm']:.2f} | "
                     f"{rms} | {c['in95_m']:.2f} / {c['in95_c']:.2f} | {'yes' if in_band(c) else '*'} | "
                     f"{chance(c):.3f} |")
    out = sum(not in_band(c) for c in cells)
    lines.append(f"\n{out} of {len(cells)} cells out of band; an exactly right σ would leave "
                 f"{out_of_band_by_chance([max(2, round(min(c['n_m'], *c['n_xyz']))) for c in cells]):.1f} out on average at these sample sizes; "
                 f"{sum(chance(c) < 0.05 for c in cells)} cells have a chance below 0.05")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("json", nargs="+", type=Path, help="benchmarks.accuracy --json outputs")
    args = p.parse_args(argv)
    missing = [str(path) for path in args.json if not path.is_file()]
    if missing:
        p.error(f"no such file: {', '.join(missing)}")
    rows = rows_of(args.json)
    if not rows:
        p.error("no case with a reported σ in these files")
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
