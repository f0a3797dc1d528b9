"""The registers a simulated Modbus robot refreshes from its physics core: joint state, status, pose.

Encoded as the real device does it, per the register map: for UR's server, unsigned joint angles
in mrad counted up from zero within a turn plus a revolution counter that reads 65535 (-1) for
negative angles, currents in mA (two's complement), TCP pose in 0.1 mm and mrad; refreshed at the
map's ``update_hz`` of simulated time. The drives report effort = torque / gain × gain error in
the map's effort unit (gains from the robot YAML), then quantised to the register's resolution.

Faults change what is written: ``stall`` freezes the image, ``garbage`` writes impossible
values into the joint registers, ``nan`` writes NaN into float32 joint registers.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from payload_agent.drivers.modbus.registers import Entry, int_range
from payload_agent.drivers.modbus.regmap import RegisterMap, si_factor
from payload_agent.fakes.modbus.store import RegisterStore, encode
from payload_agent.fakes.sim_robot import SimState
from payload_agent.model.kinematics import Kinematics

SAMPLE_SIGNALS = ("joint_angles", "joint_revolutions", "joint_efforts", "timestamp")


class SensorImage:
    def __init__(self, store: RegisterStore, regmap: RegisterMap, dh, gains: Sequence[float],
                 gain_error: Sequence[float], firmware: tuple[int, int] = (5, 15)):
        self.store = store
        self.map = regmap
        self.kin = Kinematics(dh)
        self.gains = np.asarray(gains, float)
        self.gain_error = np.asarray(gain_error, float)
        self.firmware = firmware
        self.stalled = False
        self.garbage = False
        self.nan = False
        self.robot_mode_ok = True  # False: the pendant has control / the robot is not in its running mode
        self.tcp_offset = (np.zeros(3), np.zeros(3))  # position m, rotation vector rad (flange frame)
        self.tool_change = 0
        self.digital_inputs = 0
        self._rng = np.random.default_rng(7)
        self._last_q: np.ndarray | None = None
        pose = [regmap[n] for n in ("tcp_position", "tcp_rotation", "tcp_offset_position", "tcp_offset_rotation")
                if n in regmap]
        if pose:  # computed from the newest angles when a client reads it (FK every cycle is costly here)
            store.on_read.extend((e.table, e.address, e.end, self._fill_pose) for e in pose)

    def _words(self, name: str, values_si: Sequence[float]) -> tuple[str, int, list]:
        e = self.map[name]
        return e.table, e.address, encode(e, [v / si_factor(e) for v in values_si])

    def write(self, state: SimState) -> None:
        if self.stalled:
            return
        m = self.map
        joint: dict[str, tuple[str, int, list]] = {}
        q = np.asarray(state.q, float)
        if "joint_revolutions" in m:
            rev = m["joint_revolutions"]
            turn = si_factor(rev) * rev.scale  # rad per count: 2π
            revs = np.floor(q / turn)
            joint["joint_angles"] = self._words("joint_angles", q - revs * turn)
            joint["joint_revolutions"] = (rev.table, rev.address, encode(rev, list(revs * rev.scale)))
        else:
            joint["joint_angles"] = self._words("joint_angles", q)
        effort = np.asarray(state.torque_nm, float) / self.gains * self.gain_error
        joint["joint_efforts"] = self._words("joint_efforts", effort)
        if "timestamp" in m:
            joint["timestamp"] = self._words("timestamp", [_wrap(m["timestamp"], state.t)])
        for name in joint:
            if self.garbage and name in ("joint_angles", "joint_revolutions"):
                joint[name] = self._garbage(m[name])
            if self.nan and name in ("joint_angles", "joint_efforts") and m[name].type == "float32":
                e = m[name]
                joint[name] = (e.table, e.address, encode(e, [math.nan] * e.n_values))
        self._last_q = q
        self.store.set_many(list(joint.values()) + self._status(state))

    def _fill_pose(self) -> None:
        if self._last_q is not None and not self.stalled:
            self.store.set_many(self._pose(self._last_q))

    def _status(self, state: SimState) -> list[tuple[str, int, list]]:
        m = self.map
        out = []
        values = {"power_on": [1 if state.servo_on else 0], "protective_stop": [int(state.protective_stop)],
                  "emergency_stop": [int(state.estop)], "tool_change": [self.tool_change],
                  "digital_inputs": [self.digital_inputs], "fault_code": [0],
                  "firmware_major": [self.firmware[0]], "firmware_minor": [self.firmware[1]]}
        if "robot_mode" in m:
            e = m["robot_mode"]
            ok = e.ok_values[0] if e.ok_values else 1
            other = next((k for k in sorted(e.value_names) if k != ok), 0)
            values["robot_mode"] = [ok if self.robot_mode_ok and state.servo_on else other]
        for name, v in values.items():
            if name in m:
                e = m[name]
                out.append((e.table, e.address, encode(e, v)))
        return out

    def _pose(self, q: np.ndarray) -> list[tuple[str, int, list]]:
        T = self.kin.flange(q)
        off_p, off_r = self.tcp_offset
        R_off = Rotation.from_rotvec(off_r)
        R_tcp = Rotation.from_matrix(T[:3, :3]) * R_off
        p_tcp = T[:3, 3] + T[:3, :3] @ off_p
        out = [self._words("tcp_position", p_tcp), self._words("tcp_rotation", R_tcp.as_rotvec())]
        if "tcp_offset_position" in self.map:
            out += [self._words("tcp_offset_position", off_p), self._words("tcp_offset_rotation", off_r)]
        return out

    def _garbage(self, e: Entry) -> tuple[str, int, list]:
        if e.type == "float32":
            words = [int(w) for w in self._rng.integers(0x4F00, 0x7F00, e.count)]  # huge values, not NaN
        else:
            lo, hi = int_range("uint16")
            words = [int(w) for w in self._rng.integers(0x1000, hi, e.count)]
        return e.table, e.address, words


def _wrap(entry: Entry, t: float) -> float:
    """A controller clock in an integer register wraps round."""
    if entry.type == "float32":
        return t
    lo, hi = int_range(entry.type)
    period = (hi - lo + 1) * entry.scale
    return (t % period) + lo * entry.scale
