"""Where the flange, and the tool on it, may go: above the floor and inside the reach box.

The YAML's ``safety.floor_z_mm`` and ``safety.reach_box_mm`` bound the flange centre. A tool reaches further:
``safety.tool_radius_mm`` (optional) is the distance from the flange centre to the tool's farthest point, with
whatever it holds, so a sphere of that radius about the flange holds the whole tool whatever its shape and
however it is turned. That sphere must then stay above the floor and inside the box. Without the key only the
flange centre is checked, and the gate's check line says so.
"""

from __future__ import annotations

import numpy as np

from payload_agent.configuration.config import SafetyConfig

# points checked along each joint-space path, ends included less one (the safety gate's and ``preflight``'s)
PATH_CHECK_POINTS = 60


def body(s: SafetyConfig) -> str:
    """What is kept clear, in the words of the gate's messages."""
    if not s.tool_radius_m:
        return "flange"
    return f"tool (within {1000 * s.tool_radius_m:.0f} mm of the flange)"


def outside(s: SafetyConfig, flange_xyz: np.ndarray) -> tuple[str, str] | None:
    """("floor" | "box", what is wrong) when the tool's sphere about ``flange_xyz`` leaves the allowed space."""
    x, y, z = (float(v) for v in flange_xyz)
    r = s.tool_radius_m or 0.0
    if z - r < s.floor_z_m:
        low = f"z = {1000 * z:.0f} mm" if not r else f"z = {1000 * (z - r):.0f} mm (flange at {1000 * z:.0f} mm)"
        return "floor", f"{body(s)} at {low}, below the floor ({1000 * s.floor_z_m:.0f} mm)"
    (xlo, xhi), (ylo, yhi), (zlo, zhi) = s.reach_box_m
    if not (xlo + r <= x <= xhi - r and ylo + r <= y <= yhi - r and zlo + r <= z <= zhi - r):
        return "box", (f"{body(s)} at ({1000 * x:.0f}, {1000 * y:.0f}, {1000 * z:.0f}) mm leaves the reach box"
                       + (f" by its {1000 * r:.0f} mm" if r else ""))
    return None


def outside_on_path(s: SafetyConfig, kin, start_q: np.ndarray, target_q: np.ndarray) -> tuple[str, str] | None:
    """``outside`` at the first of ``PATH_CHECK_POINTS`` + 1 evenly spaced points of the straight joint-space path
    from ``start_q`` to ``target_q`` (both ends included) that leaves the allowed space; None when none does.
    The flange positions of the whole path come from one batch of forward kinematics (``Kinematics.frames``): the
    gate checks every move of every candidate the plan weighs, and one pose at a time was most of its cost."""
    start_q, target_q = np.asarray(start_q, float), np.asarray(target_q, float)
    k = np.arange(PATH_CHECK_POINTS + 1, dtype=float)[:, None]
    path = start_q + (target_q - start_q) * k / PATH_CHECK_POINTS  # the points the gate checked one by one before
    for xyz in kin.frames(path)[-1][:, :3, 3]:
        out = outside(s, xyz)
        if out is not None:
            return out
    return None
