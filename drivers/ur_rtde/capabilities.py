"""The UR driver's flange pose for the kinematic cross-check and its optional capabilities
(digital inputs, joint temperatures, the payload setting).

The readings come from the RTDE receive interface's latest package (no control script, no Remote
Control needed); the TCP offset and the payload write are commands to ur-rtde's control script.
A mixin of ``URRTDEDriver`` (``driver``), which provides the connections it uses.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from payload_agent.drivers.ur_rtde.control import COMMAND_TIMEOUT_S
from payload_agent.drivers.ur_rtde.states import DIGITAL_INPUT_NAMES
from payload_agent.errors import CommunicationError, MotionAbortedError, RobotNotReadyError, UnsupportedCapability
from payload_agent.types import ControllerState, FlangePose, PayloadSetting


class URCapabilities:
    """Needs from the driver: host, _version, _has_payload_fields, _control, _receive(), _state(),
    _ensure_control(), _why_not_running(), _wait()."""

    host: str
    _version: tuple[int, ...]
    _has_payload_fields: bool
    _control: Any
    _receive: Callable[[], Any]
    _state: Callable[[bool], ControllerState]
    _ensure_control: Callable[[], None]
    _why_not_running: Callable[[], str]
    _wait: Callable[[Callable[[], bool], float, str], None]

    # -- kinematic cross-check -------------------------------------------------------------------
    def flange_pose(self) -> FlangePose:
        """actual_TCP_pose with the TCP offset the controller reports (getTCPOffset) taken out.

        Builds the control interface (uploads ur-rtde's script) if no command has yet: the
        cross-check runs right before the first move, which needs it anyway.
        """
        self._ensure_control()
        with self._control.lock:
            offset = self._control.request("getTCPOffset", timeout_s=COMMAND_TIMEOUT_S)
        pose = self._receive().getActualTCPPose()
        for what, v in (("getTCPOffset", offset), ("actual_TCP_pose", pose)):
            if v is None or len(v) != 6 or not all(math.isfinite(x) for x in v):
                raise CommunicationError(f"UR controller {self.host}: {what} returned {v!r}, not 6 finite numbers")
        flange = _pose_matrix(pose) @ np.linalg.inv(_pose_matrix(offset))
        if not np.all(np.isfinite(flange)):  # finite but absurd numbers (1e200 m) overflow the product
            raise CommunicationError(f"UR controller {self.host}: actual_TCP_pose {pose!r} with getTCPOffset "
                                     f"{offset!r} is not a pose any UR arm reports")
        return FlangePose(position_m=tuple(float(x) for x in flange[:3, 3]),
                          rotation=tuple(tuple(float(x) for x in row) for row in flange[:3, :3]))

    # -- digital inputs, temperatures --------------------------------------------------------------
    def read_digital_input(self, index: int) -> bool:
        """Bit ``index`` of RTDE ``actual_digital_input_bits``: 0-7 DI0-7, 8-15 CI0-7, 16-17 tool TI0-1.

        Read with ur-rtde's ``getDigitalInState`` from the receive interface's latest package;
        needs no control script and no Remote Control.
        """
        if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < len(DIGITAL_INPUT_NAMES):
            raise ValueError(f"UR digital input index must be an integer in [0, {len(DIGITAL_INPUT_NAMES) - 1}] "
                             f"(0-7 standard DI0-7, 8-15 configurable CI0-7, 16-17 tool TI0-1), got {index!r}")
        try:
            return bool(self._receive().getDigitalInState(index))
        except RuntimeError as exc:  # the field is missing from the recipe / no package yet
            raise CommunicationError(f"UR controller {self.host}: cannot read digital input "
                                     f"{DIGITAL_INPUT_NAMES[index]} (bit {index} of actual_digital_input_bits): {exc}") \
                from exc

    def joint_temperatures_c(self) -> tuple[float, ...]:
        """RTDE ``joint_temperatures`` (°C) of the latest package, through ``getJointTemperatures``."""
        try:
            values = tuple(float(v) for v in self._receive().getJointTemperatures())
        except RuntimeError as exc:  # the field is missing from the recipe / no package yet
            raise CommunicationError(f"UR controller {self.host}: cannot read joint_temperatures: {exc}") from exc
        if len(values) != 6 or not all(math.isfinite(v) for v in values):
            raise CommunicationError(f"UR controller {self.host}: joint_temperatures is {list(values)}, "
                                     "expected 6 finite values")
        return values

    # -- payload ---------------------------------------------------------------------------------
    def read_payload(self) -> PayloadSetting:
        if not self._has_payload_fields:
            raise UnsupportedCapability(f"UR controller {self.host} (PolyScope {'.'.join(map(str, self._version))}) "
                                        "has no RTDE payload fields (they need 5.5.1 / 3.11 or newer)")
        r = self._receive()
        mass, cog = float(r.getPayload()), [float(c) for c in r.getPayloadCog()]
        if len(cog) != 3 or not all(math.isfinite(v) for v in [mass, *cog]):  # a NaN would pass any readback check
            raise CommunicationError(f"UR controller {self.host}: the RTDE payload fields read {mass} kg at {cog} m, "
                                     "not a finite mass and centre of gravity")
        return PayloadSetting(mass_kg=mass, cog_m=(cog[0], cog[1], cog[2]))

    def write_payload(self, payload: PayloadSetting) -> None:
        mass = float(payload.mass_kg)
        cog = [float(c) for c in payload.cog_m]
        if not (math.isfinite(mass) and mass >= 0 and len(cog) == 3 and all(math.isfinite(c) for c in cog)):
            raise ValueError(f"invalid payload {payload!r}")
        # ur-rtde's control script keeps the current centre of gravity when it is sent
        # [0, 0, 0] (rtde_control.script, set_payload branch for PolyScope >= 5.0): send 1 nm instead.
        sent_cog = cog if any(cog) else [0.0, 0.0, 1e-9]
        state = self._state(refresh_remote=False)
        if not state.motion_allowed:
            raise RobotNotReadyError(f"UR controller {self.host}: {state.reason}")
        self._ensure_control()
        with self._control.lock:
            ok = self._control.request("setPayload", mass, sent_cog, timeout_s=COMMAND_TIMEOUT_S)
        if not ok:
            raise MotionAbortedError(f"UR controller {self.host}: set_payload was not executed "
                                     f"({self._why_not_running()})")
        if self._has_payload_fields:
            def matches() -> bool:
                got = self.read_payload()
                return abs(got.mass_kg - mass) < 1e-6 and all(abs(a - b) < 1e-6 for a, b in zip(got.cog_m, cog))

            self._wait(matches, 2.0, "the controller to report the new payload")


def _pose_matrix(pose: Sequence[float]) -> np.ndarray:
    """UR pose [x, y, z, rx, ry, rz] (m, rotation vector) -> 4x4 homogeneous transform."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.asarray(pose[3:6], float)).as_matrix()
    T[:3, 3] = np.asarray(pose[:3], float)
    return T
