"""Terminal progress (agent/progress.py) driven like the runner drives it, into a StringIO."""

from __future__ import annotations

import io
import math
import threading

import numpy as np
import pytest

from payload_agent.types import Sample
from payload_agent.motion.planner import Move, Plan, SweepKey, expected_durations
from payload_agent.configuration.procedure import Procedure
from payload_agent.output.progress import Progress, format_duration

START = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def _plan() -> Plan:
    a = Move("approach", "approach", (0.0, 0.1, 0.0, 0.0, 0.0, 0.0), 0.1, 1.0)
    s = Move("b-j2 up", "sweep", (0.0, 1.1, 0.0, 0.0, 0.0, 0.0), 0.1, 1.0, SweepKey("b", 2, "up", 5.0))
    return Plan(Procedure("test", "", {}, (), "0"), (a, s))


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def sample(q2: float) -> Sample:
    return Sample(None, 0.0, (0.0, q2, 0.0, 0.0, 0.0, 0.0), (0.0,) * 6)


@pytest.fixture
def plan():
    return _plan()


def test_format_duration():
    assert format_duration(0) == "0:00" and format_duration(65.4) == "1:05" and format_duration(3725) == "1:02:05"
    assert format_duration(float("nan")) == "?" and format_duration(-3) == "0:00"


def test_non_tty_prints_one_line_per_sweep_start_and_end(plan):
    out, clock = io.StringIO(), Clock()
    durations = expected_durations(plan, np.array(START))
    p = Progress(out, plan, durations, True, tty=False, clock=clock)
    p.begin_phase("empty")
    p.begin_move(1, plan.moves[0])
    p.on_sample(sample(0.0))
    p.end_move()
    assert out.getvalue() == ""  # travel/approach moves are silent in a log
    p.begin_move(2, plan.moves[1])
    for k in range(50):
        p.on_sample(sample(0.1 + 0.02 * k))
        p.refresh()  # the render path is a no-op without a terminal
    clock.t += 11.0
    p.end_move()
    p.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == 2 and "\r" not in out.getvalue()
    assert lines[0].startswith("  [empty] sweep b-j2 up: started, expected 0:10, run time left ~0:30")  # 1 rad at 0.1 rad/s + 0.1 s ramp; 3 moves left
    assert lines[1] == "  [empty] sweep b-j2 up: done, 50 samples in 0:11 (run 36 % done)"  # 11.2 of 31.4 s robot time


def test_fraction_from_angle_and_time_left(plan):
    out, clock = io.StringIO(), Clock()
    durations = expected_durations(plan, np.array(START))
    p = Progress(out, plan, durations, True, tty=True, clock=clock, render_thread=False)
    later = expected_durations(plan, np.array(plan.moves[-1].target_rad))
    # before anything: the whole run, two phases
    assert p.time_left_s() == pytest.approx(sum(durations) + sum(later))
    p.begin_phase("empty")
    p.begin_move(2, plan.moves[1], start_q=(0.0, 0.1, 0.0, 0.0, 0.0, 0.0))
    p.on_sample(sample(0.35))  # a quarter of the way from 0.1 to 1.1 rad
    assert p.fraction() == pytest.approx(0.25)
    assert p.time_left_s() == pytest.approx(0.75 * durations[1] + sum(later))
    p.on_sample(sample(2.0))  # overshoot is clamped
    assert p.fraction() == 1.0
    p.end_move()
    p.begin_phase("loaded")
    p.begin_move(1, plan.moves[0])  # no sample yet: elapsed time against the expected duration
    clock.t += later[0] / 2
    assert p.fraction() == pytest.approx(0.5)
    assert p.time_left_s() == pytest.approx(later[0] / 2 + later[1])
    p.close()


def test_tty_redraws_one_line_rate_limited_and_clears_it(plan):
    out, clock = io.StringIO(), Clock()
    p = Progress(out, plan, expected_durations(plan, np.array(START)), True, tty=True, clock=clock,
                 render_thread=False)
    p.begin_phase("loaded")
    p.begin_move(2, plan.moves[1], start_q=(0.0, 0.1, 0.0, 0.0, 0.0, 0.0))
    first = out.getvalue()
    assert first.startswith("\r  [loaded 2/2] move 2/2 b-j2 up") and "  0 %" in first and "\n" not in first
    assert "run [##############------]  68 %" in first  # the empty phase and the approach are done
    p.on_sample(sample(0.6))
    assert p.refresh() is False  # drawn 0 s ago: rate-limited
    clock.t += 0.05
    assert p.refresh() is False
    clock.t += 0.2
    assert p.refresh() is True
    line = out.getvalue()[len(first):]
    assert line.startswith("\r") and "b-j2 up             50 %" in line and "1 samples" in line
    assert "run [#################---]  84 %" in line  # (11.2 + 1.1 + 0.5 · 10.1) / 31.4
    p.end_move()
    blank = out.getvalue()[len(first) + len(line):]
    assert blank == "\r" + " " * (len(line) - 1) + "\r"  # the drawn line is overwritten with spaces
    assert p.refresh(force=True) is False  # nothing drawn between moves
    p.close()
    assert "\n" not in out.getvalue()


def test_the_line_means_something_at_a_simulations_time_scale(plan):
    """At 50x a move is over in a few hundredths of a second: the line drawn when each move starts must
    already show how far the run is and every sample so far, not "0 %, 0 samples"."""
    out, clock = io.StringIO(), Clock()
    durations = expected_durations(plan, np.array(START))
    p = Progress(out, plan, durations, True, tty=True, clock=clock, render_thread=False, time_scale=50.0,
                 phases=("loaded",))
    p.begin_phase("loaded")
    p.begin_move(1, plan.moves[0], start_q=START)
    for k in range(40):
        p.on_sample(sample(0.0025 * k))
    clock.t += durations[0] / 50
    p.end_move()
    p.begin_move(2, plan.moves[1], start_q=plan.moves[0].target_rad)  # drawn at once, nothing received yet
    line = out.getvalue().split("\r")[-1]
    assert "move 2/2 b-j2 up" in line and "40 samples" in line
    assert f"run [##" in line and f"{100 * durations[0] / sum(durations):3.0f} %" in line
    assert "~0:00 left" in line  # 10 s of robot time at 50x: a fifth of a second
    p.close()


def test_render_thread_draws_while_samples_arrive_from_another_thread(plan):
    out = io.StringIO()
    p = Progress(out, plan, expected_durations(plan, np.array(START)), True, tty=True, redraw_interval_s=0.02)
    p.begin_move(2, plan.moves[1], start_q=(0.0, 0.1, 0.0, 0.0, 0.0, 0.0))
    done = threading.Event()

    def stream():
        for k in range(2000):
            p.on_sample(sample(0.1 + k / 2000))
        done.set()

    t = threading.Thread(target=stream)
    t.start()
    t.join(5)
    assert done.is_set()
    import time

    deadline = time.monotonic() + 2.0
    while "2000 samples" not in out.getvalue() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert "2000 samples" in out.getvalue()
    p.end_move()
    p.close()
    assert p._thread is None


def test_disabled_writes_nothing(plan):
    out = io.StringIO()
    p = Progress(out, plan, [math.nan, math.nan], False, tty=True)
    p.begin_phase("empty")
    p.begin_move(1, plan.moves[0])
    p.on_sample(sample(0.05))
    p.end_move()
    p.close()
    assert out.getvalue() == ""


def test_rejects_mismatched_durations(plan):
    with pytest.raises(ValueError, match="durations has 1 entries for a plan of 2 moves"):
        Progress(io.StringIO(), plan, [1.0], True)
