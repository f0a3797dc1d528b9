"""The identified payload as the operator types it into the controller, and whether it was written.

Two forms per controller, each with its units in its labels:

- the **pendant form**, in the units the controller's own payload screen shows: mass in kg and
  the centre of gravity in mm for both PolyScope (UR: Installation > General > Payload on the
  e-Series, Installation > TCP on CB3) and the Elite pendant (tool payload: kg, mm);
- the **script form**, what a robot program or an API call takes: URScript
  ``set_target_payload(m, [x, y, z])`` with the centre of gravity in metres; Elite's JSON-RPC
  ``cmd_set_payload`` with ``m`` in kg and ``cog`` in mm (docs/sources.md).

Any other driver gets kg and mm in the flange frame of the YAML's DH table (frame 6), unless its
class declares ``payload_units = ("kg", "m")`` (or ``"mm"``) and ``payload_vendor``. A new
controller is one ``ControllerForm`` in ``FORMS``.

The agent's centre of mass is in the YAML's flange frame (DH frame 6), which for the shipped
UR and Elite tables is the controller's tool flange frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

LENGTH_FACTOR = {"m": 0.001, "mm": 1.0}  # from mm
LENGTH_DIGITS = {"m": 4, "mm": 1}


@dataclass(frozen=True)
class ControllerForm:
    """How one controller takes a payload: its pendant screen and its script or API call."""

    controller: str  # "Universal Robots controller"
    screen: str  # where on the pendant: "PolyScope Installation > General > Payload"
    screen_unit: str  # length unit the screen shows: "mm" or "m"
    script_name: str = ""  # "URScript"; "" when there is no script form
    script: str = ""  # format with {m}, {x}, {y}, {z} (lengths in ``script_unit``)
    script_unit: str = "m"


FORMS: dict[str, ControllerForm] = {
    "ur_rtde": ControllerForm("Universal Robots controller", "PolyScope: Installation > General > Payload", "mm",
                              "URScript", "set_target_payload({m}, [{x}, {y}, {z}])", "m"),
    "elite_ec": ControllerForm("Elite EC controller", "Elite pendant: tool payload", "mm", "JSON-RPC",
                               'cmd_set_payload {{"tool_num": 0, "m": {m}, "cog": [{x}, {y}, {z}]}}', "mm"),
}


@dataclass(frozen=True)
class PendantValues:
    controller: str
    mass_kg: float
    cog: tuple[float, float, float]  # in ``length_unit``: what the pendant screen shows
    length_unit: str  # "m" or "mm"
    frame: str
    screen: str = ""  # where on the pendant
    script_name: str = ""
    script: str = ""  # the script or API form, filled in; "" when the controller has none

    @property
    def cog_text(self) -> str:
        return ", ".join(f"{v:.{LENGTH_DIGITS[self.length_unit]}f}" for v in self.cog)

    @property
    def pendant_text(self) -> str:
        """``mass 2.031 kg, CoG X 30.3 mm, Y -18.8 mm, Z 60.4 mm``: every field with its unit, as on the screen."""
        d = LENGTH_DIGITS[self.length_unit]
        return (f"mass {self.mass_kg:.3f} kg, centre of gravity X {self.cog[0]:.{d}f} {self.length_unit}, "
                f"Y {self.cog[1]:.{d}f} {self.length_unit}, Z {self.cog[2]:.{d}f} {self.length_unit}")

    def describe(self) -> str:
        where = f"; {self.screen}" if self.screen else ""
        text = f"Values for the {self.controller} ({self.frame}{where}): {self.pendant_text}"
        if self.script:
            text += f"\n  {self.script_name} form: {self.script}"
        return text

    def to_json(self) -> dict[str, Any]:
        return {"controller": self.controller, "mass_kg": round(self.mass_kg, 6), "cog": list(self.cog),
                "cog_unit": self.length_unit, "frame": self.frame, "screen": self.screen or None,
                "script": self.script or None}


def pendant_values(driver_type: str | None, mass_kg: float, cog_mm: Sequence[float]) -> PendantValues:
    """The payload in the units the controller of ``driver_type`` shows (see the module docstring)."""
    form = FORMS.get(driver_type or "")
    if form is None:
        name, unit = _declared(driver_type)
        form = ControllerForm(name, "", unit)
    unit = form.screen_unit
    cog = tuple(float(c) * LENGTH_FACTOR[unit] for c in cog_mm)
    script = ""
    if form.script:
        u, d = form.script_unit, LENGTH_DIGITS[form.script_unit]
        x, y, z = (f"{float(c) * LENGTH_FACTOR[u]:.{d}f}" for c in cog_mm)
        script = form.script.format(m=f"{float(mass_kg):.3f}", x=x, y=y, z=z)
    return PendantValues(form.controller, float(mass_kg), cog, unit, "tool flange frame",  # type: ignore[arg-type]
                         form.screen, form.script_name, script)


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
            written = rec.get("written") if isinstance(rec.get("written"), Mapping) else {}
            inertia = back.get("inertia_com_kgm2") if written.get("inertia_com_kgm2") is not None else None
            extra = ""
            if isinstance(inertia, list) and len(inertia) == 3:
                six = [inertia[0][0], inertia[1][1], inertia[2][2], inertia[0][1], inertia[0][2], inertia[1][2]]
                extra = f", inertia [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] [{', '.join(f'{float(v):.6f}' for v in six)}] kg·m²"
            note = f" {rec['note']}" if rec.get("note") else ""
            return (f"Written to the controller{tool} and read back: {float(back.get('mass_kg', float('nan'))):.3f} kg "
                    f"at [{cog}] mm{extra}.{note}")
        return "Not written to the controller: " + str(rec.get("reason") or "not requested (--apply not given)") + "."
    if history_entry is not None and getattr(history_entry, "applied", False):
        cog = history_entry.applied_cog_mm or ()
        return (f"Written to the controller and read back: {history_entry.applied_mass_kg:.3f} kg at "
                f"[{', '.join(f'{float(v):.1f}' for v in cog)}] mm.")
    return "Not written to the controller (type the values above, or run with --apply)."


def payload_write_record(requested: bool, applied: bool, written: Any = None, read_back: Any = None,
                         reason: str | None = None, note: str | None = None) -> dict[str, Any]:
    """The manifest's ``payload_write`` object (the runner stores it after a write-back, or its refusal).

    ``written`` / ``read_back``: PayloadSetting-like (mass_kg, cog_m, tool_num, inertia_com_kgm2) or None.
    """
    def setting(p: Any) -> dict[str, Any] | None:
        if p is None:
            return None
        inertia = getattr(p, "inertia_com_kgm2", None)
        return {"mass_kg": float(p.mass_kg), "cog_mm": [1000.0 * float(c) for c in p.cog_m],
                "tool_num": getattr(p, "tool_num", None),
                "inertia_com_kgm2": None if inertia is None else [[float(v) for v in row] for row in inertia]}

    record = {"requested": bool(requested), "applied": bool(applied), "written": setting(written),
              "read_back": setting(read_back), "reason": reason}
    if note:  # e.g. why the identified inertia was not written
        record["note"] = note
    return record
