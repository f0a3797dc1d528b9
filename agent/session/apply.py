"""Writing the identified payload to the controller: show the difference, ask, write, read back, verify."""

from __future__ import annotations

from typing import Callable

from payload_agent.drivers.base import Driver
from payload_agent.errors import CommunicationError, MotionAbortedError, PayloadAgentError
from payload_agent.solvers.results import RunResult
from payload_agent.types import PayloadSetting

READBACK_TOL_KG = 0.001  # the controllers store mass to 1 g or better
READBACK_TOL_M = 0.0005  # and the centre of mass to 0.5 mm or better


def apply_result(driver: Driver, result: RunResult, ask: Callable[[str], str] | None,
                 out: Callable[[str], None]) -> PayloadSetting:
    """Show the controller's current setting and the difference, write, read back, verify."""
    est = result.primary
    new = PayloadSetting(mass_kg=float(est.mass_kg), cog_m=tuple(float(c) for c in est.cog_m))
    try:
        current = driver.read_payload()
    except PayloadAgentError as exc:
        current = None
        out(f"Current controller payload setting: unknown ({exc})")
    if current is not None:
        out(describe_payload_change(current, new))
    if ask is not None:
        answer = ask("Write the identified payload to the controller? [y/N] ")
        if answer.strip().lower() not in ("y", "yes"):
            out("Not applied (declined).")
            raise MotionAbortedError("the operator declined writing the payload; the result is kept")
    if current is not None and current.tool_num is not None:
        new = PayloadSetting(new.mass_kg, new.cog_m, current.tool_num)
    driver.write_payload(new)
    back = driver.read_payload()
    dm = abs(back.mass_kg - new.mass_kg)
    dc = max(abs(a - b) for a, b in zip(back.cog_m, new.cog_m))
    if dm > READBACK_TOL_KG or dc > READBACK_TOL_M:
        raise CommunicationError(
            f"the controller reads back {back.mass_kg:.4f} kg at {[round(1000 * c, 2) for c in back.cog_m]} mm "
            f"after writing {new.mass_kg:.4f} kg at {[round(1000 * c, 2) for c in new.cog_m]} mm")
    out(f"Applied and read back: {back.mass_kg:.4f} kg, centre of mass "
        f"{', '.join(f'{1000 * c:.1f}' for c in back.cog_m)} mm")
    return back


def describe_payload_change(current: PayloadSetting, new: PayloadSetting) -> str:
    cur_mm = [1000 * c for c in current.cog_m]
    new_mm = [1000 * c for c in new.cog_m]
    tool = f" (tool {current.tool_num})" if current.tool_num is not None else ""
    return (f"Controller payload setting{tool}: {current.mass_kg:.3f} kg at "
            f"[{', '.join(f'{v:.1f}' for v in cur_mm)}] mm\n"
            f"Identified:                 {new.mass_kg:.3f} kg at [{', '.join(f'{v:.1f}' for v in new_mm)}] mm\n"
            f"Difference:                 {new.mass_kg - current.mass_kg:+.3f} kg, "
            f"[{', '.join(f'{b - a:+.1f}' for a, b in zip(cur_mm, new_mm))}] mm")
