"""The modbus driver's YAML options, and the register map they resolve to.

YAML ``driver`` mapping (every key validated by ``plan`` without connecting)::

    driver:
      type: modbus
      transport: tcp              # tcp | rtu
      host: 192.168.1.10          # tcp: the controller's address
      port: 502
      # serial_port: /dev/ttyUSB0 # rtu: the serial device; baudrate, parity, stopbits, bytesize
      #   or socket://192.168.1.50:4001: a serial device server's TCP port in raw mode (RTU frames over TCP)
      unit_id: 1                  # Modbus unit (device) id
      preset: ur_modbus_server    # a map in drivers/modbus/presets/, or leave out and give a full map
      map:                        # entries to add or change (key by key); null removes an optional one
        joint_efforts: {unit: A}
      sample_rate_hz: 250         # polling rate; samples arrive at most at the device's refresh rate
      timeout_s: 0.25             # per request

See docs/modbus.md for the signals and the handshake.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

from payload_agent.configuration.options import option, parse_options
from payload_agent.drivers.base import DriverOptions
from payload_agent.drivers.modbus.regmap import RegisterMap, build_map, load_preset
from payload_agent.errors import ConfigError


@dataclass(frozen=True)
class Endpoint:
    """Where and how to connect (from the driver options)."""

    transport: str  # "tcp" | "rtu"
    host: str | None
    port: int
    serial_port: str | None
    baudrate: int
    parity: str
    stopbits: int
    bytesize: int
    device_id: int
    timeout_s: float
    retries: int

    @property
    def device_server(self) -> tuple[str, int] | None:
        """RTU through a serial device server: its host and TCP port (``socket://host:port``), else None."""
        if self.transport != "rtu" or not self.serial_port.startswith("socket://"):
            return None
        url = urlsplit(self.serial_port)
        return url.hostname, url.port

    def describe(self) -> str:
        if self.transport == "tcp":
            return f"{self.host}:{self.port} (Modbus TCP, unit {self.device_id})"
        return f"{self.serial_port} (Modbus RTU {self.baudrate} baud, unit {self.device_id})"


@dataclass(frozen=True, kw_only=True)
class ModbusOptions(DriverOptions):
    transport: str = option("tcp", choices=("tcp", "rtu"), help="tcp or rtu")
    host: str | None = option(None, help="the controller's IP address (tcp)")
    port: int = option(502, min=0, max=65535, help="Modbus TCP port (0: a simulated server picks a free one)")
    serial_port: str | None = option(None, help="serial device (rtu), e.g. /dev/ttyUSB0, or a serial device "
                                                "server's TCP port, socket://192.168.1.50:4001")
    baudrate: int = option(115200, min=300, max=4_000_000)
    parity: str = option("N", choices=("N", "E", "O"))
    stopbits: int = option(1, choices=(1, 2))
    bytesize: int = option(8, choices=(7, 8))
    unit_id: int = option(1, min=0, max=247, help="Modbus unit / device id")
    preset: str | None = option(None, help="register map preset (drivers/modbus/presets)")
    map: dict[str, Any] | None = option(None, help="register map entries, added to or overriding the preset")
    bridge_gaps: int | None = option(None, min=0, max=124, help="undefined registers a read may span")
    sample_rate_hz: float = option(250.0, gt=0, max=1000, help="polling rate")
    server_update_hz: float | None = option(None, gt=0, max=10000, help="how often the device refreshes")
    timeout_s: float = option(0.25, gt=0, max=10)
    retries: int = option(0, min=0, max=5)
    command_poll_s: float | None = option(None, gt=0, max=1, help="answer polling period (tcp 0.01 s, rtu 0.05 s)")
    ack_timeout_s: float = option(1.0, gt=0, max=30, help="how long the program may take to take a command")
    heartbeat_timeout_s: float = option(0.5, gt=0, max=30)
    stop_ack_wait_s: float = option(0.5, gt=0, max=10)
    max_abs_angle_deg: float = option(720.0, gt=0, max=7200, help="a decoded angle beyond this is garbage")
    repeat_is_stale: bool = option(True, help="a sample identical to the previous one is not new")
    max_round_trip_s: float | None = option(None, gt=0, max=10, help="slower replies are not samples "
                                            "(default: 3 × the median round trip + 2 ms, at least 5 ms)")

    @classmethod
    def parse(cls, data: Any, key_path: str = "driver", source: str | None = None) -> "ModbusOptions":
        return parse_modbus_options(data, key_path, source)


def parse_modbus_options(data: Any, key_path: str = "driver", source: str | None = None) -> ModbusOptions:
    opts = parse_options(ModbusOptions, data, key_path, source)
    if opts.transport == "tcp" and not opts.host:
        raise ConfigError(f"{key_path}.host", "Modbus TCP needs the controller's address (host)", source)
    if opts.transport == "rtu" and not opts.serial_port:
        raise ConfigError(f"{key_path}.serial_port", "Modbus RTU needs the serial device (serial_port)", source)
    if opts.transport == "rtu" and opts.serial_port.startswith("socket://"):
        try:
            url = urlsplit(opts.serial_port)
            bad = not url.hostname or url.port is None or url.path not in ("", "/") or url.query
        except ValueError:  # a port that is no number or out of range
            bad = True
        if bad:
            raise ConfigError(f"{key_path}.serial_port", f"{opts.serial_port!r}: a serial device server is "
                                                         "socket://HOST:PORT (its TCP data port, raw mode)", source)
    if opts.preset is None and opts.map is None:
        raise ConfigError(f"{key_path}.map", "give a register map (map) or a preset name (preset) plus overrides; "
                                             "see docs/modbus.md", source)
    resolve_map(opts, key_path, source)  # validate now: plan rejects a bad map without connecting
    return opts


def resolve_map(opts: ModbusOptions, key_path: str = "driver", source: str | None = None) -> RegisterMap:
    preset = load_preset(opts.preset, f"{key_path}.preset", source) if opts.preset else None
    regmap = build_map(preset, opts.map, key_path, source, opts.preset)
    if opts.bridge_gaps is not None:
        regmap = RegisterMap(regmap.entries, regmap.vendor, regmap.model, opts.bridge_gaps, regmap.update_hz,
                             regmap.preset)
    if opts.server_update_hz is not None:
        regmap = RegisterMap(regmap.entries, regmap.vendor, regmap.model, regmap.bridge_gaps,
                             opts.server_update_hz, regmap.preset)
    return regmap


def endpoint(opts: ModbusOptions) -> Endpoint:
    return Endpoint(opts.transport, opts.host, opts.port, opts.serial_port, opts.baudrate, opts.parity,
                    opts.stopbits, opts.bytesize, opts.unit_id, opts.timeout_s, opts.retries)
