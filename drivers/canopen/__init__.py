"""CANopen CiA 402 servo drives (one per joint) through the canopen library on python-can.

``CANopenDriver`` (``driver``) fills the driver contract's hooks; ``CANopenOptions`` (``options``) is its
YAML ``driver`` section, importable without python-can's CANopen stack (the registry parses a robot YAML
with it alone).
"""
