"""The `serve` configuration: where the servers bind, who may do what. A YAML file of its own (``--config``).

    opcua:
      endpoint: opc.tcp://127.0.0.1:4840/payload-agent/   # binds here; 0.0.0.0 for every interface
      anonymous_read: false      # true: anonymous sessions may browse and read (never write or call)
      trusted_clients: /etc/payload-agent/opcua-trusted   # optional; default <state>/<robot>/opcua/trusted/
    users:                       # user names for OPC UA sessions; passwords as hashes (serve_config.hash_password)
      - {name: plc, password: "pbkdf2_sha256$200000$<salt hex>$<hash hex>", role: operator}   # may start jobs
      - {name: scada, password: "pbkdf2_sha256$...", role: reader}                            # read only
    modbus:                      # optional: the same handshake over Modbus TCP registers (docs/production.md, "The PLC in charge")
      host: 127.0.0.1
      port: 5020
      unit: 1

Security is not optional: the OPC UA server offers Basic256Sha256 with SignAndEncrypt only, and its
certificate is created on first start in the robot's state folder (``<state>/<robot>/opcua/``).
Without any operator no one can start a job; without ``anonymous_read`` anonymous sessions are refused.
Only client applications whose certificate (DER or PEM) is in the ``trusted_clients`` folder may open a
session at all (``plc.opcua_trust``); a refused one's certificate is kept in ``<state>/<robot>/opcua/rejected/``.
"""

from __future__ import annotations

import hashlib
import hmac
import os
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlparse

import yaml

from payload_agent.configuration.yamlcheck import Node
from payload_agent.errors import ConfigError

ROLES = ("operator", "reader")
PBKDF2_ITERATIONS = 200_000


def hash_password(password: str, *, salt: bytes | None = None, iterations: int = PBKDF2_ITERATIONS) -> str:
    salt = salt or os.urandom(16)
    digest = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), salt, iterations)
    return f"pbkdf2_sha256${iterations}${salt.hex()}${digest.hex()}"


def check_password(password: str, stored: str) -> bool:
    try:
        scheme, iterations, salt, digest = stored.split("$")
        if scheme != "pbkdf2_sha256":
            return False
        got = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), bytes.fromhex(salt), int(iterations))
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(got.hex(), digest)


@dataclass(frozen=True)
class UserSpec:
    name: str
    password_hash: str
    role: str  # operator | reader


@dataclass(frozen=True)
class ModbusSpec:
    host: str = "127.0.0.1"
    port: int = 5020
    unit: int = 1


@dataclass(frozen=True)
class ServeConfig:
    endpoint: str = "opc.tcp://127.0.0.1:4840/payload-agent/"
    anonymous_read: bool = False
    users: tuple[UserSpec, ...] = ()
    modbus: ModbusSpec | None = None
    source: str = "<serve config>"
    trusted_clients_dir: Path | None = None  # None: <state>/<robot>/opcua/trusted/

    def user(self, name: str | None, password: str | None) -> UserSpec | None:
        for u in self.users:
            if name is not None and u.name == name and password is not None and check_password(password,
                                                                                                u.password_hash):
                return u
        return None


def parse_serve_config(data, source: str = "<serve config>") -> ServeConfig:
    top = Node(data if data is not None else {}, "", source)
    top.reject_unknown(["opcua", "users", "modbus"])
    endpoint, anonymous, trusted = ServeConfig.endpoint, False, None
    if top.has("opcua"):
        o = top.child("opcua")
        endpoint = o.string("endpoint", ServeConfig.endpoint)
        anonymous = o.boolean("anonymous_read", False)
        if o.has("trusted_clients"):
            trusted = Path(o.string("trusted_clients")).expanduser()
            if trusted.exists() and not trusted.is_dir():
                raise o.error("trusted_clients", f"{trusted} is not a folder (a folder of client certificates, "
                                                 "DER or PEM)")
        o.reject_unknown(["endpoint", "anonymous_read", "trusted_clients"])
        url = urlparse(endpoint)
        if url.scheme != "opc.tcp" or not url.hostname or not url.port:
            raise o.error("endpoint", f"expected opc.tcp://HOST:PORT/PATH, got {endpoint!r}")
    users = []
    raw_users = top.raw("users", [])
    if not isinstance(raw_users, list):
        raise top.error("users", "expected a list of {name, password, role}")
    for i, item in enumerate(raw_users):
        u = Node(item, f"users[{i}]", source)
        name = u.string("name")
        pw = u.string("password")
        if not pw.startswith("pbkdf2_sha256$"):
            raise u.error("password", "store a hash, never the password itself: "
                                      "python -c 'from payload_agent.plc.serve_config import hash_password; "
                                      "print(hash_password(\"...\"))'")
        role = u.string("role", choices=ROLES)
        u.reject_unknown(["name", "password", "role"])
        users.append(UserSpec(name, pw, role))
    modbus = None
    if top.has("modbus"):
        m = top.child("modbus")
        modbus = ModbusSpec(m.string("host", "127.0.0.1"), m.integer("port", 5020, min=0, max=65535),
                            m.integer("unit", 1, min=0, max=247))
        m.reject_unknown(["host", "port", "unit"])
    return ServeConfig(endpoint, anonymous, tuple(users), modbus, source, trusted)


def load_serve_config(path: Path) -> ServeConfig:
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError("--config", f"no such file: {path}") from None
    except yaml.YAMLError as exc:
        raise ConfigError("<file>", f"not valid YAML: {exc}", str(path)) from None
    return parse_serve_config(data, str(path))
