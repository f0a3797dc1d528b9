"""Live progress on the terminal while the robot moves.

The line is about the whole run, so it means something at any time scale: at a simulation's
50x a move lasts a few hundredths of a second and a per-move "0 %, 0 samples" is all one
would ever see. It shows the phase, the move (number, label, its own percent), a bar and
percent for the whole run (robot time done over the run's expected robot time, every phase
included), the samples recorded so far in the run, and the wall time left.

A move's own percent comes from the leading joint's angle between where the move started
and its target (whatever the controller's speed scaling does); before the first sample
arrives, or for a move that does not go anywhere, from elapsed time against the expected
duration.

Two output styles:

- a terminal (``out.isatty()``): one line redrawn in place with ``\\r`` about 5 times a
  second, for every move; it is blanked at the end of each move so the runner's own lines
  never mix with it;
- anything else (a log file, CI, ``--unattended`` under a cell controller): one line when
  each sweep starts and one when it ends, nothing in between.

Threading: ``on_sample`` runs on the driver's stream thread. It only updates counters under
a lock; all writing happens on the caller's thread (``begin_move``/``end_move``) or on a
small render thread. A slow or blocked terminal (a paused SSH session) can therefore never
stall the sample stream and lose data.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Callable, Sequence, TextIO

import numpy as np

from payload_agent.types import Sample
from payload_agent.motion.planner import Move, Plan, expected_durations

REDRAW_INTERVAL_S = 0.2  # ~5 Hz
BAR_WIDTH = 20


def format_duration(seconds: float) -> str:
    """``m:ss`` (or ``h:mm:ss``) for a non-negative number of seconds; ``?`` if unknown."""
    if seconds is None or not math.isfinite(seconds):
        return "?"
    s = int(round(max(0.0, seconds)))
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class Progress:
    """Progress display for one run; the runner calls it, the stream thread feeds it samples.

    ``durations``: expected duration of each plan move for the first phase (as
    ``planner.expected_durations(plan, start_q)``; NaN where unknown). Later phases start
    where the plan ends, so their durations are computed from there. ``phases``: the phase
    names run with this plan, in order (``("loaded",)`` when a stored baseline replaces the
    empty run). ``time_scale``: simulated time runs this much faster than wall time (robot
    time left is divided by it). ``tty``: force the style (default: ``out.isatty()``).
    """

    def __init__(self, out: TextIO, plan: Plan, durations: Sequence[float], enabled: bool = True, *,
                 phases: Sequence[str] = ("empty", "loaded"), time_scale: float = 1.0, tty: bool | None = None,
                 clock: Callable[[], float] = time.monotonic, redraw_interval_s: float = REDRAW_INTERVAL_S,
                 render_thread: bool = True):
        if len(durations) != len(plan.moves):
            raise ValueError(f"durations has {len(durations)} entries for a plan of {len(plan.moves)} moves")
        self.out = out
        self.plan = plan
        self.enabled = bool(enabled)
        self.phases = tuple(phases)
        self.time_scale = float(time_scale) if time_scale and time_scale > 0 else 1.0
        if tty is None:
            try:
                tty = bool(out.isatty())
            except (AttributeError, ValueError):
                tty = False
        self.tty = tty
        self._clock = clock
        self._interval = float(redraw_interval_s)
        self._use_thread = render_thread
        self._first = [0.0 if not math.isfinite(d) else float(d) for d in durations]
        later = expected_durations(plan, np.asarray(plan.moves[-1].target_rad)) if plan.moves else []
        self._later = [0.0 if not math.isfinite(d) else float(d) for d in later]
        self._lock = threading.Lock()
        self._write_lock = threading.Lock()
        self._phase_index = 0
        self._phase_name = self.phases[0] if self.phases else ""
        self._move: Move | None = None
        self._move_index = 0
        self._t_begin = 0.0
        self._start_q: np.ndarray | None = None
        self._latest_q: np.ndarray | None = None
        self._samples = 0
        self._run_samples = 0  # every sample since the first move of the first phase
        self._done_in_phase = 0  # moves of the current phase that have ended
        self._last_draw = -math.inf
        self._line_len = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- runner side ------------------------------------------------------------------------
    def begin_phase(self, name: str) -> None:
        """The runner starts phase ``name`` (one of ``phases``); moves are counted from 1 again."""
        if not self.enabled:
            return
        with self._lock:
            if name in self.phases:
                self._phase_index = self.phases.index(name)
            self._phase_name = name
            self._move_index = 0
            self._done_in_phase = 0

    def begin_move(self, i: int, move: Move, start_q: Sequence[float] | None = None) -> None:
        """Move ``i`` (1-based, as the runner numbers them) of the plan starts now.

        ``start_q``: where the robot stands (rad); if None, the first sample received is taken.
        """
        if not self.enabled:
            return
        with self._lock:
            self._move, self._move_index = move, int(i)
            self._t_begin = self._clock()
            self._start_q = None if start_q is None else np.asarray(start_q, float)
            self._latest_q = None
            self._samples = 0
            self._last_draw = -math.inf
        if self.tty:
            self._ensure_thread()
            self.refresh(force=True)
        elif move.kind == "sweep":
            left = self.time_left_s()
            self._write_line(f"  [{self._phase_name}] sweep {move.label}: started, expected "
                             f"{format_duration(self._expected(self._move_index) / self.time_scale)}, "
                             f"run time left ~{format_duration(left)}")

    def on_sample(self, sample: Sample) -> None:
        """Called from the driver's stream thread for every sample: cheap, never writes."""
        if not self.enabled:
            return
        with self._lock:
            if self._move is None:
                return
            q = sample.q
            if self._start_q is None:
                self._start_q = np.asarray(q, float)
            self._latest_q = q
            self._samples += 1
            self._run_samples += 1

    def end_move(self, status: str = "done") -> None:
        """The current move ended (``status``: "done", "aborted", ...)."""
        if not self.enabled:
            return
        with self._lock:
            move, n, elapsed = self._move, self._samples, self._clock() - self._t_begin
            self._move = None
            if move is not None:
                self._done_in_phase = max(self._done_in_phase, self._move_index)
        if move is None:
            return
        if self.tty:
            self._clear_line()
        elif move.kind == "sweep":
            self._write_line(f"  [{self._phase_name}] sweep {move.label}: {status}, {n} samples in "
                             f"{format_duration(elapsed)} (run {100 * self.run_fraction():.0f} % done)")

    def close(self) -> None:
        """Stop the render thread and leave the terminal on a clean line. Safe to call twice."""
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout=2.0)
        self._thread = None
        if self.enabled and self.tty:
            with self._lock:
                self._move = None
            self._clear_line()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- state ------------------------------------------------------------------------------
    def fraction(self) -> float:
        """How far the current move is, 0..1 (0 when no move is running)."""
        with self._lock:
            return self._fraction_locked()

    def _fraction_locked(self) -> float:
        move = self._move
        if move is None:
            return 0.0
        target = np.asarray(move.target_rad, float)
        if self._start_q is not None and self._latest_q is not None:
            span = target - self._start_q
            j = int(np.argmax(np.abs(span)))
            if abs(span[j]) > 1e-6:
                return float(min(1.0, max(0.0, (self._latest_q[j] - self._start_q[j]) / span[j])))
        expected = self._expected(self._move_index)
        if expected > 0:
            return float(min(1.0, max(0.0, (self._clock() - self._t_begin) * self.time_scale / expected)))
        return 0.0

    def run_fraction(self) -> float:
        """How far the whole run is, 0..1: robot time done over the expected robot time of every phase."""
        with self._lock:
            return self._run_fraction_locked()

    def _run_fraction_locked(self) -> float:
        n_phases = max(1, len(self.phases))
        total = sum(self._first) + sum(self._later) * (n_phases - 1)
        if total <= 0:
            return 0.0
        before = 0.0 if self._phase_index == 0 else sum(self._first) + sum(self._later) * (self._phase_index - 1)
        table = self._first if self._phase_index == 0 else self._later
        done = before + sum(table[:self._done_in_phase])
        if self._move is not None:
            done = before + sum(table[:self._move_index - 1]) + self._fraction_locked() * self._expected(
                self._move_index)
        return float(min(1.0, max(0.0, done / total)))

    def _expected(self, i: int) -> float:
        table = self._first if self._phase_index == 0 else self._later
        return table[i - 1] if 1 <= i <= len(table) else 0.0

    def time_left_s(self) -> float:
        """Expected wall time left for the run: rest of this move, rest of the phase, later phases."""
        with self._lock:
            frac = self._fraction_locked()
            i = self._move_index
            table = self._first if self._phase_index == 0 else self._later
            rest = (1.0 - frac) * self._expected(i) if self._move is not None else 0.0
            rest += sum(table[i:])  # the moves after move i (all of them before the first move)
            rest += sum(self._later) * max(0, len(self.phases) - 1 - self._phase_index)
        return rest / self.time_scale

    def status_line(self) -> str:
        """The one-line status the terminal shows (empty when no move is running)."""
        with self._lock:
            move = self._move
            if move is None:
                return ""
            frac = self._fraction_locked()
            run = self._run_fraction_locked()
            n, i = self._run_samples, self._move_index
        left = self.time_left_s()
        filled = int(round(run * BAR_WIDTH))
        bar = "#" * filled + "-" * (BAR_WIDTH - filled)
        total = len(self.plan.moves)
        phase = f"{self._phase_name} {self._phase_index + 1}/{len(self.phases)}" if len(self.phases) > 1 \
            else self._phase_name
        return (f"  [{phase}] move {i}/{total} {move.label:<18s} {100 * frac:3.0f} %  run [{bar}] {100 * run:3.0f} %  "
                f"{n} samples  ~{format_duration(left)} left")

    # -- drawing ----------------------------------------------------------------------------
    def refresh(self, force: bool = False) -> bool:
        """Redraw the terminal line if ~1/5 s has passed (or ``force``); returns whether it drew."""
        if not (self.enabled and self.tty):
            return False
        now = self._clock()
        with self._lock:
            if self._move is None or (not force and now - self._last_draw < self._interval):
                return False
            self._last_draw = now
        line = self.status_line()
        if not line:
            return False
        with self._write_lock:
            pad = max(0, self._line_len - len(line))
            self._write("\r" + line + " " * pad)
            self._line_len = len(line)
        return True

    def _clear_line(self) -> None:
        with self._write_lock:
            if self._line_len:
                self._write("\r" + " " * self._line_len + "\r")
                self._line_len = 0

    def _write_line(self, text: str) -> None:
        with self._write_lock:
            self._write(text + "\n")

    def _write(self, text: str) -> None:
        try:
            self.out.write(text)
            self.out.flush()
        except (OSError, ValueError):
            pass  # a closed or broken terminal must not end the run

    def _ensure_thread(self) -> None:
        if not self._use_thread or self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._render_loop, name="payload-agent-progress", daemon=True)
        self._thread.start()

    def _render_loop(self) -> None:
        while not self._stop.wait(self._interval):
            self.refresh()
