"""The UR driver's flange pose for the kinematic cross-check and its optional capabilities
(digital inputs, joint temperatures, the payload setting with its inertia where the version has it).

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

READBACK_WAIT_S = 2.0  # the RTDE payload fields show a new setting within a few cycles
# a pose no UR arm reports, generously (the largest UR reaches 1.75 m; a rotation vector's angle is at most π,
# wound once more at most): corrupt data that parsed into finite numbers, refused before any arithmetic
MAX_POSE_M = 100.0
MAX_ROTATION_RAD = 4 * math.pi


class URCapabilities:
    """Needs from the driver: host, _version, _has_payload_fields, _has_inertia_field, _inertia_writable, _control, _receive(), _state(),
    _ensure_control(), _why_not_running(), _wait()."""

    host: str
    _version: tuple[int, ...]
    _has_payload_fields: bool
    _has_inertia_field: bool  # RTDE payload_inertia (5.11 / 3.15)
    _inertia_writable: bool  # set_target_payload with its readback (e-Series 5.11)
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
            if not _plausible_pose(v):
                raise CommunicationError(f"UR controller {self.host}: {what} returned {v!r}, not a pose any UR arm "
                                         f"reports (6 finite numbers, positions within ±{MAX_POSE_M:g} m, a rotation "
                                         f"vector of at most {MAX_ROTATION_RAD:.3g} rad)")
        flange = _pose_matrix(pose) @ np.linalg.inv(_pose_matrix(offset))
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
    def payload_inertia_support(self) -> str:
        """"" where ``write_payload`` writes the inertia too: set_target_payload through ur-rtde's script
        (its lines are tagged PolyScope 5.10) and RTDE ``payload_inertia`` to read it back (5.11)."""
        if self._inertia_writable:
            return ""
        version = ".".join(map(str, self._version)) or "unknown"
        return (f"UR controller {self.host} (PolyScope {version}) takes mass and centre of gravity only: the "
                "inertia needs set_target_payload and the RTDE payload_inertia readback (e-Series PolyScope 5.11 "
                "or newer)")

    def read_payload(self) -> PayloadSetting:
        if not self._has_payload_fields:
            raise UnsupportedCapability(f"UR controller {self.host} (PolyScope {'.'.join(map(str, self._version))}) "
                                        "has no RTDE payload fields (they need 5.5.1 / 3.11 or newer)")
        r = self._receive()
        mass, cog = float(r.getPayload()), [float(c) for c in r.getPayloadCog()]
        if len(cog) != 3 or not all(math.isfinite(v) for v in [mass, *cog]):  # a NaN would pass any readback check
            raise CommunicationError(f"UR controller {self.host}: the RTDE payload fields read {mass} kg at {cog} m, "
                                     "not a finite mass and centre of gravity")
        inertia = None
        if self._has_inertia_field:
            six = [float(v) for v in r.getPayloadInertia()]
            if len(six) != 6 or not all(math.isfinite(v) for v in six):
                raise CommunicationError(f"UR controller {self.host}: RTDE payload_inertia reads {six}, "
                                         "not 6 finite numbers")
            inertia = ur_six_to_tensor(six)
        return PayloadSetting(mass_kg=mass, cog_m=(cog[0], cog[1], cog[2]), inertia_com_kgm2=inertia)

    def write_payload(self, payload: PayloadSetting) -> None:
        """Mass and centre of gravity (setPayload), with the inertia (setTargetPayload) where the controller
        takes it and ``payload`` has one; then waits until the RTDE payload fields report what was written."""
        mass = float(payload.mass_kg)
        cog = [float(c) for c in payload.cog_m]
        if not (math.isfinite(mass) and mass >= 0 and len(cog) == 3 and all(math.isfinite(c) for c in cog)):
            raise ValueError(f"invalid payload {payload!r}")
        six = None
        if payload.inertia_com_kgm2 is not None and self._inertia_writable:
            six = tensor_to_ur_six(payload.inertia_com_kgm2)
        # ur-rtde's control script keeps the current centre of gravity when it is sent
        # [0, 0, 0] (rtde_control.script, set_payload branch for PolyScope >= 5.0): send 1 nm instead.
        sent_cog = cog if any(cog) else [0.0, 0.0, 1e-9]
        state = self._state(refresh_remote=False)
        if not state.motion_allowed:
            raise RobotNotReadyError(f"UR controller {self.host}: {state.reason}")
        self._ensure_control()
        call = ("setTargetPayload", mass, sent_cog, six) if six is not None else ("setPayload", mass, sent_cog)
        with self._control.lock:
            ok = self._control.request(*call, timeout_s=COMMAND_TIMEOUT_S)
        what = "set_target_payload" if six is not None else "set_payload"
        if not ok:
            raise MotionAbortedError(f"UR controller {self.host}: {what} was not executed "
                                     f"({self._why_not_running()})")
        if self._has_payload_fields:
            self._check_payload_readback(mass, cog, six, what)

    def _check_payload_readback(self, mass: float, cog: list[float], six: list[float] | None, what: str) -> None:
        """Wait up to READBACK_WAIT_S for the RTDE payload fields to show what was written; else say what
        they show and the likely cause (the controller took the command but not the values)."""
        got: list[PayloadSetting] = []

        def matches() -> bool:
            got[:] = [self.read_payload()]
            p = got[0]
            ok = abs(p.mass_kg - mass) < 1e-6 and all(abs(a - b) < 1e-6 for a, b in zip(p.cog_m, cog))
            if six is not None and p.inertia_com_kgm2 is not None:
                ok = ok and all(abs(a - b) < 1e-9 for a, b in zip(tensor_to_ur_six(p.inertia_com_kgm2), six))
            return ok

        try:
            self._wait(matches, READBACK_WAIT_S, "the controller to report the new payload")
        except CommunicationError:
            if not got:
                raise
            p = got[0]
            read = f"{p.mass_kg:.4f} kg at {[round(1000 * c, 2) for c in p.cog_m]} mm"
            if six is not None and p.inertia_com_kgm2 is not None:
                read += f", inertia {[round(v, 6) for v in tensor_to_ur_six(p.inertia_com_kgm2)]} kg·m²"
            wrote = f"{mass:.4f} kg at {[round(1000 * c, 2) for c in cog]} mm" + \
                (f", inertia {[round(v, 6) for v in six]} kg·m²" if six is not None else "")
            raise CommunicationError(
                f"UR controller {self.host}: {what} ran but the controller reports {read} after {wrote} was "
                f"written. Likely: another program or URCap set the payload again, the robot left Remote Control, "
                f"or this PolyScope ({'.'.join(map(str, self._version))}) ignores part of {what}; the payload "
                "setting was NOT verified: check it on the pendant (Installation > General > Payload)") from None


# UR's 6-vector order (URScript set_target_payload, RTDE payload_inertia): [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]
_UR_SIX = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
UR_INERTIA_LIMIT_KGM2 = 133.0  # set_target_payload refuses elements beyond this (Script Manual)


def tensor_to_ur_six(tensor) -> list[float]:
    """A 3x3 inertia about the CoG (flange axes, kg·m²) -> UR's [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]; ValueError when
    it is not a symmetric, positive semi-definite tensor within set_target_payload's limits."""
    T = np.asarray(tensor, float)
    if T.shape != (3, 3) or not np.all(np.isfinite(T)):
        raise ValueError(f"payload inertia must be a 3x3 matrix of finite numbers (kg·m²), got {tensor!r}")
    if not np.allclose(T, T.T, rtol=0, atol=1e-9 + 1e-6 * float(np.max(np.abs(T)))):
        raise ValueError(f"payload inertia {T.tolist()} is not symmetric")
    if float(np.min(np.linalg.eigvalsh(T))) < -1e-9:
        raise ValueError(f"payload inertia {T.tolist()} is not positive semi-definite (no body has it)")
    six = [float(T[i, j]) for i, j in _UR_SIX]
    if max(abs(v) for v in six) > UR_INERTIA_LIMIT_KGM2:
        raise ValueError(f"payload inertia {six} has an element beyond set_target_payload's "
                         f"±{UR_INERTIA_LIMIT_KGM2:g} kg·m²")
    return six


def ur_six_to_tensor(six: Sequence[float]) -> tuple[tuple[float, float, float], ...]:
    """UR's [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] -> the symmetric 3x3 tensor (rows)."""
    xx, yy, zz, xy, xz, yz = (float(v) for v in six)
    return ((xx, xy, xz), (xy, yy, yz), (xz, yz, zz))


def _plausible_pose(v: Sequence[float] | None) -> bool:
    """[x, y, z, rx, ry, rz] as a UR controller can report it: finite, within ``MAX_POSE_M`` and
    ``MAX_ROTATION_RAD``; absurd finite numbers (1e200 m) would overflow the transforms into NaN."""
    return (v is not None and len(v) == 6 and all(math.isfinite(x) for x in v)
            and max(abs(x) for x in v[:3]) <= MAX_POSE_M and math.hypot(*v[3:]) <= MAX_ROTATION_RAD)


def _pose_matrix(pose: Sequence[float]) -> np.ndarray:
    """UR pose [x, y, z, rx, ry, rz] (m, rotation vector) -> 4x4 homogeneous transform."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.asarray(pose[3:6], float)).as_matrix()
    T[:3, 3] = np.asarray(pose[:3], float)
    return T
