"""The CiA 301 / CiA 402 objects the driver reads and writes, as a canopen ObjectDictionary.

The driver needs no vendor EDS: it uses only standard objects, whose index, sub-index and
data type the standards fix (docs/sources.md, "CANopen CiA 402"). The canopen library needs
them declared to encode SDO values and to lay out PDO mappings.
"""

from __future__ import annotations

from canopen import ObjectDictionary
from canopen.objectdictionary import (INTEGER8, INTEGER16, INTEGER32, UNSIGNED8, UNSIGNED16, UNSIGNED32,
                                      VISIBLE_STRING, ODArray, ODRecord, ODVariable)

CONTROLWORD, STATUSWORD = 0x6040, 0x6041
ERROR_CODE = 0x603F
MODES_OF_OPERATION, MODES_DISPLAY = 0x6060, 0x6061
POSITION_ACTUAL, TARGET_POSITION = 0x6064, 0x607A
POSITION_WINDOW, POSITION_WINDOW_TIME = 0x6067, 0x6068
RATED_CURRENT, RATED_TORQUE = 0x6075, 0x6076
TORQUE_ACTUAL, CURRENT_ACTUAL = 0x6077, 0x6078
PROFILE_VELOCITY, PROFILE_ACCELERATION, PROFILE_DECELERATION = 0x6081, 0x6083, 0x6084
QUICK_STOP_DECELERATION = 0x6085
DEVICE_NAME, SOFTWARE_VERSION, IDENTITY = 0x1008, 0x100A, 0x1018
ERROR_REGISTER, PRODUCER_HEARTBEAT = 0x1001, 0x1017
CONSUMER_HEARTBEAT = 0x1016  # ARRAY of UNSIGNED32: node id << 16 | consumer time in ms
ABORT_CONNECTION = 0x6007  # INTEGER16: what a drive does when it loses its master (3 = quick stop)

_VARIABLES = [  # (index, name, data type, PDO-mappable)
    (0x1000, "Device type", UNSIGNED32, False),
    (ERROR_REGISTER, "Error register", UNSIGNED8, False),
    (DEVICE_NAME, "Manufacturer device name", VISIBLE_STRING, False),
    (SOFTWARE_VERSION, "Manufacturer software version", VISIBLE_STRING, False),
    (PRODUCER_HEARTBEAT, "Producer heartbeat time", UNSIGNED16, False),
    (ERROR_CODE, "Error code", UNSIGNED16, True),
    (ABORT_CONNECTION, "Abort connection option code", INTEGER16, False),
    (CONTROLWORD, "Controlword", UNSIGNED16, True),
    (STATUSWORD, "Statusword", UNSIGNED16, True),
    (0x605A, "Quick stop option code", INTEGER16, False),
    (MODES_OF_OPERATION, "Modes of operation", INTEGER8, True),
    (MODES_DISPLAY, "Modes of operation display", INTEGER8, True),
    (POSITION_ACTUAL, "Position actual value", INTEGER32, True),
    (POSITION_WINDOW, "Position window", UNSIGNED32, False),
    (POSITION_WINDOW_TIME, "Position window time", UNSIGNED16, False),
    (RATED_CURRENT, "Motor rated current", UNSIGNED32, False),
    (RATED_TORQUE, "Motor rated torque", UNSIGNED32, False),
    (TORQUE_ACTUAL, "Torque actual value", INTEGER16, True),
    (CURRENT_ACTUAL, "Current actual value", INTEGER16, True),
    (TARGET_POSITION, "Target position", INTEGER32, True),
    (PROFILE_VELOCITY, "Profile velocity", UNSIGNED32, True),
    (PROFILE_ACCELERATION, "Profile acceleration", UNSIGNED32, True),
    (PROFILE_DECELERATION, "Profile deceleration", UNSIGNED32, True),
    (QUICK_STOP_DECELERATION, "Quick stop deceleration", UNSIGNED32, True),
]


def _var(name: str, index: int, subindex: int, data_type: int, mappable: bool = False) -> ODVariable:
    v = ODVariable(name, index, subindex)
    v.data_type = data_type
    v.pdo_mappable = mappable
    return v


def _record(name: str, index: int, members: list[tuple[str, int]]) -> ODRecord:
    rec = ODRecord(name, index)
    for sub, (member, data_type) in enumerate(members):
        rec.add_member(_var(member, index, sub, data_type))
    return rec


def cia402_dictionary() -> ObjectDictionary:
    """The standard objects of a CiA 402 drive that this driver uses, PDO parameters included."""
    od = ObjectDictionary()
    for index, name, data_type, mappable in _VARIABLES:
        od.add_object(_var(name, index, 0, data_type, mappable))
    consumer = ODArray("Consumer heartbeat time", CONSUMER_HEARTBEAT)
    consumer.add_member(_var("Highest sub-index", CONSUMER_HEARTBEAT, 0, UNSIGNED8))
    consumer.add_member(_var("Consumer heartbeat time", CONSUMER_HEARTBEAT, 1, UNSIGNED32))  # template of 1..127
    od.add_object(consumer)
    od.add_object(_record("Identity object", IDENTITY, [("Highest sub-index", UNSIGNED8), ("Vendor-ID", UNSIGNED32),
                                                         ("Product code", UNSIGNED32), ("Revision number", UNSIGNED32),
                                                         ("Serial number", UNSIGNED32)]))
    for n in range(4):  # PDO communication and mapping parameters, RPDO 0x1400/0x1600, TPDO 0x1800/0x1A00
        for com, mapping, kind in ((0x1400, 0x1600, "RPDO"), (0x1800, 0x1A00, "TPDO")):
            od.add_object(_record(f"{kind}{n + 1} communication parameter", com + n,
                                  [("Highest sub-index", UNSIGNED8), ("COB-ID", UNSIGNED32),
                                   ("Transmission type", UNSIGNED8)]))
            od.add_object(_record(f"{kind}{n + 1} mapping parameter", mapping + n,
                                  [("Number of mapped objects", UNSIGNED8)]
                                  + [(f"Mapped object {k}", UNSIGNED32) for k in range(1, 9)]))
    return od
