"""The identified payload as the operator types it into the controller, and whether it was written.

Every controller has its own units for the payload setting; the value the agent reports in
kg and mm must be retyped in those, in the controller's frame:

- Universal Robots (``ur_rtde``): mass in kg, centre of gravity in metres, in the tool flange
  frame (PolyScope's payload setting, URScript ``set_target_payload``);
- Elite EC (``elite_ec``): mass in kg, centre of mass in mm, tool flange frame;
- any other driver: kg and mm in the flange frame of the YAML's DH table (frame 6), unless the
  driver class declares ``payload_units = ("kg", "m")`` (or ``"mm"``) and ``payload_vendor``.

The agent's centre of mass is in the YAML's flange frame (DH frame 6), which for the shipped
UR and Elite tables is the controller's tool flange frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

# driver type -> (controller name, length unit)
KNOWN = {"ur_rtde": ("Universal Robots controller", "m"), "elite_ec": ("Elite EC controller", "mm")}


@dataclass(frozen=True)
class PendantValues:
    controller: str
    mass_kg: float
    cog: tuple[float, float, float]  # in ``length_unit``
    length_unit: str  # "m" or "mm"
    frame: str

    @property
    def cog_text(self) -> str:
        digits = 4 if self.length_unit == "m" else 1
        return ", ".join(f"{v:.{digits}f}" for v in self.cog)

    def describe(self) -> str:
        return (f"Values for the {self.controller} ({self.frame}): mass {self.mass_kg:.3f} kg, "
                f"centre of mass [{self.cog_text}] {self.length_unit}")

    def to_json(self) -> dict[str, Any]:
        return {"controller": self.controller, "mass_kg": round(self.mass_kg, 6), "cog": list(self.cog),
                "cog_unit": self.length_unit, "frame": self.frame}


def pendant_values(driver_type: str | None, mass_kg: float, cog_mm: Sequence[float]) -> PendantValues:
    """The payload in the units the controller of ``driver_type`` expects (see the module docstring)."""
    name, unit = KNOWN.get(driver_type or "", (None, None))
    if name is None:
        name, unit = _declared(driver_type)
    factor = 0.001 if unit == "m" else 1.0
    cog = tuple(float(c) * factor for c in cog_mm)
    return PendantValues(name, float(mass_kg), cog, unit, "tool flange frame")  # type: ignore[arg-type]


def _declared(driver_type: str | None) -> tuple[str, str]:
    """A third-party driver's own declaration, if it is installed and declares one; else kg and mm."""
    generic = (f"{driver_type} controller" if driver_type else "controller", "mm")
    if not driver_type:
        return generic
    try:
        from payload_agent.drivers.registry import driver_class

        cls = driver_class(driver_type)
    except Exception:  # not installed here (a report read elsewhere): the generic form
        return generic
    units = getattr(cls, "payload_units", None)
    unit = units[1] if isinstance(units, (tuple, list)) and len(units) == 2 and units[1] in ("m", "mm") else "mm"
    return str(getattr(cls, "payload_vendor", generic[0])), unit


def driver_type_of(manifest: Mapping[str, Any]) -> str | None:
    """The driver a run was recorded with (from its config snapshot)."""
    cfg = manifest.get("config") or {}
    drv = cfg.get("driver") if isinstance(cfg, Mapping) else None
    return str(drv.get("type")) if isinstance(drv, Mapping) and drv.get("type") else None


def write_back_text(manifest: Mapping[str, Any], history_entry: Any = None) -> str:
    """Whether the values were written to the controller and read back, in one sentence.

    Reads the manifest's ``payload_write`` record (docs/run-format.md) or, for runs recorded
    before it existed, the history entry of the run.
    """
    rec = manifest.get("payload_write")
    if isinstance(rec, Mapping):
        back = rec.get("read_back")
        if rec.get("applied") and isinstance(back, Mapping):
            cog = ", ".join(f"{float(v):.1f}" for v in back.get("cog_mm", []))
            tool = f" (tool {back['tool_num']})" if back.get("tool_num") is not None else ""
            return (f"Written to the controller{tool} and read back: {float(back.get('mass_kg', float('nan'))):.3f} kg "
                    f"at [{cog}] mm.")
        return "Not written to the controller: " + str(rec.get("reason") or "not requested (--apply not given)") + "."
    if history_entry is not None and getattr(history_entry, "applied", False):
        cog = history_entry.applied_cog_mm or ()
        return (f"Written to the controller and read back: {history_entry.applied_mass_kg:.3f} kg at "
                f"[{', '.join(f'{float(v):.1f}' for v in cog)}] mm.")
    return "Not written to the controller (type the values above, or run with --apply)."


def payload_write_record(requested: bool, applied: bool, written: Any = None, read_back: Any = None,
                         reason: str | None = None) -> dict[str, Any]:
    """The manifest's ``payload_write`` object (the runner stores it after a write-back, or its refusal).

    ``written`` / ``read_back``: PayloadSetting-like (mass_kg, cog_m, tool_num) or None.
    """
    def setting(p: Any) -> dict[str, Any] | None:
        if p is None:
            return None
        return {"mass_kg": float(p.mass_kg), "cog_mm": [1000.0 * float(c) for c in p.cog_m],
                "tool_num": getattr(p, "tool_num", None)}

    return {"requested": bool(requested), "applied": bool(applied), "written": setting(written),
            "read_back": setting(read_back), "reason": reason}
