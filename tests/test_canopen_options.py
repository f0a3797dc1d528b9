"""The canopen driver's YAML section: every mistake is refused at parse time (plan), naming its key."""

import subprocess
import sys

import pytest
import yaml

from conftest import ROOT, tweak
from payload_agent.configuration.config import parse_config
from payload_agent.drivers.base import MotionLimits
from payload_agent.drivers.canopen.driver import CANopenDriver
from payload_agent.errors import ConfigError

SIM = ROOT / "configs" / "sim-canopen-arm.yaml"


@pytest.fixture
def data():
    return yaml.safe_load(SIM.read_text())


def _refused(data, path, value, key, text=""):
    with pytest.raises(ConfigError) as exc:
        parse_config(tweak(data, path, value), source="sim-canopen-arm.yaml")
    assert exc.value.key_path == key, str(exc.value)
    assert text in str(exc.value)
    return exc.value


@pytest.mark.parametrize("bad, key, text", [
    ([1, 2, 3, 3, 5, 6], "driver.node_ids[3]", "node id 3 is already joint 3's"),
    ([0, 2, 3, 4, 5, 6], "driver.node_ids[0]", "between 1 and 127"),
    ([1, 2, 3, 4, 5, 128], "driver.node_ids[5]", "between 1 and 127"),
    ([1, 2, 3, 4, 5], "driver.node_ids", "expected 6 values"),
    ([1, 2, "3", 4, 5, 6], "driver.node_ids[2]", "expected an integer"),
])
def test_a_bad_node_id_is_refused_naming_the_key(data, bad, key, text):
    _refused(data, "driver.node_ids", bad, key, text)


def test_other_mistakes_name_their_key(data):
    _refused(data, "driver.direction", [1, -1, 0, 1, 1, 1], "driver.direction[2]", "1 or -1")
    _refused(data, "driver.interface", "socketcann", "driver.interface", "socketcan")
    _refused(data, "driver.counts_per_rad", [1000, 1000, -1, 1000, 1000, 1000], "driver.counts_per_rad[2]")
    _refused(data, "driver.effort_object", "torques", "driver.effort_object")
    _refused(data, "driver.heartbeat_timeout_ms", 100, "driver.heartbeat_timeout_ms", "must exceed heartbeat_ms")
    _refused(data, "driver.sync_rate_hz", 5, "driver.sync_rate_hz")
    _refused(data, "driver.node_id", [1, 2, 3, 4, 5, 6], "driver.node_id", "")  # a misspelt key is unknown
    _refused(data, "driver.master_node_id", 4, "driver.master_node_id", "is joint 4's drive")
    _refused(data, "driver.master_heartbeat_timeout_ms", 50, "driver.master_heartbeat_timeout_ms",
             "must exceed master_heartbeat_ms")


def test_a_bad_node_id_fails_plan_before_any_bus_opens(data, tmp_path):
    """`payload-agent plan` on a YAML with a duplicate node id: exit 2, the key named, no simulated drives started."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(tweak(data, "driver.node_ids", [1, 2, 3, 4, 2, 6])))
    proc = subprocess.run([sys.executable, "-m", "payload_agent.cli", "plan", "--robot", str(bad)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "driver.node_ids[4]" in proc.stderr and "node id 2 is already joint 2's" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_channel_may_be_a_number_and_effort_unit_follows_the_options(data):
    cfg = parse_config(tweak(data, "driver.channel", 0), source="x.yaml")
    assert cfg.driver_options.channel == "0"
    limits = MotionLimits(3.0, 3.0)
    assert CANopenDriver(cfg.driver_options, limits).effort_unit == "Nm"
    cur = parse_config(tweak(tweak(data, "driver.effort_object", "current"), "effort.unit", "A"), source="x.yaml")
    assert CANopenDriver(cur.driver_options, limits).effort_unit == "A"
    raw = parse_config(tweak(data, "driver.effort_scaling", "permille"), source="x.yaml")
    drv = CANopenDriver(raw.driver_options, limits)
    assert drv.effort_unit == "permille_rated"
    with pytest.raises(ConfigError, match="effort.unit"):
        drv.check_effort_unit("Nm")
    assert drv.nominal_period_s == pytest.approx(1 / 250)
