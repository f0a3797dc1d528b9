"""Catching unit mistakes in a robot YAML before they move a robot.

DH tables are copied between conventions and tools (URDF in metres and radians, vendor
sheets in mm and degrees). A value in the wrong unit still parses as a number, and the
safety gate then computes with a robot that does not exist. These checks name the file,
the key and the unit the value most likely is in:

- DH lengths that look like metres (every non-zero length below 5 mm), or some rows in metres
  among others in mm (non-zero lengths below 2 mm beside lengths of 50 mm and more: each named);
- ``alpha_deg`` / ``offset_deg`` that look like radians (±π/2, ±π to 0.01);
- joint limits that look like radians (all within ±2π, or a pair at ±π/2, ±π, ±2π) and
  limits beyond ±360°, which no 6-axis controller has.
"""

from __future__ import annotations

import math
from typing import Sequence

from payload_agent.errors import ConfigError

MAX_METRE_LIKE_LENGTH_MM = 5.0  # no joint-torque-measurable arm has every DH length below 5 mm
# a mixed table: a non-zero length below 2 mm beside others of 50 mm and more is a length in metres
# (an arm's links are 50-1500 mm long, i.e. 0.05-1.5 in metres; no real DH length is a fraction of a mm)
MIXED_METRE_LIKE_MM, MIXED_TABLE_MIN_MM = 2.0, 50.0
RADIAN_TOL = 0.01
MAX_LIMIT_DEG = 360.0
_RADIAN_ANGLES = (math.pi / 2, math.pi, 3 * math.pi / 2, 2 * math.pi)


def _looks_like_radians(value: float) -> float | None:
    """The radian angle (π/2, π, ...) ``value`` matches, or None."""
    for r in _RADIAN_ANGLES:
        if abs(abs(value) - r) < RADIAN_TOL:
            return math.copysign(r, value)
    return None


def check_dh(rows: Sequence[tuple[float, float, float, float]], key: str, source: str | None) -> None:
    """``rows``: (a_mm, d_mm, alpha_deg, offset_deg) per joint as written in the YAML."""
    lengths = [(abs(v), f"{key}[{i}].{name}", v) for i, row in enumerate(rows)
               for name, v in (("a_mm", row[0]), ("d_mm", row[1])) if v != 0]
    if lengths and max(v for v, _, _ in lengths) < MAX_METRE_LIKE_LENGTH_MM:
        _, where, value = max(lengths)
        raise ConfigError(where, f"{value:g} looks like metres: every DH length of this table is below "
                                 f"{MAX_METRE_LIKE_LENGTH_MM:g} mm. The DH table is in millimetres "
                                 f"(write {1000 * value:g})", source)
    metre_like = [(where, v) for a, where, v in lengths if a < MIXED_METRE_LIKE_MM]
    if metre_like and max(a for a, _, _ in lengths) >= MIXED_TABLE_MIN_MM:
        rows = " and ".join(f"{where} = {v:g}" for where, v in metre_like)
        fix = ", ".join(f"{1000 * v:g}" for _, v in metre_like)
        raise ConfigError(metre_like[0][0], f"{rows} look{'s' if len(metre_like) == 1 else ''} like metres among "
                                            f"lengths in millimetres; the DH table is in millimetres (write {fix})",
                          source)
    for i, (_, _, alpha, offset) in enumerate(rows):
        for name, v in (("alpha_deg", alpha), ("offset_deg", offset)):
            r = _looks_like_radians(v)
            if r is not None:
                raise ConfigError(f"{key}[{i}].{name}", f"{v:g} looks like radians ({r:.4f} rad = "
                                                        f"{math.degrees(r):g}°); {name} is in degrees "
                                                        f"(write {math.degrees(r):g})", source)


def check_joint_limit(lo: float, hi: float, key: str, source: str | None) -> None:
    for v in (lo, hi):
        if abs(v) > MAX_LIMIT_DEG:
            raise ConfigError(key, f"{v:g}° is beyond ±{MAX_LIMIT_DEG:g}°, which no 6-axis controller allows; "
                                   "joint limits are in degrees (is this value in another unit?)", source)


def check_joint_limits_unit(limits: Sequence[tuple[float, float]], key: str, source: str | None) -> None:
    """Joint limits (deg as written) that look like radians: all within ±2π, or a pair at ±π/2, ±π, ±2π."""
    small = [max(abs(lo), abs(hi)) <= 2 * math.pi + RADIAN_TOL for lo, hi in limits]
    for i, (lo, hi) in enumerate(limits):
        radian_pair = _looks_like_radians(lo) is not None and _looks_like_radians(hi) is not None
        if small[i] and (all(small) or radian_pair):
            in_deg = ", ".join(f"{math.degrees(v):g}" for v in (lo, hi))
            raise ConfigError(f"{key}[{i}]", f"[{lo:g}, {hi:g}] looks like radians ([{in_deg}]°); "
                                             "joint_limits_deg is in degrees", source)
