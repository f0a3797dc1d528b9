"""Simulated CANopen CiA 402 servo drives on python-can's virtual bus (the ``canopen`` driver's controller)."""

from payload_agent.fakes.canopen.controller import SimulatedCANopenArm

__all__ = ["SimulatedCANopenArm"]
