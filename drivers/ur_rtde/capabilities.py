"""The UR driver's optional capabilities: digital inputs, joint temperatures, the payload setting.

All read from the RTDE receive interface's latest package (no control script, no Remote Control
needed), except the payload write, which is a command to ur-rtde's control script. A mixin of
``URRTDEDriver`` (``driver``), which provides the connections it uses.
"""

from __future__ import annotations

import math
from typing import Any, Callable

from payload_agent.drivers.ur_rtde.control import COMMAND_TIMEOUT_S
from payload_agent.drivers.ur_rtde.states import DIGITAL_INPUT_NAMES
from payload_agent.errors import CommunicationError, MotionAbortedError, RobotNotReadyError, UnsupportedCapability
from payload_agent.types import ControllerState, PayloadSetting


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
