"""payload-agent: identify a robot tool's mass and centre of mass from PTP moves."""

__version__ = "0.1.0"
