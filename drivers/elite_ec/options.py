"""The ``driver`` section of a robot YAML for the Elite EC driver, as a typed dataclass.

Parsed by ``configuration.options.parse_options`` (through ``Driver.parse_options``), so
``plan`` checks it without connecting and a mistake names its key (``driver.rpc_port``).

    driver:
      type: elite_ec
      host: 192.168.1.200        # required
      rpc_port: 8055
      monitor_port: 8056
      sample_source: monitor     # or "poll": get_joint_pos + getRobotTorques on a second 8055 connection
      poll_rate_hz: 50           # only for sample_source: poll
      connect_timeout_s: 3.0
      reply_timeout_s: 2.0
      tool_num: 0                # tool whose payload read_payload/write_payload use
      joint_max_speed_deg_s: [150, 150, 190, 260, 260, 260]  # optional: each joint's 100 % speed
      target_tolerance_deg: 0.1  # final position check after a move

A port of 0 passes the parser: it means "any free port" to a simulated controller, which
then rewrites the options to where it listens (``bound_options``). The driver refuses to
connect to port 0.
"""

from __future__ import annotations

from dataclasses import dataclass

from payload_agent.drivers.base import DriverOptions, option

SAMPLE_SOURCES = ("monitor", "poll")


@dataclass(frozen=True, kw_only=True)
class EliteECOptions(DriverOptions):
    host: str = option(help="the controller's IP address or host name")
    rpc_port: int = option(8055, min=0, max=65535, help="JSON-RPC control port (0: a simulated controller picks)")
    monitor_port: int = option(8056, min=0, max=65535, help="monitor port (0: a simulated controller picks)")
    sample_source: str = option("monitor", choices=SAMPLE_SOURCES,
                                help='"monitor" (8056 frames every 8 ms) or "poll" (8055 polling)')
    poll_rate_hz: float = option(50.0, min=1.0, max=500.0, help="sampling rate for sample_source: poll")
    connect_timeout_s: float = option(3.0, min=0.05, max=120.0)
    reply_timeout_s: float = option(2.0, min=0.05, max=120.0)
    tool_num: int = option(0, min=0, max=7, help="tool whose payload read_payload/write_payload use")
    joint_max_speed_deg_s: tuple[float, ...] | None = option(None, gt=0, length=6,
                                                             help="each joint's 100 % speed, deg/s")
