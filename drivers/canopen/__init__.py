"""CANopen CiA 402 servo drives (one per joint) through the canopen library on python-can."""

from payload_agent.drivers.canopen.driver import CANopenDriver
from payload_agent.drivers.canopen.options import CANopenOptions

__all__ = ["CANopenDriver", "CANopenOptions"]
