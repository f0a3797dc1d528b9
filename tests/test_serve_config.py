"""The `serve` configuration: password hashes only, endpoint and roles checked with the key named."""

import pytest

from payload_agent.errors import ConfigError
from payload_agent.plc.serve_config import check_password, hash_password, parse_serve_config


def test_hash_and_users():
    h = hash_password("s3cret", iterations=1000)
    assert check_password("s3cret", h) and not check_password("wrong", h) and not check_password("s3cret", "x$y")
    cfg = parse_serve_config({"opcua": {"endpoint": "opc.tcp://0.0.0.0:4841/pa/", "anonymous_read": True},
                              "users": [{"name": "plc", "password": h, "role": "operator"}],
                              "modbus": {"port": 1502}})
    assert cfg.anonymous_read and cfg.modbus.port == 1502 and cfg.modbus.host == "127.0.0.1"
    assert cfg.user("plc", "s3cret").role == "operator" and cfg.user("plc", "nope") is None
    assert parse_serve_config(None).users == () and not parse_serve_config(None).anonymous_read  # secure default


@pytest.mark.parametrize("data, key", [
    ({"users": [{"name": "plc", "password": "plaintext", "role": "operator"}]}, "users[0].password"),
    ({"users": [{"name": "plc", "password": "pbkdf2_sha256$1$00$00", "role": "admin"}]}, "users[0].role"),
    ({"opcua": {"endpoint": "http://host:80/"}}, "opcua.endpoint"),
    ({"opcua": {"anonymous": True}}, "opcua"),
    ({"modbus": {"port": 70000}}, "modbus.port"),
])
def test_bad_config_names_the_key(data, key):
    with pytest.raises(ConfigError) as exc:
        parse_serve_config(data, "serve.yaml")
    assert key in str(exc.value) and "serve.yaml" in str(exc.value)


def test_trusted_clients_folder(tmp_path):
    """The trust folder of client certificates: default None (the server uses <state>/<robot>/opcua/trusted); a
    path that exists but is a file is refused naming the key."""
    assert parse_serve_config(None).trusted_clients_dir is None
    cfg = parse_serve_config({"opcua": {"trusted_clients": str(tmp_path / "trusted")}})
    assert cfg.trusted_clients_dir == tmp_path / "trusted"
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ConfigError, match="opcua.trusted_clients.*not a folder"):
        parse_serve_config({"opcua": {"trusted_clients": str(tmp_path / "afile")}}, "serve.yaml")
