"""What a solver returns, and how it is written (JSON) and shown (table)."""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np


@dataclass(frozen=True, eq=False)
class Estimate:
    """One solver's estimate of mass and centre of mass (SI), frozen: a change is a new estimate.

    ``covariance`` is the 4×4 covariance of θ = [m, m·cx, m·cy, m·cz] as a read-only array (a nested
    list given by a caller is converted); ``notes`` a tuple (``with_notes`` adds to a copy).
    """

    solver: str
    mass_kg: float
    cog_m: tuple[float, float, float]
    residual_rms_nm: dict[str, float] = field(default_factory=dict)  # per sweep (and joint where relevant)
    samples: dict[str, int] = field(default_factory=dict)
    mass_std_kg: float | None = None
    cog_std_m: tuple[float, float, float] | None = None
    covariance: np.ndarray | None = None  # of θ = [m, m·cx, m·cy, m·cz], SI
    condition_number: float | None = None
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.covariance is not None:
            cov = np.array(self.covariance, dtype=float)
            cov.setflags(write=False)
            object.__setattr__(self, "covariance", cov)
        object.__setattr__(self, "notes", tuple(self.notes))

    def with_notes(self, *notes: str) -> "Estimate":
        """This estimate with ``notes`` added after its own."""
        return replace(self, notes=self.notes + tuple(notes)) if notes else self

    @property
    def cog_mm(self) -> tuple[float, float, float]:
        return tuple(1000.0 * v for v in self.cog_m)

    def to_json(self) -> dict[str, Any]:
        d = {"solver": self.solver, "mass_kg": self.mass_kg, "cog_mm": list(self.cog_mm),
             "residual_rms_nm": self.residual_rms_nm, "samples": self.samples}
        if self.mass_std_kg is not None:
            d["mass_ci95_kg"] = 1.96 * self.mass_std_kg
            d["mass_std_kg"] = self.mass_std_kg
        if self.cog_std_m is not None:
            d["cog_std_mm"] = [1000.0 * v for v in self.cog_std_m]
            d["cog_ci95_mm"] = [1960.0 * v for v in self.cog_std_m]
        if self.covariance is not None:
            d["covariance_theta_si"] = self.covariance.tolist()
        if self.condition_number is not None:
            d["condition_number"] = self.condition_number
        if self.notes:
            d["notes"] = list(self.notes)
        return d


@dataclass
class RunResult:
    """The result file: the chosen estimate first, other solvers' estimates beside it."""

    robot: str
    run_dir: str
    primary: Estimate
    others: list[Estimate] = field(default_factory=list)
    quality: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        d = {"robot": self.robot, "run_dir": self.run_dir, **self.primary.to_json(),
             "estimates": {e.solver: e.to_json() for e in [self.primary, *self.others]}}
        if self.quality:
            d["quality"] = self.quality
        d.update(self.extra)
        return d

    def write(self, path: Path) -> None:
        """Atomically (temp file, fsync, rename): a crash never leaves a half-written result."""
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(json.dumps(self.to_json(), indent=2))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)


def format_table(result: RunResult, truth: dict[str, Any] | None = None) -> str:
    """The terminal summary: one row per quantity, one column per solver (+ truth in simulation)."""
    ests = [result.primary, *result.others]
    head = ["", *[e.solver + (" *" if e is result.primary else "") for e in ests]]
    rows = [["mass [kg]", *[_pm(e.mass_kg, e.mass_std_kg, 4) for e in ests]]]
    for i, axis in enumerate("xyz"):
        rows.append([f"cog {axis} [mm]", *[_pm(e.cog_mm[i], None if e.cog_std_m is None else 1000 * e.cog_std_m[i], 2)
                                          for e in ests]])
    if truth is not None:
        head.append("truth")
        rows[0].append(f"{truth['mass_kg']:.4f}")
        for i in range(3):
            rows[i + 1].append(f"{truth['cog_mm'][i]:.2f}")
    widths = [max(len(r[c]) for r in [head, *rows]) for c in range(len(head))]
    lines = ["  ".join(cell.rjust(w) for cell, w in zip(r, widths)) for r in [head, *rows]]
    lines.insert(1, "  ".join("-" * w for w in widths))
    lines.append("(* = primary result; ± is the 95 % interval where the solver reports one)")
    p = result.primary
    if p.condition_number is not None or p.residual_rms_nm:
        worst = max(p.residual_rms_nm.items(), key=lambda kv: kv[1], default=None)
        parts = []
        if p.condition_number is not None:
            parts.append(f"condition number {p.condition_number:.3g}")
        if worst is not None:
            parts.append(f"largest residual RMS {worst[1]:.3g} N·m ({worst[0]})")
        lines.append(f"{p.solver}: " + ", ".join(parts))
    if result.quality:
        passed = bool(result.quality.get("passed"))
        checks = ", ".join(f"{c['check']}: z = {c['z']:+.1f}" if "z" in c else c["check"]
                           for c in result.quality.get("checks", []) if passed or not c.get("passed", False))
        verdict = "passed" if passed else "FAILED"  # FAILED (…) names only the checks that failed
        lines.append(f"quality checks {verdict}" + (f" ({checks})" if checks else ""))
        for reason in result.quality.get("reasons", []):
            lines.append(f"  - {reason}")
    lines.extend(inertia_lines(result.extra, truth))
    return "\n".join(lines)


def inertia_lines(extra: dict[str, Any], truth: dict[str, Any] | None = None) -> list[str]:
    """The inertia part's lines of the summary (none for a run without wrist moves)."""
    part = extra.get("inertia")
    if part is None:
        return []
    tensor, std = extra.get("inertia_com_kgm2"), extra.get("inertia_com_std_kgm2")
    if tensor is None:
        return [f"inertia: not given ({part.get('refused')})"]
    names = ("xx", "xy", "xz", "yy", "yz", "zz")
    idx = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    cells = [f"I{n} {tensor[i][j]:.5f} ± {1.96 * std[i][j]:.5f}" for n, (i, j) in zip(names, idx)]
    out = ["inertia about the CoM [kg·m², flange axes, ± 95 %]: " + ", ".join(cells)]
    if truth is not None and truth.get("inertia_com_kgm2") is not None:
        t = truth["inertia_com_kgm2"]
        out.append("  truth: " + ", ".join(f"I{n} {t[i][j]:.5f}" for n, (i, j) in zip(names, idx)))
    if part.get("inconsistency"):
        out.append(f"  (the data alone gave a tensor that is {part['inconsistency']}: projected onto the possible ones)")
    return out


def _pm(value: float, std: float | None, digits: int) -> str:
    if std is None or not math.isfinite(std):
        return f"{value:.{digits}f}"
    return f"{value:.{digits}f} ± {1.96 * std:.{digits}f}"
