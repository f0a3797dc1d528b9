"""Writes every sample of every sweep to the run folder as it arrives.

Layout (see docs/run-format.md): ``manifest.json`` at the top, one CSV per sweep in a
folder per phase (``empty/``, ``loaded/``). The manifest is rewritten after every
sweep, so an aborted run still describes what it holds.
"""

from __future__ import annotations

import json
import math
import os
import threading
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, TextIO

from payload_agent.types import Sample
from payload_agent.motion.planner import Move

CSV_COLUMNS = ["t_ctrl_s", "t_recv_s"] + [f"q{j}_rad" for j in range(1, 7)] + [f"effort{j}" for j in range(1, 7)]
# written when the driver's samples carry them (UR): the controller's target current (A) and model torque (N·m)
TARGET_COLUMNS = [f"target_current{j}" for j in range(1, 7)] + [f"target_moment{j}" for j in range(1, 7)]
FLUSH_EVERY_S = 0.25  # samples reach the OS at least this often; each sweep's file is fsynced at its end


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


class RunRecorder:
    def __init__(self, run_dir: Path, manifest: dict[str, Any]):
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=False)
        self.manifest = dict(manifest)
        self.manifest.setdefault("phases", {})
        self.manifest.setdefault("created_utc", utc_now())
        self._init_state()
        self.write_manifest()

    # -- phases and sweeps ------------------------------------------------------------------
    @classmethod
    def reopen(cls, run_dir: Path) -> "RunRecorder":
        """An existing run folder, to resume it: its manifest is kept and extended."""
        rec = cls.__new__(cls)
        rec.run_dir = Path(run_dir)
        rec.manifest = json.loads((rec.run_dir / "manifest.json").read_text(encoding="utf-8"))
        rec.manifest.setdefault("phases", {})
        rec._init_state()
        return rec

    def _init_state(self) -> None:
        self._lock = threading.Lock()
        self._manifest_lock = threading.Lock()
        self._phase: str | None = None
        self._file: TextIO | None = None
        self._frozen = False  # the open sweep takes no more samples (``freeze_sweep``)
        self._entry: dict[str, Any] | None = None
        self._targets: bool | None = None  # the open sweep file has the target columns (None: no header yet)
        self._last_flush = 0.0
        self.samples_seen = 0
        self.last_sample: Sample | None = None

    def begin_phase(self, name: str, resume: bool = False, **info: Any) -> None:
        """Start recording a phase; with ``resume``, keep its complete sweeps and set the others aside."""
        (self.run_dir / name).mkdir(exist_ok=True)
        self._phase = name
        old = self.manifest["phases"].get(name)
        if resume and old is not None:
            for key in ("sweeps", "wrist_moves"):
                for entry in old.get(key, []):
                    if entry.get("status") != "complete" and (self.run_dir / entry["file"]).exists():
                        (self.run_dir / entry["file"]).replace(self.run_dir / (entry["file"] + ".incomplete"))
                if key in old:
                    old[key] = [e for e in old[key] if e.get("status") == "complete"]
            old.update(resumed_utc=utc_now(), status="recording", **info)
        else:
            self.manifest["phases"][name] = {"started_utc": utc_now(), "sweeps": [], **info}
        self.write_manifest()

    def set_aside(self, phase: str, problems: dict[str, str]) -> None:
        """Mark these sweeps of a phase as not usable, so that a resumed phase records them again; the
        manifest's ``redone`` list says why, and their data stays on disk as ``<file>.incomplete``."""
        entries = self.manifest["phases"][phase]
        for entry in entries.get("sweeps", []):
            if entry.get("name") in problems and entry.get("status") == "complete":
                entry["status"] = "unsegmentable"
                entries.setdefault("redone", []).append({"name": entry["name"], "file": entry["file"] + ".incomplete",
                                                         "problem": problems[entry["name"]]})
        self.write_manifest()

    def end_phase(self, status: str, stop: dict[str, Any] | None = None, **info: Any) -> None:
        """Close the open phase with its status; ``stop``: how the arm was stopped (an aborted phase); ``info``
        further keys (``joint_temperatures_end``)."""
        if self._phase is not None:
            entry = self.manifest["phases"][self._phase]
            entry.update(ended_utc=utc_now(), status=status)
            if stop is not None:
                entry["stop"] = stop
            if "joint_temperatures_end" in info:
                entry.setdefault("joint_temperatures_c", {})["end"] = info.pop("joint_temperatures_end")
            entry.update(info)
            self.write_manifest()
            self._phase = None

    def adopt_phase(self, name: str, entry: dict[str, Any]) -> None:
        """A phase recorded elsewhere and copied into this folder (the stored empty-flange baseline)."""
        self.manifest["phases"][name] = entry
        self.write_manifest()

    def phase_info(self, name: str) -> dict[str, Any]:
        """A copy of a phase's manifest entry (empty if the phase is not in the run)."""
        return json.loads(json.dumps(self.manifest["phases"].get(name, {})))

    def begin_sweep(self, move: Move) -> None:
        """Open the file of a recorded move: a sweep (manifest ``sweeps``) or a wrist move (``wrist_moves``)."""
        if self._phase is None or move.recorded_name is None:
            raise ValueError("begin_sweep needs an open phase and a sweep or wrist move")
        rel = f"{self._phase}/{move.recorded_name}.csv"
        self._set_aside_earlier_attempt(move.recorded_name, "sweeps" if move.sweep else "wrist_moves", rel)
        f = open(self.run_dir / rel, "w", encoding="utf-8", newline="")  # header with the first sample: its columns
        entry = {"file": rel, "name": move.recorded_name}
        if move.sweep is not None:
            entry.update(pose=move.sweep.pose, joint=move.sweep.joint, direction=move.sweep.direction,
                         speed_percent=move.sweep.speed_percent)
        entry.update(target_deg=[round(math.degrees(v), 6) for v in move.target_rad], started_utc=utc_now(),
                     status="recording", samples=0)
        with self._lock:
            self._file, self._entry, self._targets, self._frozen = f, entry, None, False
        self.manifest["phases"][self._phase].setdefault("sweeps" if move.sweep else "wrist_moves", []).append(entry)
        self.write_manifest()

    def _set_aside_earlier_attempt(self, name: str, key: str, rel: str) -> None:
        """A sweep recorded again (redone after a stream gap): the earlier attempt leaves the phase's list for
        its ``redone`` list and its data stays on disk as ``<file>.incomplete[-N]``, never overwritten."""
        entries = self.manifest["phases"][self._phase]
        earlier = [e for e in entries.get(key, []) if e.get("name") == name and e.get("status") != "complete"]
        if not earlier:
            return
        redone = entries.setdefault("redone", [])
        for e in earlier:
            n = sum(1 for r in redone if r.get("name") == name)
            kept = rel + ".incomplete" + (f"-{n + 1}" if n else "")
            if (self.run_dir / rel).exists():
                (self.run_dir / rel).replace(self.run_dir / kept)
            redone.append({"name": name, "file": kept, "problem": f"recorded again after status {e.get('status')!r}",
                           "stream": e.get("stream")})
        entries[key] = [e for e in entries[key] if e not in earlier]

    def freeze_sweep(self) -> None:
        """Stop appending samples to the open sweep's file (``end_sweep`` closes it): called before the driver's
        stream statistics for the sweep are ended, so that they count every sample the file holds (a sample
        delivered in between would be in the file and not in the statistics)."""
        with self._lock:
            self._frozen = True

    def end_sweep(self, status: str, stream: dict[str, Any] | None = None) -> None:
        """Close the sweep's file; ``stream`` is the driver's stream statistics for it (manifest)."""
        with self._lock:
            f, entry = self._file, self._entry
            if f is not None and self._targets is None:  # no sample: the header alone
                f.write(",".join(CSV_COLUMNS) + "\n")
            self._file = self._entry = None
        if f is not None:
            try:
                f.flush()
                os.fsync(f.fileno())
            finally:
                f.close()
        if entry is not None:
            entry.update(status=status, ended_utc=utc_now())
            if stream is not None:
                entry["stream"] = stream
            self.write_manifest()

    # -- the driver's sample sink -------------------------------------------------------------
    def sink(self, s: Sample) -> None:
        with self._lock:
            self.samples_seen += 1
            self.last_sample = s
            if self._file is None or self._frozen:
                return
            if self._targets is None:
                self._targets = s.target_current is not None and s.target_moment is not None
                self._file.write(",".join(CSV_COLUMNS + (TARGET_COLUMNS if self._targets else [])) + "\n")
            t_ctrl = "" if s.t_ctrl is None else repr(float(s.t_ctrl))
            cells = [t_ctrl, repr(float(s.t_recv)), *(repr(float(v)) for v in s.q), *(repr(float(v)) for v in s.effort)]
            if self._targets:
                both = s.target_current is not None and s.target_moment is not None
                cells += [repr(float(v)) for v in (*s.target_current, *s.target_moment)] if both else [""] * 12
            self._file.write(",".join(cells) + "\n")
            self._entry["samples"] += 1
            now = time.monotonic()
            if now - self._last_flush > FLUSH_EVERY_S:
                self._file.flush()
                self._last_flush = now

    # -- manifest ---------------------------------------------------------------------------
    def update(self, **fields: Any) -> None:
        self.manifest.update(fields)
        self.write_manifest()

    def mark_resumed(self) -> None:
        self.update(status="recording", resumed_utc=utc_now())

    def mark_complete(self) -> None:
        self.update(status="complete", finished_utc=utc_now())

    def mark_stopped(self, why: str, stop: dict[str, Any] | None, session_stop_sent: bool) -> None:
        """An aborted run: why (a sentence), how the arm was stopped, and whether this session sent a stop."""
        self.update(status="incomplete", stopped_because=why, stop=stop, session_stop_sent=session_stop_sent)

    def write_manifest(self) -> None:
        tmp = self.run_dir / "manifest.json.tmp"
        with self._manifest_lock, open(tmp, "w", encoding="utf-8") as fh:
            fh.write(json.dumps(self.manifest, indent=2, default=str))
            fh.flush()
            os.fsync(fh.fileno())
            os.replace(tmp, self.run_dir / "manifest.json")

    def close(self) -> None:
        self.end_sweep("aborted") if self._file is not None else None
