"""CANopen CiA 402 servo drives, one per joint, through the canopen library on python-can.

Connect (``_open``): open the bus, put every drive in NMT PRE-OPERATIONAL, check it is a CiA 402
drive (0x1000), read its identity, write its producer heartbeat (0x1017), its consumer heartbeat
of the agent and its reaction to losing it (0x1016, 0x6007: ``watch``), its PDO layout
(``pdo.configure_pdos``), its quick stop deceleration and target window and profile position mode
(0x6060 = 1, confirmed in 0x6061), read its rated torque or current (0x6076 / 0x6075), start NMT and
the SYNC producer (which also sends the agent's heartbeat), and wait for every drive's first TPDO; then ``watch.SdoWatch`` polls the drives' SDO
servers until close. A drive found in FAULT is reported by ``state()`` (motion refused, error code 0x603F
named) and reset only with ``driver.clear_faults: true``, which logs a warning and says so in the
state's detail: never silently.

Motion (``_start_move`` / ``_move_status``, see ``motion``): the template's ``_activate`` (before the first move,
and again after a move that ended abnormally; never at connect) enables the drives through the CiA 402 power
state machine (``power``; a drive that leaves OPERATION ENABLED later is a monitor fault, refused by
``_prepare_move``); each move sends profile velocity
and acceleration/deceleration (0x6081/0x6083/0x6084, RPDO3/RPDO4) scaled so all joints arrive
together (``model.profile.synchronised_joint_rates``) and every target (0x607A) with the
new-set-point bit in one synchronous RPDO batch, waits for each drive's set-point acknowledge, completes the
handshake and waits for target reached (statusword bit 10), polling the supervision.

Stream: one Sample per SYNC from the six TPDO1 frames (``pdo.TpdoCollector``); ``t_ctrl`` is the
earliest frame's bus timestamp (``msg.timestamp``). SDO is used for configuration only (and the
liveness poll).

Stop: the quick stop controlword to every drive in an asynchronous RPDO, confirmed from their
statuswords (TPDO, else SDO); over a new bus object when the old one is gone. The drives report
no Cartesian pose (``reports_flange_pose = False``).
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from typing import Any

import canopen
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from payload_agent.drivers.base import Driver, MotionLimits, MoveStatus, Supervision
from payload_agent.drivers.canopen import device, motion, power
from payload_agent.drivers.canopen import objects as obj
from payload_agent.drivers.canopen.bus import SyncProducer, another_master, open_bus
from payload_agent.drivers.canopen.cia402 import (CW_DISABLE_VOLTAGE, CW_FAULT_RESET, FAULTY, OPERATION_ENABLED,
                                                  QUICK_STOP_ACTIVE, SW_TARGET_REACHED, describe_code, state_of)
from payload_agent.drivers.canopen.monitor import DriveMonitor
from payload_agent.drivers.canopen.options import CANopenOptions
from payload_agent.drivers.canopen.pdo import (RPDO2_COB, RPDO_COMMAND, TPDO1, Frame, TpdoCollector,
                                               configure_pdos)
from payload_agent.drivers.canopen.watch import SdoWatch, configure_master_watch
from payload_agent.errors import (CommunicationError, MotionAbortedError, MotionStopped, RobotNotReadyError,
                                  SupervisionTrip)
from payload_agent.types import ControllerInfo, ControllerState, Sample

log = logging.getLogger(__name__)

CIA402_PROFILE = 402  # 0x1000 device type, low 16 bits
FIRST_TPDO_WAIT_S = 1.0
MASTER_LISTEN_S = 0.3  # listen this long for another master's SYNC before sending anything on the bus
NOTIFIER_CYCLE_S = 0.1  # python-can's receive thread wakes this often when idle: close() waits at most this


class CANopenDriver(Driver):
    name = "canopen"
    options_class = CANopenOptions
    simulator = "payload_agent.fakes.canopen:SimulatedCANopenArm"
    reports_flange_pose = False
    sampling_clock = "agent"  # the driver produces SYNC: in a simulation, simulated time follows it
    move_poll_s = 0.002

    def __init__(self, options: CANopenOptions, limits: MotionLimits, supervision: Supervision | None = None):
        super().__init__(options, limits, supervision)
        self.options: CANopenOptions = options
        self.effort_unit = options.effort_unit
        self.nominal_period_s = 1.0 / options.sync_rate_hz
        self.n = len(options.node_ids)
        self.labels = [options.joint_label(j) for j in range(self.n)]
        self.network: canopen.Network | None = None
        self.nodes: list[canopen.RemoteNode] = []
        self.sync: SyncProducer | None = None
        self.monitor = DriveMonitor(options)
        self._move = motion.ProfileMove([], [])
        self.tpdo = TpdoCollector(self.n)
        self.effort_per_permille = [1.0] * self.n
        self._took_bus = False  # this session has sent NMT/SDO commands: it releases the drives at close
        self.fault_codes: dict[int, int] = {}  # joint -> 0x603F of drives found in FAULT at connect
        self.cleared_faults: list[str] = []  # notes for state().detail: faults reset at connect, missing objects
        self.sdo_watch: SdoWatch | None = None
        self.commanded: list[int | None] = [None] * self.n  # each drive's last set-point (counts) since enabled
        self._sdo_locks = [threading.Lock() for _ in range(self.n)]
        self._info: ControllerInfo | None = None

    def describe_endpoint(self) -> str:
        o = self.options
        return f"{o.interface} {o.channel}, nodes {', '.join(map(str, o.node_ids))}"

    # -- SDO (configuration only) ----------------------------------------------------------
    def sdo_read(self, j: int, index: int, sub: int | None = None, lock_timeout: float = -1,
                 timeout_s: float | None = None) -> Any:
        """One SDO upload; ``lock_timeout``: give up if another thread uses the drive's SDO channel;
        ``timeout_s``: a shorter reply timeout than ``sdo_timeout_s`` (the stop's confirmation)."""
        return self._sdo(j, index, sub, None, lock_timeout, timeout_s)

    def sdo_write(self, j: int, index: int, value: Any, sub: int | None = None) -> None:
        self._sdo(j, index, sub, value, -1, None)

    def _sdo(self, j: int, index: int, sub: int | None, value: Any, lock_timeout: float,
             timeout_s: float | None) -> Any:
        lock = self._sdo_locks[j]
        if not lock.acquire(timeout=lock_timeout):
            raise CommunicationError(f"{self.labels[j]}: its SDO channel is busy")
        client = self.nodes[j].sdo
        client.RESPONSE_TIMEOUT = self.options.sdo_timeout_s if timeout_s is None else timeout_s
        try:
            var = client[index] if sub is None else client[index][sub]
            if value is None:
                return var.raw
            var.raw = value
            return None
        except SdoCommunicationError as exc:
            raise CommunicationError(f"{self.labels[j]} did not answer an SDO request for 0x{index:04X} within "
                                     f"{self.options.sdo_timeout_s:g} s ({exc}): check its node id, the bit rate, "
                                     "the wiring and that it is powered") from exc
        except SdoAbortedError as exc:
            what = "read" if value is None else f"write {value!r} to"
            raise CommunicationError(f"{self.labels[j]} refused to {what} object 0x{index:04X}"
                                     f"{'' if sub is None else f' sub {sub}'}: SDO abort {exc}") from exc
        finally:
            client.RESPONSE_TIMEOUT = self.options.sdo_timeout_s
            lock.release()

    # -- connection --------------------------------------------------------------------------
    def _open(self) -> None:
        opts = self.options
        self.monitor = DriveMonitor(opts)
        self.monitor.sdo_reply_limit_s = self.supervision.max_reply_wait_s
        self.tpdo = TpdoCollector(self.n)
        self._took_bus = False
        self.commanded = [None] * self.n
        self.network = canopen.Network(open_bus(opts))
        self.network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
        try:
            self.network.connect()
            busy = another_master(self.network, max(MASTER_LISTEN_S, 3.0 / opts.sync_rate_hz))
            if busy:
                raise RobotNotReadyError(busy)
            self._took_bus = True  # from here on this session commands the drives (and releases them at close)
            self.nodes = []
            for j, nid in enumerate(opts.node_ids):
                node = canopen.RemoteNode(nid, obj.cia402_dictionary())
                self.network.add_node(node)
                node.sdo.RESPONSE_TIMEOUT = opts.sdo_timeout_s
                node.nmt.add_heartbeat_callback(functools.partial(self.monitor.on_heartbeat, j))
                node.emcy.add_callback(functools.partial(self._on_emcy, j))
                self.monitor.check_frame_lengths(self.network, j, node)  # a short EMCY/heartbeat is a fault
                self.network.subscribe(node.sdo.tx_cobid, functools.partial(self._on_sdo_response, j))
                self.nodes.append(node)
            for node in self.nodes:
                node.nmt.state = "PRE-OPERATIONAL"
            for j in range(self.n):
                self._configure(j)
            self._subscribe_tpdos()
            self._info = device.identity(self)
            self.monitor.heartbeat_since = time.monotonic()
            for node in self.nodes:
                node.nmt.state = "OPERATIONAL"
            self.monitor.expect_operational = True
            self.sync = SyncProducer(self.network.send_message, self.nominal_period_s, opts.master_node_id,
                                     opts.master_heartbeat_ms / 1000.0).start()
            self._wait_first_tpdos()
            self._wait_operational()
            self._check_faults_at_connect()
            self.sdo_watch = SdoWatch(self).start()
        except BaseException:
            self._close()
            raise

    def _configure(self, j: int) -> None:
        opts = self.options
        device_type = self.sdo_read(j, 0x1000)
        if device_type & 0xFFFF != CIA402_PROFILE:
            raise CommunicationError(f"{self.labels[j]} is not a CiA 402 drive: its device type (0x1000) is "
                                     f"0x{device_type:08X}, profile {device_type & 0xFFFF} instead of 402")
        self.sdo_write(j, obj.PRODUCER_HEARTBEAT, opts.heartbeat_ms)
        note = configure_master_watch(self, j)
        if note:
            self.cleared_faults.append(note)
        effort_index = obj.TORQUE_ACTUAL if opts.effort_object == "torque" else obj.CURRENT_ACTUAL
        try:
            configure_pdos(self.nodes[j], effort_index)
        except SdoCommunicationError as exc:
            raise CommunicationError(f"{self.labels[j]} stopped answering SDO while its PDOs were configured: "
                                     f"{exc}") from exc
        except SdoAbortedError as exc:
            raise CommunicationError(f"{self.labels[j]} refused the PDO layout (TPDO1: statusword, position actual, "
                                     f"0x{effort_index:04X}; RPDO1: controlword + target; RPDO2: controlword; "
                                     f"RPDO3: 0x6081 + 0x6083; RPDO4: 0x6084): SDO abort {exc}") from exc
        cpr = opts.counts_per_rad[j]
        self.sdo_write(j, obj.QUICK_STOP_DECELERATION, max(1, round(opts.quick_stop_decel_rad_s2 * cpr)))
        self.sdo_write(j, obj.POSITION_WINDOW, opts.window_counts(j))
        self.effort_per_permille[j] = device.effort_scale(self, j)
        device.set_profile_position_mode(self, j)

    def _wait_first_tpdos(self) -> None:
        deadline = time.monotonic() + FIRST_TPDO_WAIT_S
        while any(s == 0 for s in self.monitor.seq):
            if time.monotonic() > deadline:
                silent = [self.labels[j] for j, s in enumerate(self.monitor.seq) if s == 0]
                raise CommunicationError(f"no TPDO within {FIRST_TPDO_WAIT_S:g} s of SYNC from {', '.join(silent)}: "
                                         "is the drive NMT OPERATIONAL, and does it accept the PDO layout?")
            time.sleep(0.005)

    def _wait_operational(self) -> None:
        """Every drive's heartbeat reports NMT OPERATIONAL (those sent before the start command may not)."""
        deadline = time.monotonic() + self.options.heartbeat_timeout_ms / 1000.0
        while not all(self.monitor.operational):
            if time.monotonic() > deadline:
                late = [self.labels[j] for j, ok in enumerate(self.monitor.operational) if not ok]
                raise CommunicationError(f"no heartbeat reporting NMT OPERATIONAL from {', '.join(late)} within "
                                         f"{self.options.heartbeat_timeout_ms} ms of the start command")
            time.sleep(0.005)

    def _check_faults_at_connect(self) -> None:
        for j in self.monitor.faulty():
            try:
                self.fault_codes[j] = int(self.sdo_read(j, obj.ERROR_CODE))
            except CommunicationError:
                self.fault_codes[j] = 0
        if not self.fault_codes or not self.options.clear_faults:
            return
        for j, code in sorted(self.fault_codes.items()):
            # bit 7 low first: the reset acts on its rising edge
            self.command_drives({j: CW_DISABLE_VOLTAGE}, lambda _, sw: True, self.options.enable_timeout_s)
            if self.command_drives({j: CW_FAULT_RESET}, lambda _, sw: state_of(sw) not in FAULTY,
                                   self.options.enable_timeout_s):
                raise RobotNotReadyError(f"{self.labels[j]} stays in FAULT after a fault reset (error code "
                                         f"{describe_code(code)}): its cause persists; fix it at the drive")
            note = f"{self.labels[j]} was in FAULT at connect (error code {describe_code(code)}); reset it"
            log.warning("%s because driver.clear_faults is true", note)
            self.cleared_faults.append(note)
        self.fault_codes.clear()

    def _close(self) -> None:
        if self.sdo_watch is not None:
            self.sdo_watch.stop()
            self.sdo_watch = None
        self.monitor.expect_enabled = [False] * self.n
        took, self._took_bus = self._took_bus, False
        if not took:  # refused before commanding anything: leave the drives and the other master alone
            if self.network is not None:
                try:
                    self.network.disconnect()
                except Exception:
                    pass
                self.network = None
            return
        if self.network is not None and self.network.bus is not None:
            for j in range(len(self.nodes)):  # power stages off, brakes on
                try:
                    self._send_command(j, CW_DISABLE_VOLTAGE)
                except Exception:
                    pass
        if self.sync is not None:
            self.sync.stop()
            self.sync = None
        self.monitor.expect_operational = False
        if self.network is not None:
            try:
                for node in self.nodes:
                    node.nmt.state = "PRE-OPERATIONAL"
            except Exception:
                pass
            try:
                self.network.disconnect()
            except Exception:
                pass
            self.network = None

    # -- stream --------------------------------------------------------------------------------
    def _on_emcy(self, j: int, err) -> None:
        self.monitor.on_emcy(j, err.code, err.register)

    def _on_sdo_response(self, j: int, can_id: int, data: bytearray, timestamp: float) -> None:
        self.monitor.on_sdo_response(j)

    def _on_tpdo(self, j: int, pdo_map) -> None:  # the receive thread: record only
        data, t_recv = pdo_map.data, time.monotonic()
        if len(data) != TPDO1.size:
            self.tpdo.fail(f"a TPDO1 from {self.labels[j]} has {len(data)} data bytes; its mapping (statusword, "
                           f"position actual, effort) needs {TPDO1.size}: the drive sent a malformed PDO")
            return
        statusword, position, effort = TPDO1.unpack(data)
        self.monitor.on_frame(j, statusword, position, t_recv)
        self.tpdo.push(j, Frame(pdo_map.timestamp, t_recv, statusword, position, effort))

    def _subscribe_tpdos(self) -> None:
        for j, node in enumerate(self.nodes):
            node.tpdo.map[1].add_callback(functools.partial(self._on_tpdo, j))

    def _read_sample(self, timeout_s: float) -> Sample | None:
        self.poll_faults()
        if self.tpdo.error is not None:
            raise CommunicationError(self.tpdo.error)
        frames = self.tpdo.pop_set(timeout_s)
        if frames is None:
            if self.tpdo.error is not None:
                raise CommunicationError(self.tpdo.error)
            return None
        o = self.options
        q = tuple(o.to_angle_rad(j, f.position) for j, f in enumerate(frames))
        effort = tuple(o.direction[j] * f.effort * self.effort_per_permille[j] for j, f in enumerate(frames))
        return Sample(min(f.timestamp for f in frames), max(f.t_recv for f in frames), q, effort)

    def poll_faults(self) -> None:
        """Check heartbeats and TPDO silence; trip the supervision (stop every drive) on any fault during a move."""
        self.monitor.check_silence([self.tpdo.queued(j) for j in range(self.n)], self.nominal_period_s)
        if self.monitor.fault is not None:  # a drive that stopped itself is a motion abort (exit 4), a silent bus 6
            self.trip(self.monitor.fault, error=MotionStopped if self.monitor.drive_fault else SupervisionTrip)

    # -- commands --------------------------------------------------------------------------------
    def _send_command(self, j: int, controlword: int) -> None:
        """A controlword in the asynchronous RPDO2: the drive acts on it at once."""
        self.network.send_message(RPDO2_COB + self.options.node_ids[j], RPDO_COMMAND.pack(controlword))

    def command_drives(self, controlwords: dict[int, int], reached, timeout_s: float, poll=None) -> list[int]:
        """Send each joint its controlword, then wait until ``reached(j, statusword)`` holds on a newer TPDO of
        each; the joints for which it did not within ``timeout_s`` (``DriveMonitor.wait_for``)."""
        seq0 = list(self.monitor.seq)
        for j, controlword in controlwords.items():
            self._send_command(j, controlword)
        return self.monitor.wait_for(reached, seq0, list(controlwords), timeout_s, poll)

    def check_drives(self) -> None:
        """While enabling or moving: act on a drive fault (``poll_faults``), then raise if the supervision has
        stopped the arm."""
        self.poll_faults()
        self.check_supervision()

    def _activate(self) -> None:
        power.enable_all(self)

    def _prepare_move(self, target, speed_rad_s: float, accel_rad_s2: float) -> None:
        if self.monitor.fault is not None:
            raise MotionAbortedError(f"refusing to move, a drive fault is pending: {self.monitor.fault}; "
                                     "nothing was sent")

    def _start_move(self, target, speed_rad_s: float, accel_rad_s2: float) -> MoveStatus | None:
        self._move = motion.start(self, target, speed_rad_s, accel_rad_s2)  # None: the drives take every set-point

    def _move_status(self) -> MoveStatus:
        return motion.status(self, self._move)

    def _stop_command(self) -> bool:
        return motion.quick_stop(self)

    def _stop_fresh(self) -> bool:
        return motion.quick_stop_fresh(self)

    def _command_alive(self) -> bool:
        """The bus object works: its receive thread and the SYNC producer have not failed."""
        net = self.network
        return (net is not None and net.bus is not None and net.notifier is not None
                and net.notifier.exception is None and self.sync is not None and self.sync.alive)

    # -- state -----------------------------------------------------------------------------------
    def identify(self) -> ControllerInfo:
        if self._info is None:
            raise CommunicationError("the canopen driver is not connected (call connect() first)")
        return self._info

    def state(self) -> ControllerState:
        if self.network is None:
            return ControllerState(False, "the CANopen bus is not open: connect first")
        self.monitor.check_silence([self.tpdo.queued(j) for j in range(self.n)], self.nominal_period_s)
        problems = [self.monitor.fault] if self.monitor.fault else []
        states = self.monitor.states()
        for j, st in enumerate(states):
            if st in FAULTY:
                code = self.fault_codes.get(j, self.monitor.last_emcy_code(j))
                problems.append(f"{self.labels[j]} is in FAULT (error code "
                                f"{describe_code(code) if code else 'not reported'}): remove the cause, then reset "
                                "it at the drive, or set driver.clear_faults: true to let the agent reset it")
            elif st == QUICK_STOP_ACTIVE or st.startswith(("NOT READY", "UNKNOWN", "no TPDO")):
                problems.append(f"{self.labels[j]} is in {st}: check its power stage supply and reconnect")
        moving = any(st == OPERATION_ENABLED and not (sw or 0) & SW_TARGET_REACHED
                     for st, sw in zip(states, self.monitor.statusword))
        detail = (f"{self.n} CiA 402 drives on {self.describe_endpoint()}, SYNC {self.options.sync_rate_hz:g} Hz; "
                  + ", ".join(f"{j + 1}: {st}" for j, st in enumerate(states)))
        if self.cleared_faults:
            detail += "; " + "; ".join(self.cleared_faults)
        return ControllerState(not problems, "; ".join(problems), protective_stop=any(s in FAULTY for s in states),
                               moving=moving, detail=detail)

