"""The object dictionary of one simulated CiA 402 servo drive (CiA 301 communication area + CiA 402).

Access types, PDO mappability and defaults as the standards define them (docs/sources.md,
"CANopen CiA 402"): the drive's SDO server refuses to write a read-only object, to map an
object that is not mappable, and so on, like a real drive. Kept apart from the driver's own
table (drivers/canopen/objects.py) on purpose, so that a mistake in one shows up against the other.
"""

from __future__ import annotations

from canopen import ObjectDictionary
from canopen.objectdictionary import (INTEGER8, INTEGER16, INTEGER32, UNSIGNED8, UNSIGNED16, UNSIGNED32,
                                      VISIBLE_STRING, ODRecord, ODVariable)

DEVICE_TYPE_SERVO = 0x00020192  # CiA 402 (0x0192 = 402), additional information 0x0002: servo drive
PDO_INVALID = 1 << 31

# (index, name, type, access, PDO-mappable ("t" transmit, "r" receive, ""), default)
_ENTRIES = [
    (0x1000, "Device type", UNSIGNED32, "ro", "", DEVICE_TYPE_SERVO),
    (0x1001, "Error register", UNSIGNED8, "ro", "t", 0),
    (0x1008, "Manufacturer device name", VISIBLE_STRING, "const", "", "SimServo 402"),
    (0x100A, "Manufacturer software version", VISIBLE_STRING, "const", "", "1.4.2-sim"),
    (0x1017, "Producer heartbeat time", UNSIGNED16, "rw", "", 0),
    (0x603F, "Error code", UNSIGNED16, "ro", "t", 0),
    (0x6007, "Abort connection option code", INTEGER16, "rw", "", 1),  # 1: fault signal (vendor default varies)
    (0x6040, "Controlword", UNSIGNED16, "rw", "r", 0),
    (0x6041, "Statusword", UNSIGNED16, "ro", "t", 0),
    (0x605A, "Quick stop option code", INTEGER16, "rw", "", 2),
    (0x6060, "Modes of operation", INTEGER8, "rw", "r", 0),
    (0x6061, "Modes of operation display", INTEGER8, "ro", "t", 0),
    (0x6064, "Position actual value", INTEGER32, "ro", "t", 0),
    (0x6067, "Position window", UNSIGNED32, "rw", "", 100),
    (0x6068, "Position window time", UNSIGNED16, "rw", "", 0),
    (0x6075, "Motor rated current", UNSIGNED32, "rw", "", 0),
    (0x6076, "Motor rated torque", UNSIGNED32, "rw", "", 0),
    (0x6077, "Torque actual value", INTEGER16, "ro", "t", 0),
    (0x6078, "Current actual value", INTEGER16, "ro", "t", 0),
    (0x607A, "Target position", INTEGER32, "rw", "r", 0),
    (0x6081, "Profile velocity", UNSIGNED32, "rw", "r", 0),
    (0x6083, "Profile acceleration", UNSIGNED32, "rw", "r", 0),
    (0x6084, "Profile deceleration", UNSIGNED32, "rw", "r", 0),
    (0x6085, "Quick stop deceleration", UNSIGNED32, "rw", "r", 0),
    (0x6502, "Supported drive modes", UNSIGNED32, "ro", "", 0x00000001),  # bit 0: profile position only
]


def _var(name, index, sub, data_type, access="rw", mappable="", default=None) -> ODVariable:
    v = ODVariable(name, index, sub)
    v.data_type, v.access_type, v.default = data_type, access, default
    v.pdo_mappable = bool(mappable)
    v.description = mappable  # which PDO direction it may be mapped into ("t"/"r")
    return v


def _record(name: str, index: int, members: list[ODVariable]) -> ODRecord:
    rec = ODRecord(name, index)
    for m in members:
        rec.add_member(m)
    return rec


def drive_dictionary(node_id: int, identity: tuple[int, int, int, int]) -> ObjectDictionary:
    """A fresh object dictionary for the drive with this node id; ``identity`` = (vendor, product, revision, serial)."""
    od = ObjectDictionary()
    od.node_id = node_id
    for index, name, data_type, access, mappable, default in _ENTRIES:
        od.add_object(_var(name, index, 0, data_type, access, mappable, default))
    od.add_object(_record("Consumer heartbeat time", 0x1016,  # one entry: node id << 16 | time in ms
                          [_var("Highest sub-index", 0x1016, 0, UNSIGNED8, "const", "", 1),
                           _var("Consumer heartbeat time", 0x1016, 1, UNSIGNED32, "rw", "", 0)]))
    od.add_object(_record("Identity object", 0x1018, [_var("Highest sub-index", 0x1018, 0, UNSIGNED8, "const", "", 4)]
                          + [_var(n, 0x1018, s, UNSIGNED32, "ro", "", v)
                             for s, (n, v) in enumerate(zip(("Vendor-ID", "Product code", "Revision number",
                                                             "Serial number"), identity), start=1)]))
    for n in range(4):
        for com, mapping, base, kind, default_map in ((0x1400, 0x1600, 0x200, "RPDO", [0x60400010]),
                                                      (0x1800, 0x1A00, 0x180, "TPDO", [0x60410010, 0x60640020])):
            cob = base + 0x100 * n + node_id | (0 if n == 0 else PDO_INVALID)  # only PDO 1 valid out of reset
            members = [_var("Highest sub-index", com + n, 0, UNSIGNED8, "const", "", 5 if kind == "TPDO" else 2),
                       _var("COB-ID", com + n, 1, UNSIGNED32, "rw", "", cob),
                       _var("Transmission type", com + n, 2, UNSIGNED8, "rw", "", 255)]
            if kind == "TPDO":
                members += [_var("Inhibit time", com + n, 3, UNSIGNED16, "rw", "", 0),
                            _var("Event timer", com + n, 5, UNSIGNED16, "rw", "", 0)]
            od.add_object(_record(f"{kind}{n + 1} communication parameter", com + n, members))
            entries = default_map if n == 0 else []
            od.add_object(_record(f"{kind}{n + 1} mapping parameter", mapping + n,
                                  [_var("Number of mapped objects", mapping + n, 0, UNSIGNED8, "rw", "", len(entries))]
                                  + [_var(f"Mapped object {k}", mapping + n, k, UNSIGNED32, "rw", "",
                                          entries[k - 1] if k <= len(entries) else 0) for k in range(1, 9)]))
    return od
