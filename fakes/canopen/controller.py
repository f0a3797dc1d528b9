"""Six simulated CiA 402 drives on python-can's virtual bus, moving one simulated arm.

The simulated-controller contract (fakes/base.py) for the ``canopen`` driver. One ``SimRobot``
(the physics core) is the arm; six ``SimDrive``s, one canopen ``LocalNode`` each, share one bus
object on a virtual channel of their own (the wire; the driver opens its own bus on the same
channel).

Time: the drives' control cycle is locked to SYNC, and so is the simulated arm: every SYNC
advances the physics core by one tick of ``time_scale``/``sync_rate_hz`` simulated seconds
(``SyncSteppedRobot``), so 250 Hz of SYNC at time_scale 4 is 62.5 samples per simulated second.
A starved or jittery SYNC producer (a busy machine) then slows simulated time instead of leaving
holes in the samples; without SYNC the simulated arm stands still (a real drive would finish its
profile on its own clock). The simulated wire's clock is the simulated clock: every frame the
drives send carries it as its timestamp (``msg.timestamp``, what a hardware-timestamping
interface gives); the TPDOs carry the tick's reported time (with the physics core's timestamp
jitter) plus each frame's place on the wire. The drives' consumer heartbeat monitoring (0x1016) runs
on the same clock: at every SYNC on the wire each drive compares the master's newest heartbeat it
heard with that SYNC, both by the time the master sent them, so a pause of the shared process
(which delays both alike) never looks like a lost master; without SYNC the arm stands still and
the drives' heartbeat monitoring too.

Faults (``inject_fault``; ``joint=`` 1..6 limits one to a drive): ``drop_connections`` (the CAN
link between the agent and the drives is cut: the drives hear nothing from the master, no SYNC,
RPDO, SDO, NMT command or heartbeat, and the master hears nothing from them, no TPDO, SDO reply,
EMCY or heartbeat; each drive that consumes the master's heartbeat stops itself after its consumer
time, as 0x6007 says; the physics keeps its SYNC clock; ``heartbeat_only=True``: only the drive's
heartbeat stops),
``stall_stream`` (TPDOs stop), ``garbage`` (TPDOs of 5 bytes instead of the mapped 8),
``protective_stop`` (drive fault 0x8611 following error, EMCY; joint 2 by default),
``emergency_stop`` (every drive faults with 0x3220 DC link under-voltage: the e-stop cuts the
drives' power; it persists until ``clear_faults``), ``leave_remote`` (a drive leaves OPERATION
ENABLED, its enable input dropped, no EMCY; joint 4 by default), ``slow_reply`` (SDO answers
after ``delay_s``), ``no_reply`` (SDO requests swallowed), ``never_finish`` (target reached never
set). ``nan_values`` does not apply: PDO values are integers.
"""

from __future__ import annotations

import dataclasses
import functools
import threading
import time
import uuid
from typing import Any

import can
import canopen
import numpy as np
from can.interfaces.virtual import VirtualBus

from payload_agent.fakes.base import SimulatedController, sim_robot_kwargs
from payload_agent.fakes.canopen.drive import FAULT, FRA, OE, QSA, SOD, SimDrive
from payload_agent.fakes.canopen.motion import AxisProfile, MultiAxisPath
from payload_agent.fakes.sim_robot import SimRefused, SimRobot

DEFAULT_STOP_DECEL_RAD_S2 = 10.0
BRAKE_FACTOR = 3.0  # a disabled drive's brake stops the joint this much harder than its quick stop
CODE_FOLLOWING_ERROR, CODE_UNDERVOLTAGE = 0x8611, 0x3220
FRAME_BITS = 130  # an 8-byte CAN 2.0A data frame with stuff bits and inter-frame space


class SyncSteppedRobot(SimRobot):
    """A SimRobot without its own clock thread: the simulated drives step it once per SYNC."""

    def start(self) -> "SyncSteppedRobot":
        return self


def _true_t(state) -> float:
    """The exact simulated time of a physics tick (``t`` carries the reported timestamp's jitter)."""
    return state.t_true if getattr(state, "t_true", None) is not None else state.t


class SimClockBus(VirtualBus):
    """The simulated wire: every frame sent on it carries the simulated bus clock as its timestamp."""

    def __init__(self, channel: str, clock):
        super().__init__(channel=channel, preserve_timestamps=True)
        self._clock, self._last, self._stamp_lock = clock, 0.0, threading.Lock()

    def send(self, msg, timeout=None) -> None:
        with self._stamp_lock:
            if not self._open:  # a drive's heartbeat thread may outlive the wire by one period at close
                return
            self._last = msg.timestamp = max(self._clock(), self._last + 1e-6)
            super().send(msg, timeout)

    def send_stamped(self, msg) -> None:
        """Send with the timestamp already set (TPDOs: their SYNC's time plus their place on the wire)."""
        with self._stamp_lock:
            self._last = max(self._last, msg.timestamp)
            super().send(msg)


class SimulatedCANopenArm(SimulatedController):
    faults = frozenset({"drop_connections", "stall_stream", "garbage", "protective_stop", "emergency_stop",
                        "leave_remote", "slow_reply", "no_reply", "never_finish"})

    def __init__(self, robot: SimRobot, options, *, rated_torque_nm, rated_current_a=None, gain_error=None,
                 has_rated_torque: bool = True, faulted: dict[int, int] | None = None):
        super().__init__()
        if options.interface != "virtual":
            raise ValueError(f"the simulated CANopen arm serves python-can's virtual bus, not {options.interface!r}")
        self._robot, self.options = robot, options
        self.channel = f"{options.channel}-{uuid.uuid4().hex[:8]}"  # its own wire: no crosstalk between cells
        self.epoch = time.time()
        self._tick = (robot.now(), time.monotonic())  # (exact simulated time of the newest tick, wall time)
        self._state = robot.snapshot()
        self._latched = None
        rated_current = rated_current_a or [t / 10.0 for t in rated_torque_nm]  # 10 N·m/A at the joint
        gains = np.broadcast_to(np.asarray(1.0 if gain_error is None else gain_error, float), (6,))
        self.drives = [SimDrive(self, j, nid, counts_per_rad=options.counts_per_rad[j], direction=options.direction[j],
                                zero_counts=options.zero_counts[j],
                                rated_torque_mnm=round(1000 * rated_torque_nm[j]) if has_rated_torque else None,
                                rated_current_ma=round(1000 * rated_current[j]), gain_error=float(gains[j]),
                                serial=0x5000 + nid) for j, nid in enumerate(options.node_ids)]
        self.rated_torque_nm = tuple(float(t) for t in rated_torque_nm)
        self._faulted = dict(faulted or {})
        self._lock = threading.RLock()
        self._in_sync = False
        self._pending: list[SimDrive] = []
        self._path: MultiAxisPath | None = None
        self._rpdo_subs: dict[int, list[int]] = {}
        self.network: canopen.Network | None = None
        self._token: int | None = None
        self.sync_count = 0
        self.skipped_syncs = 0
        self._last_sync_t: float | None = None
        self._last_stamp = 0.0
        self.frame_s = FRAME_BITS / options.bitrate  # one 8-byte frame on the wire

    @classmethod
    def from_config(cls, config, **kwargs) -> "SimulatedCANopenArm":
        """From a robot YAML; ``kwargs`` (tests): ``faulted={joint: code}``, ``has_rated_torque=False``, ..."""
        from payload_agent.fakes.arms import simulated_spec

        opts, sim = config.driver_options, config.simulation
        spec = simulated_spec(sim)
        robot = SyncSteppedRobot(spec, tick_s=sim.time_scale / opts.sync_rate_hz, **sim_robot_kwargs(config))
        return cls(robot, opts, **{"rated_torque_nm": spec.rated_torque_nm, "gain_error": sim.drive_gain_error,
                                   **kwargs})

    @property
    def robot(self) -> SimRobot:
        return self._robot

    def bound_options(self, options):
        return dataclasses.replace(options, channel=self.channel)

    # -- lifecycle ------------------------------------------------------------------------------
    def start(self) -> "SimulatedCANopenArm":
        self._token = self._robot.subscribe(self._on_tick)
        self.network = canopen.Network(SimClockBus(self.channel, self.bus_time))
        self.network.NOTIFIER_CYCLE = 0.1  # close() waits at most this for the receive thread
        self.network.connect()
        for d in self.drives:
            self.network[d.node_id] = d.node
            self.network.unsubscribe(d.node.sdo.rx_cobid, d.node.sdo.on_request)  # served through _on_sdo
            self.network.subscribe(d.node.sdo.rx_cobid, functools.partial(self._on_sdo, d))
            self.network.unsubscribe(0, d.node.nmt.on_command)  # a drive off the bus hears no NMT command
            self.network.subscribe(0, functools.partial(self._on_nmt, d))
            self.pdo_config_changed(d)
        self.network.subscribe(0x80, self._on_sync)
        self._robot.start()
        for d in self.drives:
            if d.joint + 1 in self._faulted:
                d.state, d.error_code = FAULT, self._faulted[d.joint + 1]
            d.node.nmt.state = "INITIALISING"  # boot-up message
            d.node.nmt.state = "PRE-OPERATIONAL"
        return self

    def close(self) -> None:
        for d in self.drives:
            try:
                d.node.nmt.stop_heartbeat()
            except Exception:
                pass
        if self._token is not None:
            self._robot.unsubscribe(self._token)
            self._token = None
        if self.network is not None:
            self.network.disconnect()
            self.network = None
        self._robot.close()

    # -- clocks ---------------------------------------------------------------------------------
    def _on_tick(self, state) -> None:  # a robot with its own clock thread (tests may pass one)
        self._tick = (_true_t(state), time.monotonic())
        self._state = state

    def tick_time(self) -> float:
        """Simulated time of the newest physics tick (a path the robot follows ends on a tick)."""
        return self._tick[0]

    def sim_time(self) -> float:
        """Simulated now: the newest tick, advanced by the wall time since it if the robot runs its own clock."""
        t, mono = self._tick
        if isinstance(self._robot, SyncSteppedRobot):
            return t
        return t + min((time.monotonic() - mono) * self._robot.time_scale, self._robot.tick_s)

    def bus_time(self) -> float:
        return self.epoch + self.sim_time()

    def joint_state(self, j: int) -> tuple[int, int]:
        """(position actual in counts, torque actual in per mille of rated) of joint ``j`` now."""
        s = self._latched or self._state
        d = self.drives[j]
        pos = round(d.zero + d.direction * float(s.q[j]) * d.cpr)
        if d.state not in (OE, QSA, FRA):
            return pos, 0  # power stage off: the brake holds the joint, the motor gives no torque
        permille = round(1000.0 * d.direction * float(s.torque_nm[j]) * d.gain_error / self.rated_torque_nm[j])
        return pos, max(-32768, min(32767, permille))

    # -- bus services ---------------------------------------------------------------------------
    def _on_sdo(self, d: SimDrive, can_id: int, data: bytearray, timestamp: float) -> None:
        if d.silent:
            return
        if "no_reply" in self.active_faults or "slow_reply" in self.active_faults:
            self._note_withheld(d)
        if "no_reply" in self.active_faults:
            return
        delay = float(self.active_faults.get("slow_reply", {}).get("delay_s", 1.0)) \
            if "slow_reply" in self.active_faults else 0.0
        if delay > 0:
            threading.Timer(delay, self._serve_sdo, (d, bytes(data))).start()
        else:
            self._serve_sdo(d, bytes(data))

    def _note_withheld(self, d: SimDrive) -> None:
        """Log the first SDO request a reply fault held back: the agent asks only now and then (its liveness
        requests), so the fault can show no earlier than this request plus the agent's reply limit."""
        if not any(e.kind == "withheld" for e in self.events):
            self.record_event("withheld", f"SDO request to node {d.node_id}")

    def _on_nmt(self, d: SimDrive, can_id: int, data: bytearray, timestamp: float) -> None:
        if not d.silent:
            d.node.nmt.on_command(can_id, data, timestamp)

    def consumer_changed(self, d: SimDrive) -> None:
        """A drive was told to consume a node's heartbeat (0x1016): listen to that heartbeat's COB-ID."""
        if self.network is not None and d.consumer is not None:
            self.network.subscribe(0x700 + d.consumer[0], self._on_heartbeat)

    def _on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            for d in self.drives:
                d.on_heartbeat_of(can_id - 0x700, timestamp)

    def _serve_sdo(self, d: SimDrive, data: bytes) -> None:
        with self._lock:
            if self.network is not None:
                d.node.sdo.on_request(d.node.sdo.rx_cobid, data, 0.0)

    def pdo_config_changed(self, d: SimDrive) -> None:
        """Re-subscribe a drive's RPDO COB-IDs after the master rewrote its PDO parameters."""
        if self.network is None:
            return
        for cob in self._rpdo_subs.pop(d.joint, []):
            self.network.unsubscribe(cob, d.on_rpdo_message)
        d._rpdos = d.rpdos()
        for cob in d._rpdos:
            self.network.subscribe(cob, d.on_rpdo_message)
        self._rpdo_subs[d.joint] = list(d._rpdos)

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            self.sync_count += 1
            if isinstance(self._robot, SyncSteppedRobot):
                self._on_tick(self._robot.step())  # the drives' cycle, locked to SYNC
            self._latched = self._state
            self._in_sync = True
            try:
                for d in self.drives:
                    d.apply_sync_rpdos()
            finally:
                self._in_sync = False
            if self._pending:
                pending, self._pending = self._pending, []
                self._start(pending)
            frames = []
            for d in self.drives:
                d.check_consumer(timestamp)  # the drive's clock: the SYNC's time on the wire (see the docstring)
                d.update()
                frames += d.tpdo_frames(self.sync_count)
            latched, self._latched = self._latched, None
        if _true_t(latched) == self._last_sync_t:  # a free-running physics clock fell behind: nothing new
            self.skipped_syncs += 1
            return
        self._last_sync_t = _true_t(latched)
        # the drives sample at SYNC (the latched tick, its reported time with the physics core's jitter) and
        # their TPDOs follow each other on the wire
        t0 = max(self.epoch + latched.t, self._last_stamp)
        for k, (cob, payload) in enumerate(frames, start=1):
            self.network.bus.send_stamped(can.Message(arbitration_id=cob, data=payload, is_extended_id=False,
                                                      timestamp=t0 + k * self.frame_s))
        self._last_stamp = t0 + len(frames) * self.frame_s

    # -- motion ---------------------------------------------------------------------------------
    def request_setpoint(self, d: SimDrive) -> None:
        """A drive saw a new set-point: start it now, or with the others at the end of this SYNC."""
        if self._in_sync:
            self._pending.append(d)
        else:
            self._start([d])

    def _start(self, drives: list[SimDrive]) -> None:
        def profile(d: SimDrive, t0: float, q0: float) -> AxisProfile:
            raw = [d.node.sdo[i].raw for i in (0x607A, 0x6081, 0x6083, 0x6084)]
            target = d.direction * (raw[0] - d.zero) / d.cpr
            return AxisProfile(q0, target, raw[1] / d.cpr, raw[2] / d.cpr, raw[3] / d.cpr, t0)

        ready = [d for d in drives if all(d.node.sdo[i].raw > 0 for i in (0x6081, 0x6083, 0x6084))]
        for d in drives:
            if d not in ready:
                self.record_event("refused", f"node {d.node_id}: profile velocity/acceleration is 0")
        if not ready:
            return

        def make(t0: float, q0: np.ndarray) -> MultiAxisPath:
            self._path = MultiAxisPath(q0, {d.joint: profile(d, t0, float(q0[d.joint])) for d in ready})
            return self._path
        try:
            self._robot.follow_path(make)
        except SimRefused as exc:  # still moving: the set-point is not acknowledged
            for d in ready:
                self.record_event("refused", f"node {d.node_id}: {exc}")
            return
        for d in ready:
            d.ack, d.stop_end_t = True, None
            d.end_t = self._path.profiles[d.joint].t_end
            self.record_event("move", f"node {d.node_id}: target {d.node.sdo[0x607A].raw} counts")

    def stop_joint(self, d: SimDrive, quick: bool) -> float:
        """Ramp joint ``d`` down (its quick stop deceleration, or its brake); the simulated time it stands still."""
        qs = d.node.sdo[0x6085].raw / d.cpr
        decel = (qs if qs > 0 else DEFAULT_STOP_DECEL_RAD_S2) * (1.0 if quick else BRAKE_FACTOR)
        path, now = self._path, self.sim_time()
        prof = None if path is None else path.profiles.get(d.joint)
        if prof is None or now >= prof.t_end or not self._robot.snapshot().moving:
            return now
        if not quick:
            self.record_event("stop", f"node {d.node_id}: power stage off while moving (brake)")
        path.pending_stops[d.joint] = decel
        self._robot.stop(decel)
        return prof.t_end

    # -- faults ---------------------------------------------------------------------------------
    def _targets(self, params: dict[str, Any], default: int | None) -> list[SimDrive]:
        joint = params.get("joint", default)
        return self.drives if joint is None else [self.drives[int(joint) - 1]]

    def _apply_fault(self, name: str, params: dict[str, Any]) -> None:
        with self._lock:
            if name == "drop_connections":
                for d in self._targets(params, None):
                    d.node.nmt.stop_heartbeat()
                    d.silent = not params.get("heartbeat_only", False)
            elif name in ("stall_stream", "garbage", "never_finish"):
                for d in self._targets(params, None):
                    setattr(d, {"stall_stream": "stalled"}.get(name, name), True)
            elif name == "protective_stop":
                for d in self._targets(params, 2):
                    d.fault(int(params.get("code", CODE_FOLLOWING_ERROR)))
            elif name == "emergency_stop":
                for d in self.drives:
                    d.fault(CODE_UNDERVOLTAGE, persists=True)
            elif name == "leave_remote":
                for d in self._targets(params, 4):
                    if d.state in (OE, QSA):
                        self.stop_joint(d, quick=False)
                    d.state, d.ack = SOD, False

    def _clear_fault(self, name: str) -> None:
        with self._lock:
            for d in self.drives:
                if name == "drop_connections":
                    d.silent = False
                    d.node.nmt.start_heartbeat(d.node.sdo[0x1017].raw)
                d.stalled = d.stalled and name != "stall_stream"
                d.garbage = d.garbage and name != "garbage"
                d.never_finish = d.never_finish and name != "never_finish"
                if name == "emergency_stop":
                    d.fault_persists = False
