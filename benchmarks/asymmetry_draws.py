"""What carries a cell's mean mass error on an arm with a Coulomb direction asymmetry: the case's draws.

The asymmetry a_j leaves a_j·Δs_j·C_j in the two-direction average (Δs the friction level's change between the empty
and the loaded run), and through a drive-gain calibration a_j·Δr_j·C_j of the reference run in the gains: both linear
in a, whose draws (uniform ±15 %, ``benchmarks.hard.draw``) have mean zero, as have the drifts
(``benchmarks.cases.robot_draws``). This regresses each payload's push (realistic+asymmetry's mass error less the
plain realistic one's, same case, averaged over noise draws) on the drawn products a_j·Δs and a_j·Δr·m of joints 2
and 3, and prints the fit, the products' sample means over the cell's payloads, and the push the fit predicts for
the mean of every further block of as many payloads (draws only, nothing simulated): how far the cell's mean is
from what its draws make it.

    .venv/bin/python -m benchmarks.asymmetry_draws --asym benchmarks/results/session21-end-asym-72.json \\
        --plain benchmarks/results/session15-table72-start.json [--procedure 10] [--method general-bi-cal-comp]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from benchmarks import cases

NAMES = ("a2·Δs", "a3·Δs", "a2·Δr·m", "a3·Δr·m")


def products(index: int, mass_kg: float) -> np.ndarray:
    """The drawn products of one payload index (realistic+asymmetry's draws)."""
    d = cases.robot_draws("realistic+asymmetry", index)
    a = np.asarray(d["effects"].coulomb_asymmetry, float)
    return np.array([a[1] * d["drift_load"], a[2] * d["drift_load"], a[1] * d["drift_ref"] * mass_kg,
                     a[2] * d["drift_ref"] * mass_kg])


def pushes(asym: list[dict], plain: list[dict], procedure: str, method: str) -> dict[int, float]:
    """Payload index -> the asymmetry's push on the mass (g), averaged over the noise draws both files have."""
    key = lambda c: (c["procedure"], c["method"], c["payload"], c["noise_draw"])  # noqa: E731
    base = {key(c): c["mass_err_g"] for c in plain if c["scenario"] == "realistic" and c.get("mass_err_g") is not None}
    out: dict[int, list[float]] = {}
    for c in asym:
        if c["procedure"] == procedure and c["method"] == method and key(c) in base and c.get("mass_err_g") is not None:
            out.setdefault(c["payload"], []).append(c["mass_err_g"] - base[key(c)])
    return {i: float(np.mean(v)) for i, v in sorted(out.items())}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--asym", required=True, help="accuracy results JSON with realistic+asymmetry rows")
    p.add_argument("--plain", required=True, help="accuracy results JSON with realistic rows of the same cases")
    p.add_argument("--procedure", default="10")
    p.add_argument("--method", default="general-bi-cal-comp")
    p.add_argument("--blocks", type=int, default=25, help="further blocks of payloads drawn for the spread (default 25)")
    args = p.parse_args()
    push = pushes(json.load(open(args.asym))["cases"], json.load(open(args.plain))["cases"], args.procedure, args.method)
    n = len(push)
    masses = [m for m, _ in cases.payloads(n * (args.blocks + 1))]
    X = np.array([products(i, masses[i]) for i in push])
    y = np.array(list(push.values()))
    coef, *_ = np.linalg.lstsq(np.column_stack([np.ones(n), X]), y, rcond=None)
    resid = y - np.column_stack([np.ones(n), X]) @ coef
    print(f"{args.procedure} / {args.method}: {n} payloads, push mean {y.mean():+.2f} g (s.e. {y.std(ddof=1) / np.sqrt(n):.2f} "
          f"over payloads), sd {y.std(ddof=1):.2f} g")
    print("fit: intercept {:+.2f} g, ".format(coef[0]) + ", ".join(f"{k} {c:+.1f}" for k, c in zip(NAMES, coef[1:]))
          + f" g per unit; residual rms {np.sqrt(np.mean(resid ** 2)):.2f} g")
    print("sample means of the products: " + ", ".join(f"{k} {v:+.5f}" for k, v in zip(NAMES, X.mean(0))))
    more = np.array([products(i, masses[i]) for i in range(n, n * (args.blocks + 1))]) @ coef[1:]
    blocks = more.reshape(args.blocks, n).mean(1)
    print(f"predicted push of {args.blocks} further blocks of {n} payloads: mean {more.mean():+.2f} g, block means "
          f"sd {blocks.std(ddof=1):.2f} g, range {blocks.min():+.2f} to {blocks.max():+.2f} g; this cell's {y.mean():+.2f} g")


if __name__ == "__main__":
    main()
