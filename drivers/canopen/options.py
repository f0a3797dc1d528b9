"""The ``driver`` section of a robot YAML for CANopen CiA 402 drives, as a typed dataclass.

Parsed by ``configuration.options.parse_options`` (through ``CANopenOptions.parse``), then
checked by ``check_options`` for what one field alone cannot say (unique node ids, directions of
±1, a known python-can interface), so ``plan`` refuses a bad section before any bus opens and the
error names its key (``driver.node_ids[3]: node id 3 is already joint 3's``).

    driver:
      type: canopen
      interface: socketcan          # python-can interface: socketcan, pcan, kvaser, ixxat, vector, virtual, ...
      channel: can0                 # the interface's channel ("PCAN_USBBUS1", "0", a virtual bus name)
      bitrate: 1000000              # bit/s, for interfaces that set it (socketcan takes it from `ip link`)
      node_ids: [1, 2, 3, 4, 5, 6]  # the drive of joint 1 first; 1..127, unique
      counts_per_rad: [...]         # position units of 0x6064 / 0x607A per joint radian (encoder x gear / 2 pi)
      direction: [1, -1, ...]       # +1: the drive counts up when the joint angle grows; -1: the opposite
      zero_counts: [0, ...]         # position actual value at joint angle 0
      effort_object: torque         # 0x6077 torque actual value, or "current": 0x6078 current actual value
      effort_scaling: rated         # per mille x rated torque (0x6076) / current (0x6075) -> N·m / A; or "permille"
      rated_torque_nm: [...]        # only for drives without 0x6076 (the drive's own value wins; a mismatch
      rated_current_a: [...]        #   of more than 1 % is refused); likewise 0x6075 for current
      sync_rate_hz: 250             # SYNC producer rate = sample rate
      heartbeat_ms: 50              # producer heartbeat time written to every drive (0x1017)
      heartbeat_timeout_ms: 150     # consumer: a drive silent for longer is lost (the run aborts)
      master_node_id: 127           # the agent's own node id on the bus: its heartbeat is 0x700 + this
      master_heartbeat_ms: 50       # the agent's heartbeat (sent with SYNC); 0: none, the drives cannot watch it
      master_heartbeat_timeout_ms: 150  # consumer time written to every drive (0x1016): a drive that hears no
                                    #   heartbeat from the agent for longer quick-stops itself (0x6007 = 3)
      clear_faults: false           # a drive found in FAULT at connect is reported; true: reset it (and say so)
"""

from __future__ import annotations

import math

from dataclasses import dataclass
from typing import Any

from payload_agent.drivers.base import DriverOptions, option
from payload_agent.errors import ConfigError

EFFORT_OBJECTS = ("torque", "current")
EFFORT_SCALINGS = ("rated", "permille")
INT32_MIN, INT32_MAX = -(1 << 31), (1 << 31) - 1


@dataclass(frozen=True, kw_only=True)
class CANopenOptions(DriverOptions):
    interface: str = option(help="the python-can interface: socketcan, pcan, kvaser, ixxat, vector, virtual, ...")
    channel: str = option(help='the interface channel: "can0", "PCAN_USBBUS1", "0", a virtual bus name')
    bitrate: int = option(1_000_000, min=10_000, max=1_000_000, help="CAN bit rate, bit/s")
    node_ids: tuple[int, ...] = option(length=6, min=1, max=127, help="each joint's CANopen node id, joint 1 first")
    counts_per_rad: tuple[float, ...] = option(length=6, gt=0, help="position units (0x6064, 0x607A) per joint radian")
    direction: tuple[int, ...] = option((1, 1, 1, 1, 1, 1), length=6, min=-1, max=1,
                                        help="+1 or -1: the drive's counting sense relative to the joint angle")
    zero_counts: tuple[int, ...] = option((0, 0, 0, 0, 0, 0), length=6, min=INT32_MIN, max=INT32_MAX,
                                          help="position actual value at joint angle 0")
    effort_object: str = option("torque", choices=EFFORT_OBJECTS,
                                help='"torque" (0x6077 torque actual) or "current" (0x6078 current actual)')
    effort_scaling: str = option("rated", choices=EFFORT_SCALINGS,
                                 help='"rated": per mille x rated torque/current (N·m or A); "permille": raw')
    rated_torque_nm: tuple[float, ...] | None = option(None, length=6, gt=0,
                                                       help="rated torque per drive, for drives without 0x6076")
    rated_current_a: tuple[float, ...] | None = option(None, length=6, gt=0,
                                                       help="rated current per drive, for drives without 0x6075")
    sync_rate_hz: float = option(250.0, min=10.0, max=1000.0, help="SYNC producer rate (the sample rate), Hz")
    heartbeat_ms: int = option(50, min=5, max=10_000, help="producer heartbeat time written to each drive (0x1017)")
    heartbeat_timeout_ms: int = option(150, min=10, max=60_000, help="consumer heartbeat time: a drive silent "
                                                                     "for longer is lost")
    master_node_id: int = option(127, min=1, max=127, help="the agent's own node id: its heartbeat COB-ID is "
                                                             "0x700 + this; must differ from every drive's")
    master_heartbeat_ms: int = option(50, min=0, max=10_000, help="the agent's heartbeat period; 0: none (the drives "
                                                                  "then cannot stop themselves when the agent is lost)")
    master_heartbeat_timeout_ms: int = option(150, min=10, max=60_000,
                                              help="consumer heartbeat time written to every drive (0x1016): a drive "
                                                   "that hears no heartbeat from the agent for longer quick-stops")
    sdo_timeout_s: float = option(0.5, min=0.01, max=10.0, help="how long an SDO transfer may wait for the drive")
    enable_timeout_s: float = option(1.0, min=0.05, max=30.0, help="per CiA 402 state transition")
    clear_faults: bool = option(False, help="reset a drive found in FAULT at connect (reported, never silent)")
    quick_stop_decel_rad_s2: float = option(10.0, gt=0, max=1000.0, help="quick stop deceleration (0x6085)")
    position_window_deg: float = option(0.02, gt=0, max=5.0, help="target reached window (0x6067)")

    @classmethod
    def parse(cls, data: Any, key_path: str = "driver", source: str | None = None) -> "CANopenOptions":
        if isinstance(data, dict) and isinstance(data.get("channel"), int) and not isinstance(data["channel"], bool):
            data = {**data, "channel": str(data["channel"])}  # kvaser & co. number their channels
        return check_options(super().parse(data, key_path, source), key_path, source)

    @property
    def effort_unit(self) -> str:
        if self.effort_scaling == "permille":
            return "permille_rated"
        return "Nm" if self.effort_object == "torque" else "A"

    def joint_label(self, j: int) -> str:
        """How messages name a drive: "joint 3 (node 3)" (0-based ``j``)."""
        return f"joint {j + 1} (node {self.node_ids[j]})"

    def to_counts(self, j: int, angle_rad: float) -> int:
        """Joint ``j``'s angle as its drive's position (0x607A / 0x6064, counts)."""
        return round(self.zero_counts[j] + self.direction[j] * float(angle_rad) * self.counts_per_rad[j])

    def to_angle_rad(self, j: int, counts: int) -> float:
        """Drive ``j``'s position (counts) as the joint's angle: the inverse of ``to_counts``."""
        return self.direction[j] * (counts - self.zero_counts[j]) / self.counts_per_rad[j]

    def window_counts(self, j: int) -> int:
        """The target reached window (0x6067) of drive ``j`` in counts, at least 1."""
        return max(1, round(math.radians(self.position_window_deg) * self.counts_per_rad[j]))


def known_interfaces() -> tuple[str, ...]:
    """python-can's interface names (its own table, so a new backend needs no change here)."""
    from can.interfaces import VALID_INTERFACES

    return tuple(sorted(VALID_INTERFACES))


def check_options(opts: CANopenOptions, key_path: str = "driver", source: str | None = None) -> CANopenOptions:
    """What one field alone cannot check; ConfigError names the key. Runs at parse time, before any bus opens."""
    interfaces = known_interfaces()
    if opts.interface not in interfaces:
        raise ConfigError(f"{key_path}.interface", f"unknown python-can interface {opts.interface!r}; "
                                                   f"known: {', '.join(interfaces)}", source)
    if not opts.channel.strip():
        raise ConfigError(f"{key_path}.channel", "the channel is empty", source)
    seen: dict[int, int] = {}
    for j, nid in enumerate(opts.node_ids):
        if nid in seen:
            raise ConfigError(f"{key_path}.node_ids[{j}]", f"node id {nid} is already joint {seen[nid] + 1}'s; every "
                                                           "drive needs its own node id (1..127)", source)
        seen[nid] = j
    for j, d in enumerate(opts.direction):
        if d not in (1, -1):
            raise ConfigError(f"{key_path}.direction[{j}]", f"must be 1 or -1, got {d}", source)
    if opts.heartbeat_timeout_ms <= opts.heartbeat_ms:
        raise ConfigError(f"{key_path}.heartbeat_timeout_ms", f"must exceed heartbeat_ms ({opts.heartbeat_ms} ms), got "
                                                              f"{opts.heartbeat_timeout_ms} ms; 3x is usual", source)
    if opts.master_node_id in seen:
        raise ConfigError(f"{key_path}.master_node_id", f"node id {opts.master_node_id} is joint "
                                                        f"{seen[opts.master_node_id] + 1}'s drive; the agent needs a "
                                                        "node id of its own on the bus (127 is usual)", source)
    if opts.master_heartbeat_ms and opts.master_heartbeat_timeout_ms <= opts.master_heartbeat_ms:
        raise ConfigError(f"{key_path}.master_heartbeat_timeout_ms",
                          f"must exceed master_heartbeat_ms ({opts.master_heartbeat_ms} ms), got "
                          f"{opts.master_heartbeat_timeout_ms} ms; 3x is usual", source)
    return opts
