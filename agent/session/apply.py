"""Writing the identified payload to the controller: show the difference, ask, write, read back, verify.

The inertia about the centre of mass goes with mass and CoG when the result has one (``inertia_com_kgm2``,
null when the quality check refused it) and the driver's controller takes it
(``Driver.payload_inertia_support``); otherwise mass and CoG only, and the output says why in one line.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from payload_agent.drivers.base import Driver
from payload_agent.errors import CommunicationError, DataError, MotionAbortedError, PayloadAgentError
from payload_agent.solvers.results import RunResult
from payload_agent.types import PayloadSetting

READBACK_TOL_KG = 0.001  # the controllers store mass to 1 g or better
READBACK_TOL_M = 0.0005  # and the centre of mass to 0.5 mm or better
READBACK_TOL_KGM2 = 1e-6  # the inertia elements as doubles (UR: RTDE payload_inertia)


def identified_inertia(result: RunResult) -> tuple[tuple[float, float, float], ...] | None:
    """The result's inertia about the centre of mass (3x3, flange axes, kg·m²), or None when it has none
    or the quality check did not accept it (``inertia_com_kgm2`` null, ``inertia_unsupported`` set)."""
    value = getattr(result.primary, "inertia_com_kgm2", None)
    if value is None:
        value = result.extra.get("inertia_com_kgm2")
    if value is None or result.extra.get("inertia_unsupported"):
        return None
    tensor = np.asarray(value, float)
    if tensor.shape != (3, 3) or not np.all(np.isfinite(tensor)):
        raise DataError(f"the result's inertia_com_kgm2 is not a 3x3 matrix of numbers: {value!r}")
    return tuple(tuple(float(v) for v in row) for row in tensor)


def payload_to_write(result: RunResult, driver: Driver | None = None) -> tuple[PayloadSetting, str | None]:
    """The setting ``--apply`` writes and, when the identified inertia is left out, why (one line)."""
    est = result.primary
    inertia = identified_inertia(result)
    why = None
    if inertia is not None and driver is not None:
        reason = driver.payload_inertia_support()
        if reason:
            inertia, why = None, f"Inertia not written: {reason}."
    return PayloadSetting(float(est.mass_kg), tuple(float(c) for c in est.cog_m), inertia_com_kgm2=inertia), why


def apply_result(driver: Driver, result: RunResult, ask: Callable[[str], str] | None,
                 out: Callable[[str], None]) -> PayloadSetting:
    """Show the controller's current setting and the difference, write, read back, verify."""
    new, why_no_inertia = payload_to_write(result, driver)
    try:
        current = driver.read_payload()
    except PayloadAgentError as exc:
        current = None
        out(f"Current controller payload setting: unknown ({exc})")
    if current is not None:
        out(describe_payload_change(current, new))
    if why_no_inertia:
        out(why_no_inertia)
    if ask is not None:
        answer = ask("Write the identified payload to the controller? [y/N] ")
        if answer.strip().lower() not in ("y", "yes"):
            out("Not applied (declined).")
            raise MotionAbortedError("the operator declined writing the payload; the result is kept")
    if current is not None and current.tool_num is not None:
        new = PayloadSetting(new.mass_kg, new.cog_m, current.tool_num, new.inertia_com_kgm2)
    driver.write_payload(new)
    back = driver.read_payload()
    dm = abs(back.mass_kg - new.mass_kg)
    dc = max(abs(a - b) for a, b in zip(back.cog_m, new.cog_m))
    di = 0.0
    if new.inertia_com_kgm2 is not None:
        if back.inertia_com_kgm2 is None:
            raise CommunicationError("the inertia was written but the controller does not report it: not verified")
        di = float(np.max(np.abs(np.asarray(back.inertia_com_kgm2) - np.asarray(new.inertia_com_kgm2))))
    if dm > READBACK_TOL_KG or dc > READBACK_TOL_M or di > READBACK_TOL_KGM2:
        raise CommunicationError(f"the controller reads back {describe_setting(back)} after writing {describe_setting(new)}")
    out(f"Applied and read back: {describe_setting(back, with_inertia=new.inertia_com_kgm2 is not None)}")
    return back


def describe_setting(p: PayloadSetting, with_inertia: bool = True) -> str:
    """"1.2340 kg at [x, y, z] mm" and, where known, the inertia as UR's [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]."""
    text = f"{p.mass_kg:.4f} kg, centre of mass [{', '.join(f'{1000 * c:.1f}' for c in p.cog_m)}] mm"
    if with_inertia and p.inertia_com_kgm2 is not None:
        t = p.inertia_com_kgm2
        six = (t[0][0], t[1][1], t[2][2], t[0][1], t[0][2], t[1][2])
        text += f", inertia [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] [{', '.join(f'{v:.6f}' for v in six)}] kg·m² about the CoG"
    return text


def describe_payload_change(current: PayloadSetting, new: PayloadSetting) -> str:
    cur_mm = [1000 * c for c in current.cog_m]
    new_mm = [1000 * c for c in new.cog_m]
    tool = f" (tool {current.tool_num})" if current.tool_num is not None else ""
    return (f"Controller payload setting{tool}: {current.mass_kg:.3f} kg at "
            f"[{', '.join(f'{v:.1f}' for v in cur_mm)}] mm\n"
            f"Identified:                 {new.mass_kg:.3f} kg at [{', '.join(f'{v:.1f}' for v in new_mm)}] mm\n"
            f"Difference:                 {new.mass_kg - current.mass_kg:+.3f} kg, "
            f"[{', '.join(f'{b - a:+.1f}' for a, b in zip(cur_mm, new_mm))}] mm")
