"""Profile position moves of the CANopen driver and the quick stop (the power state machine before them: ``power``).

Every step waits on the drives' statuswords as their TPDOs bring them (``DriveMonitor.wait_for``),
never on SDO polling, and polls the supervision while it waits. A move uses no SDO: its profile
values travel in synchronous RPDOs with its set-points; before they go out, every drive must have
answered one SDO liveness request sent for this move (``watch.SdoWatch.confirm_alive``).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import TYPE_CHECKING

import numpy as np

from payload_agent.drivers.canopen import objects as obj
from payload_agent.drivers.canopen.bus import quick_stop_on_new_bus
from payload_agent.drivers.canopen.cia402 import (CW_ENABLE_OPERATION, CW_NEW_SETPOINT, CW_QUICK_STOP,
                                                  SW_SETPOINT_ACK, SW_TARGET_REACHED, state_of, stopped)
from payload_agent.drivers.move_status import DONE, RUNNING, MoveStatus, aborted
from payload_agent.drivers.canopen.pdo import (RPDO1_COB, RPDO3_COB, RPDO4_COB, RPDO_DECELERATION, RPDO_PROFILE,
                                               RPDO_SETPOINT)
from payload_agent.errors import CommunicationError
from payload_agent.model.profile import JointProfiles, synchronised_profiles, whole_unit_rates

if TYPE_CHECKING:
    from payload_agent.drivers.canopen.driver import CANopenDriver

log = logging.getLogger(__name__)

STOP_CONFIRM_S = 0.25  # statuswords confirming a quick stop: TPDOs first, then SDO
SDO_CONFIRM_S = 0.1  # ... each drive's SDO reply (a drive off the bus never answers)
FRESH_STOP_WAIT_S = 0.3
MIN_ACK_WAIT_S = 0.5  # set-point acknowledge: at least this, or 20 SYNC periods


def _profile_frames(drv: "CANopenDriver", j: int, prof: JointProfiles, travel_counts: int) -> list[tuple[int, bytes]]:
    """RPDO3 (profile velocity, acceleration) and RPDO4 (deceleration = acceleration) of joint ``j``'s trapezoid
    in ``prof``, in whole counts (``model.profile.whole_unit_rates``: rounded up, so no joint arrives late)."""
    cpr, nid = drv.options.counts_per_rad[j], drv.options.node_ids[j]
    v, a = whole_unit_rates(prof.speeds_rad_s[j] * cpr, prof.accels_rad_s2[j] * cpr, travel_counts, prof.duration_s)
    return [(RPDO3_COB + nid, RPDO_PROFILE.pack(v, a)), (RPDO4_COB + nid, RPDO_DECELERATION.pack(a))]


@dataclasses.dataclass
class ProfileMove:
    """One synchronised move under way: which joints move to which counts, and the handshake's phase
    ("ack": waiting for every set-point acknowledge, "reach": for target reached, "done": nothing to move)."""

    moving: list[int]
    counts: list[int]
    phase: str = "done"
    seq: list[int] = dataclasses.field(default_factory=list)
    ack_deadline: float = 0.0


def start(drv: "CANopenDriver", target: np.ndarray, speed_rad_s: float, accel_rad_s2: float) -> ProfileMove:
    """Send one synchronised PTP move in profile position mode to the enabled drives (see the driver's
    docstring): the profiles and every set-point with the new-set-point bit at one SYNC."""
    m, o, lim = drv.monitor, drv.options, drv.limits
    prof = synchronised_profiles(drv.latest_sample.q, target, speed_rad_s, accel_rad_s2, lim.max_joint_speed_rad_s,
                                 lim.max_joint_accel_rad_s2)
    counts = [o.to_counts(j, target[j]) for j in range(drv.n)]
    # a joint moves if its target changed; before its first set-point, if it stands outside the target window
    moving = [j for j in range(drv.n) if (counts[j] != drv.commanded[j] if drv.commanded[j] is not None
                                          else abs(counts[j] - m.position[j]) > o.window_counts(j))]
    if not moving:
        return ProfileMove(moving, counts)
    # a drive late on SDO trips here, before any set-point; nothing is sent once the supervision stopped the arm
    drv.sdo_watch.confirm_alive(drv.check_drives)
    profile = [frame for j in moving for frame in _profile_frames(drv, j, prof, counts[j] - m.position[j])]
    mv = ProfileMove(moving, counts, "ack", list(m.seq),
                     ack_deadline=time.monotonic() + max(MIN_ACK_WAIT_S, 20 * drv.nominal_period_s))
    # profiles first, then the set-points: all act at the same SYNC
    drv.sync.after_next_sync(profile + _setpoints(drv, mv, CW_ENABLE_OPERATION | CW_NEW_SETPOINT))
    for j in moving:  # each drive's last set-point since enabled (any stop forgets them: ``_forget_enabled``)
        drv.commanded[j] = counts[j]
    return mv


def _setpoints(drv: "CANopenDriver", mv: ProfileMove, controlword: int) -> list[tuple[int, bytes]]:
    return [(RPDO1_COB + drv.options.node_ids[j], RPDO_SETPOINT.pack(controlword, mv.counts[j])) for j in mv.moving]


def status(drv: "CANopenDriver", mv: ProfileMove) -> MoveStatus:
    """One look at the drives' statuswords: the handshake's next step, target reached, or why it failed (the
    reader thread acts on drive faults, the base's loop on the supervision)."""
    m = drv.monitor
    if mv.phase == "ack":
        late = m.pending(lambda j, sw: bool(sw & SW_SETPOINT_ACK), mv.seq, mv.moving)
        if not late:
            mv.seq, mv.phase = list(m.seq), "reach"  # new-set-point bit low: the handshake's second half
            drv.sync.after_next_sync(_setpoints(drv, mv, CW_ENABLE_OPERATION))
        elif time.monotonic() > mv.ack_deadline:
            return aborted(f"{', '.join(drv.labels[j] for j in late)} did not acknowledge the new set-point "
                           "(statusword bit 12) in time; every drive was quick-stopped")
        return RUNNING
    if mv.phase == "reach" and m.pending(lambda j, sw: not sw & SW_SETPOINT_ACK and bool(sw & SW_TARGET_REACHED),
                                         mv.seq, mv.moving):
        return RUNNING
    return DONE  # (the base checks that the arm stands at the target)


def _forget_enabled(drv: "CANopenDriver") -> None:
    drv.monitor.expect_enabled = [False] * drv.n  # our own stop is not a fault
    drv.commanded = [None] * drv.n  # stopped short of their targets


def quick_stop(drv: "CANopenDriver") -> bool:
    """Quick stop controlword to every drive over the driver's bus; True once every statusword confirms it."""
    m = drv.monitor
    _forget_enabled(drv)
    if drv.sync is not None:
        drv.sync.cancel_pending()  # set-points queued for the next SYNC never go out
    pending = drv.command_drives(dict.fromkeys(range(drv.n), CW_QUICK_STOP), lambda j, sw: stopped(state_of(sw)),
                                 STOP_CONFIRM_S)
    for j in list(pending):  # no TPDO confirmed it (stream stalled?): ask over SDO, if the channel is free
        try:
            if stopped(state_of(drv.sdo_read(j, obj.STATUSWORD, lock_timeout=0.05, timeout_s=SDO_CONFIRM_S))):
                pending.remove(j)
        except CommunicationError:
            pass
    if pending:
        log.warning("quick stop not confirmed by %s", ", ".join(drv.labels[j] for j in pending))
    return not pending


def quick_stop_fresh(drv: "CANopenDriver") -> bool:
    """The same over a new bus object on the same interface and channel (the driver's own bus is gone)."""
    _forget_enabled(drv)
    confirmed = quick_stop_on_new_bus(drv.options, drv.options.node_ids, FRESH_STOP_WAIT_S)
    missing = [drv.labels[j] for j, nid in enumerate(drv.options.node_ids) if nid not in confirmed]
    if missing:
        o = drv.options
        log.warning("quick stop over a new bus not confirmed by %s%s", ", ".join(missing),
                    f"; a drive cut off from the agent stops itself {o.master_heartbeat_timeout_ms} ms after the "
                    "agent's last heartbeat it heard (0x1016, 0x6007 = 3)" if o.master_heartbeat_ms else "")
    return not missing
