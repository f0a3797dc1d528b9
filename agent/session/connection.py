"""Building and opening the driver a robot YAML names, the simulated controller included.

``build_driver`` checks everything that needs no connection (the driver's options, its
effort unit against ``effort.unit``), so ``plan`` refuses a bad driver section before any
socket opens. ``open_controller`` starts the simulated controller when the YAML has a
``simulation`` section and points the driver at it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from typing import Iterator

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.drivers.base import Driver, DriverOptions, MotionLimits, Supervision
from payload_agent.drivers.registry import make_driver
from payload_agent.errors import ConfigError
from payload_agent.types import ControllerInfo

SAMPLE_WAIT_S = 5.0
STILL_WINDOW_S = 0.3  # the arm must stand this long (controller time where it stamps samples) before we start
STILL_TOLERANCE_RAD = math.radians(0.1)  # far above encoder noise, far below what any motion covers in the window


def motion_limits(config: Config) -> MotionLimits:
    return MotionLimits(config.robot.max_joint_speed_rad_s, config.robot.max_joint_accel_rad_s2)


def supervision(config: Config) -> Supervision:
    gap = config.safety.max_stream_gap_s
    if gap is None:
        return Supervision(None, config.safety.stop_ack_timeout_s)
    # a YAML that allows longer stream gaps (a busy host) allows replies, and the controller's "finished", as late
    return Supervision(gap, config.safety.stop_ack_timeout_s, max_reply_wait_s=max(gap, Supervision.max_reply_wait_s),
                       finish_grace_s=max(gap, Supervision.finish_grace_s))


def build_driver(config: Config, options: DriverOptions | None = None) -> Driver:
    """The driver for ``config`` (not connected); ConfigError if its effort unit is not the YAML's."""
    driver = make_driver(options or config.driver_options, motion_limits(config), supervision(config))
    try:
        driver.check_effort_unit(config.effort.unit)
    except ConfigError as exc:
        raise ConfigError(exc.key_path, exc.problem, config.source) from None
    return driver


@contextlib.contextmanager
def simulated_cell(config: Config, cell=None) -> Iterator[object | None]:
    """The running simulated cell for a sim YAML (started here unless given), else None."""
    if cell is not None or config.simulation is None:
        yield cell
        return
    from payload_agent.session.simulation import SimulatedCell

    own = SimulatedCell(config).start()
    try:
        yield own
    finally:
        own.close()


def identify_controller(driver: Driver) -> ControllerInfo:
    """What the controller reports of itself, with the serial the YAML declares (``driver.serial``) where
    it reports none: the robot's identity for its stored baseline, never where it is reached (an address or
    port changes, the robot does not). A declared serial the controller contradicts is refused."""
    info = driver.identify()
    declared = driver.options.serial
    if not declared:
        return info
    if info.serial and info.serial != declared:
        raise ConfigError("driver.serial", f"the YAML declares serial {declared!r}, the controller at "
                                           f"{driver.describe_endpoint()} reports {info.serial!r}: is this the right "
                                           "robot's YAML?")
    return dataclasses.replace(info, serial=declared)


def motion_under_way(driver: Driver, state) -> str | None:
    """Why a new session must not start because the arm is moving for someone else, or None if it stands.

    The controller's own word (``state.moving``) is not enough: a Modbus handshake only knows its own
    program's motion, a drive its own setpoint. The stream tells for every driver: the joint angles may not
    change over ``STILL_WINDOW_S``. Nothing is sent to the controller either way.
    """
    if state.moving:
        return "the robot is moving (the controller reports a motion under way)"
    first = driver.wait_sample(SAMPLE_WAIT_S)
    deadline = time.monotonic() + SAMPLE_WAIT_S + STILL_WINDOW_S
    last = first
    while _elapsed(first, last) < STILL_WINDOW_S:
        if time.monotonic() > deadline:
            break  # a slow stream: judge on what arrived
        last = driver.wait_sample(SAMPLE_WAIT_S, after=last.t_recv)
    moved = max(abs(b - a) for a, b in zip(first.q, last.q))
    if moved > STILL_TOLERANCE_RAD:
        return (f"the robot is moving: its joints turned {math.degrees(moved):.2f}° in "
                f"{_elapsed(first, last):.2f} s with no command from this session")
    return None


def _elapsed(first, last) -> float:
    if first.t_ctrl is not None and last.t_ctrl is not None:
        return last.t_ctrl - first.t_ctrl
    return last.t_recv - first.t_recv


def read_current_q(config: Config) -> np.ndarray:
    """Connect only to read where the robot stands now (for `plan --connect`); nothing moves."""
    build_driver(config)  # refuse a bad driver section before starting anything
    with simulated_cell(config) as cell:
        driver = build_driver(config, cell.options if cell is not None else None)
        try:
            driver.connect()
            return np.asarray(driver.wait_sample(SAMPLE_WAIT_S).q, float)
        finally:
            driver.close()
