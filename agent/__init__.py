"""payload-agent: identify a robot tool's mass and centre of mass from PTP moves.

``payload_agent.identify(robot, unattended=True, apply=False)`` is the Python API (see ``api``).
"""

from payload_agent.version import __version__


def identify(robot, **options):
    """Identify the mounted tool's payload; see ``payload_agent.api.identify``."""
    from payload_agent.api import identify as _identify

    return _identify(robot, **options)
