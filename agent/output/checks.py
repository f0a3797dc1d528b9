"""The quality checks of a result, as rows a person reads: value and limit with units, and by how much it failed.

``result.json`` stores each check as ``{check, value, limit, passed, ...}`` (see
``payload_agent.evaluation.quality``). Most limits are maxima; "mass significance" and
"samples per sweep" are minima. A failed check's margin is the distance beyond the limit in
the check's unit and as a share of the limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

MINIMUM_CHECKS = ("mass significance", "samples per sweep")


@dataclass(frozen=True)
class CheckRow:
    name: str
    passed: bool
    value: str  # with unit
    limit: str  # with unit and direction ("≤ 3 σ")
    margin: str  # "" when passed; else "exceeds by 1.2 σ (40 %)"
    detail: str  # the check's own numbers (differences, σ) and its reason

    def to_json(self) -> dict[str, Any]:
        return {"check": self.name, "passed": self.passed, "value": self.value, "limit": self.limit,
                "margin": self.margin, "detail": self.detail}


def _unit(name: str) -> tuple[str, float, str]:
    """(unit suffix, scale applied to value and limit, format) for a check name."""
    if " vs " in name or name == "mass significance":
        return " σ", 1.0, ".2f"
    if name == "mass upper bound":
        return " kg", 1.0, ".3f"
    if name.startswith("residual"):
        return " × noise", 1.0, ".2f"
    if name.startswith("samples"):
        return " samples", 1.0, ".0f"
    if name.startswith("drive gain"):
        return " %", 100.0, ".2f"
    return "", 1.0, ".4g"


def check_row(c: Mapping[str, Any]) -> CheckRow:
    name = str(c.get("check", "?"))
    passed = bool(c.get("passed"))
    unit, scale, fmt = _unit(name)
    minimum = name.startswith(MINIMUM_CHECKS)
    value, limit = c.get("value"), c.get("limit")
    num = isinstance(value, (int, float)) and isinstance(limit, (int, float))
    v_txt = f"{scale * value:{fmt}}{unit}" if isinstance(value, (int, float)) and math.isfinite(value) else str(value)
    if name.startswith("drive gain") and isinstance(value, (int, float)):
        v_txt = f"|ratio − 1| = {v_txt}"
    l_txt = (f"{'≥' if minimum else '≤'} {scale * limit:{fmt}}{unit}"
             if isinstance(limit, (int, float)) and math.isfinite(limit) else "")
    margin = ""
    if not passed and num:
        over = (limit - value) if minimum else (value - limit)
        if math.isfinite(over):
            share = f" ({100 * over / abs(limit):.0f} %)" if limit else ""
            margin = f"{'short of' if minimum else 'exceeds'} the limit by {scale * over:{fmt}}{unit}{share}"
        else:
            margin = "beyond any limit (infinite)"
    return CheckRow(name, passed, v_txt, l_txt, margin, _detail(c))


def _detail(c: Mapping[str, Any]) -> str:
    parts = []
    if "difference_kg" in c and "sigma_kg" in c:
        parts.append(f"Δm = {c['difference_kg']:+.4f} kg, σ = {c['sigma_kg']:.4f} kg")
    if "difference_mm" in c and "sigma_mm" in c:
        parts.append(f"Δ = {c['difference_mm']:+.2f} mm, σ = {c['sigma_mm']:.2f} mm")
    if "mass_kg" in c and "mass_std_kg" in c:
        parts.append(f"m = {c['mass_kg']:.4f} ± {1.96 * c['mass_std_kg']:.4f} kg (95 %)")
    if "residual_rms_nm" in c and "noise_nm" in c:
        parts.append(f"{c.get('where', '')}: RMS {c['residual_rms_nm']:.3f} N·m, noise {c['noise_nm']:.3f} N·m".lstrip(": "))
    if "ratio" in c:
        parts.append(f"measured / modelled torque {c['ratio']:.4f}" + (f" ± {c['ratio_std']:.4f}" if "ratio_std" in c
                                                                        else ""))
    if "where" in c and "residual_rms_nm" not in c:
        parts.append(str(c["where"]))
    if not c.get("passed") and c.get("reason"):
        parts.append(str(c["reason"]))
    return "; ".join(parts)


def check_rows(quality: Mapping[str, Any] | None) -> list[CheckRow]:
    """Failed checks first (the operator's question is "what failed?"), then the passed ones."""
    rows = [check_row(c) for c in (quality or {}).get("checks", [])]
    return [r for r in rows if not r.passed] + [r for r in rows if r.passed]


def failed_summary(quality: Mapping[str, Any] | None) -> list[str]:
    """One line per failed check, for the terminal: name, value, limit and margin."""
    return [f"FAILED {r.name}: {r.value} ({r.limit}); {r.margin}" for r in check_rows(quality) if not r.passed]
