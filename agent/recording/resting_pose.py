"""Where this agent's last completed motion left the arm: ``<state>/<robot>/resting_pose.json``.

Why: the first move of a session runs at the slow approach speed because the arm may stand anywhere,
on a path nobody checked. When it still stands exactly where our own last session's completed motion
left it (the record, checked against the live joint angles), that is a pose our own approved plan
reached and stood at; a session (verify, run, baseline, calibrate) can then start from it at travel
speed instead of creeping there at approach speed (issue 23: a known-tool change within 8 s of robot
time; issue 22: `run` after `calibrate`). The safety gate still checks the whole plan, that first path
included, and does the comparison with the live angles itself.

The record is removed before a phase's first move and written when a phase completed with the arm at
its last target, or, after a stop our own supervision made because the link to the controller failed
(``CommunicationError``: a stalled stream, no reply, a dropped connection), as the path of the move that
was under way: the arm then stands somewhere on that approved joint-space line (the gate refuses a move
that starts off it), and the next session checks the live angles against the line. A stop the
controller made itself (a fault, perhaps a collision), Ctrl-C, any other exception or motion by anyone
else leaves no record, or one the live angles no longer match: the next session approaches slowly.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Sequence

import numpy as np

from payload_agent.recording.state import write_json_atomic

FILE_NAME = "resting_pose.json"
FORMAT = "payload-agent-resting-pose/1"
# a standing arm's reported angles agree with the record far closer than this (encoder resolution and
# noise: thousandths of a degree); a pose that differs more was moved by someone, and counts as unknown
MATCH_TOL_RAD = math.radians(0.1)


@dataclass(frozen=True)
class RestingPose:
    """Where our last session left the arm: at ``q_rad`` (rad), or, with ``q_to_rad``, somewhere on the straight
    joint-space path from ``q_rad`` to ``q_to_rad`` (the move our supervision stopped); which run left it."""

    q_rad: tuple[float, ...]
    run_dir: str
    recorded_utc: str
    q_to_rad: tuple[float, ...] | None = None

    def offset_rad(self, q: Sequence[float]) -> float:
        """The largest joint difference of ``q`` to the pose or to the nearest point of the path (inf when the
        joint counts differ)."""
        q = np.asarray(q, float)
        a = np.asarray(self.q_rad)
        if q.shape != a.shape:
            return math.inf
        nearest = a
        if self.q_to_rad is not None:
            d = np.asarray(self.q_to_rad) - a
            if float(d @ d) > 0.0:
                nearest = a + float(np.clip((q - a) @ d / (d @ d), 0.0, 1.0)) * d
        return float(np.max(np.abs(q - nearest)))

    def matches(self, q: Sequence[float]) -> bool:
        return self.offset_rad(q) <= MATCH_TOL_RAD

    def describe(self) -> str:
        deg = (lambda q: "[" + ", ".join(f"{math.degrees(v):.2f}" for v in q) + "]°")
        where = deg(self.q_rad) if self.q_to_rad is None else f"on the path {deg(self.q_rad)} -> {deg(self.q_to_rad)}"
        return f"{where} where run {Path(self.run_dir).name} left it ({self.recorded_utc})"


def path_for(state_root: Path) -> Path:
    return Path(state_root) / FILE_NAME


def load(state_root: Path) -> RestingPose | None:
    """The record, or None when there is none or it cannot be read (then nobody knows where the arm is:
    the slow approach, the safe side)."""
    p = path_for(state_root)
    try:
        data = json.loads(p.read_text("utf-8"))
        if data.get("format") != FORMAT:
            return None
        q = tuple(float(v) for v in data["q_rad"])
        to = None if data.get("q_to_rad") is None else tuple(float(v) for v in data["q_to_rad"])
        if not q or not all(math.isfinite(v) for v in q + (to or ())) or (to is not None and len(to) != len(q)):
            return None
        return RestingPose(q, str(data["run_dir"]), str(data["recorded_utc"]), to)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def standing_at(state_root: Path, q: Sequence[float] | None) -> RestingPose | None:
    """The record when the arm stands where it says (``q``, the live angles or where a plan assumes the arm
    stands, matches it): a session's first move may then run at travel speed. None otherwise."""
    rec = None if q is None else load(state_root)
    return rec if rec is not None and rec.matches(q) else None


def clear(state_root: Path) -> None:
    """Forget the record: called before our motion starts (the arm leaves the recorded pose)."""
    try:
        path_for(state_root).unlink()
    except FileNotFoundError:
        pass


def record(state_root: Path, q: Sequence[float], run_dir: Path, q_to: Sequence[float] | None = None) -> RestingPose:
    """Write the record: the arm stands at ``q`` after a completed phase of the run in ``run_dir`` (with ``q_to``:
    somewhere on the path from ``q`` to ``q_to``, the move our supervision stopped)."""
    pose = RestingPose(tuple(float(v) for v in q), str(run_dir), datetime.now().astimezone().isoformat(timespec="seconds"),
                       None if q_to is None else tuple(float(v) for v in q_to))
    write_json_atomic(path_for(state_root), {"format": FORMAT, "q_rad": list(pose.q_rad), "run_dir": pose.run_dir,
                                             "recorded_utc": pose.recorded_utc,
                                             "q_to_rad": None if pose.q_to_rad is None else list(pose.q_to_rad)})
    return pose
