"""Numbers of the simulated UR e-Series controller: ports, mode codes, register protocol, defaults.

Sources for every code: docs/sources.md, "UR / ur_rtde" (ur_rtde 1.6 headers and control script,
UR's RTDE guide). Fake-side model values (gains, noise, temperatures, the default TCP) are marked.
"""

from __future__ import annotations

import math

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORTS = (30001, 30002, 30003)

# Drive gains (N·m per A), per joint. Around 10 N·m/A; deliberately not all equal so that a
# per-joint gain calibration has something to find. Fake-side model, not UR data.
DEFAULT_GAINS_NM_PER_A = (10.4, 10.2, 9.8, 10.1, 9.9, 10.0)
DEFAULT_CURRENT_NOISE_A = 0.07
UR5E_HOME_Q = (0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)
# The TCP the installation defines, [x, y, z, rx, ry, rz] (m, rotation vector) in the flange frame:
# RTDE tcp_offset and URScript get_tcp_offset() report it; actual_TCP_pose is the flange pose
# times it. A tool centre 120 mm out, turned 0.3 rad about z: a fake-side choice, nonzero so that a
# client that forgets to take the offset out is caught.
DEFAULT_TCP_OFFSET = (0.0, 0.0, 0.12, 0.0, 0.0, 0.3)

# robot_mode (RTDE guide; ur_rtde rtde_receive_interface.h getRobotMode doc)
ROBOT_MODE_POWER_OFF, ROBOT_MODE_POWER_ON, ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING = 3, 4, 5, 7
ROBOT_MODE_NAMES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
                    4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE"}
# safety_mode (RTDE guide)
SAFETY_MODE_NORMAL, SAFETY_MODE_PROTECTIVE_STOP, SAFETY_MODE_ROBOT_EMERGENCY_STOP = 1, 3, 7
SAFETY_MODE_NAMES = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
                     6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT"}
# safety_status_bits (ur_rtde rtde_control_interface.h enum SafetyStatus = bit numbers)
SSB_NORMAL, SSB_PROTECTIVE, SSB_ROBOT_ESTOP, SSB_ESTOP, SSB_STOPPED_BY_SAFETY = 0, 2, 6, 7, 10
# runtime_state (ur_rtde rtde_control_interface.h enum RuntimeState)
RUNTIME_STOPPING, RUNTIME_STOPPED, RUNTIME_PLAYING, RUNTIME_PAUSING, RUNTIME_PAUSED, RUNTIME_RESUMING = range(6)
# robot_status_bits (ur_rtde enum RobotStatus = bit numbers)
RSB_POWER_ON, RSB_PROGRAM_RUNNING = 0, 1
JOINT_MODE_RUNNING, JOINT_MODE_POWER_OFF = 253, 239

# ur_rtde control script register protocol (ur_rtde rtde_control_interface.h / rtde.h / rtde_control.script)
UR_CONTROLLER_RDY_FOR_CMD = 1
UR_CONTROLLER_DONE_WITH_CMD = 2
CMD_MOVEJ, CMD_SET_PAYLOAD, CMD_PROTECTIVE_STOP, CMD_STOPL, CMD_STOPJ, CMD_SET_WATCHDOG = 1, 17, 31, 33, 34, 35
CMD_GET_TCP_OFFSET, CMD_IS_STEADY, CMD_SET_TARGET_PAYLOAD, CMD_STOP_SCRIPT = 40, 47, 65, 255
# commands the script handles as "real-time" (process, then signal ready; no done handshake)
REALTIME_CMDS = frozenset({24, 11, 9, 10, 6, 25, 26, 27, 38, 58})

UNLOCK_PROTECTIVE_STOP_DELAY_S = 5.0  # PolyScope refuses to unlock earlier
N_DIGITAL_INPUTS = 18  # actual_digital_input_bits: 8 standard + 8 configurable + 2 tool inputs (RTDE guide)
# RTDE joint_temperatures (VECTOR6D, °C). Fake-side model, not UR data: the joints start at these values and
# warm towards the steady state with a 30-minute time constant of simulated time.
DEFAULT_JOINT_TEMPS_C = (31.5, 33.0, 32.2, 35.1, 34.7, 34.9)
DEFAULT_STEADY_JOINT_TEMPS_C = (34.5, 37.0, 36.0, 38.5, 37.5, 37.0)
JOINT_TEMP_TAU_S = 1800.0


def pick_loopback_host() -> str:
    """A 127.0.0.x address on which the UR ports can be bound right now (``fakes.base.free_loopback_host``)."""
    from payload_agent.fakes.base import free_loopback_host

    return free_loopback_host((RTDE_PORT, DASHBOARD_PORT, *SCRIPT_PORTS))
