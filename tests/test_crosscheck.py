"""The kinematic cross-check names the usual mistakes in a robot YAML's DH table."""

import dataclasses
import math

import numpy as np
import pytest

from payload_agent.configuration.config import load_config
from payload_agent.model.kinematics import Kinematics
from payload_agent.motion.crosscheck import compare_pose
from payload_agent.types import FlangePose

from conftest import ROOT

TRUE = load_config(ROOT / "configs" / "ec66.yaml").robot.kinematics
Q = np.radians([10, -70, 80, 95, -85, 20])


def reported(kin: Kinematics, q) -> FlangePose:
    T = kin.flange(q)
    return FlangePose(tuple(T[:3, 3]), tuple(map(tuple, T[:3, :3])))


def with_rows(**changes) -> Kinematics:
    rows = list(TRUE.rows)
    for key, value in changes.items():
        j, field = int(key[-1]) - 1, key[:-1]
        rows[j] = dataclasses.replace(rows[j], **{field: value(rows[j])})
    return Kinematics(rows)


def check(yaml_kin: Kinematics):
    return compare_pose(yaml_kin, Q, reported(TRUE, Q), 0.005, math.radians(1))


def test_a_correct_model_passes():
    assert check(TRUE).ok


@pytest.mark.parametrize("wrong, cause", [
    (dict(a_m2=lambda r: -r.a_m, a_m3=lambda r: -r.a_m), "signs of a2 and a3"),
    (dict(a_m3=lambda r: -r.a_m), "sign of a3"),
    (dict(d_m4=lambda r: -r.d_m), "sign of d4"),
    (dict(offset_rad2=lambda r: r.offset_rad + math.pi / 2), "zero offset of joint 2"),
])
def test_a_wrong_model_is_refused_with_its_likely_cause(wrong, cause):
    result = check(with_rows(**wrong))
    assert not result.ok and cause in result.likely_cause
    assert "mm" in result.describe() and cause in result.describe()


def test_a_pose_in_millimetres_is_named_as_a_unit_mistake():
    pose = reported(TRUE, Q)
    in_mm = FlangePose(tuple(1000 * v for v in pose.position_m), pose.rotation)
    result = compare_pose(TRUE, Q, in_mm, 0.005, math.radians(1))
    assert not result.ok and "units" in result.likely_cause


def test_sign_flipped_dh_is_refused_before_any_motion_command(tmp_path):
    """A YAML with a2 and a3 flipped (a usual copy mistake between DH conventions), against the simulated EC66."""
    import yaml

    from payload_agent.configuration.config import parse_config
    from payload_agent.errors import SafetyError
    from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification

    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    for j in (1, 2):
        data["robot"]["kinematics"]["dh"][j]["a_mm"] *= -1
    data["driver"].update(rpc_port=0, monitor_port=0)
    data["storage"] = {"runs_dir": str(tmp_path / "runs"), "state_dir": str(tmp_path / "state")}
    data.pop("watch", None)
    cells = []
    with pytest.raises(SafetyError) as err:
        run_identification(parse_config(data, "flipped.yaml"),
                           RunOptions(assume_yes=True, report=False),
                           OperatorUI(progress=False, out=lambda s: None),
                           SimulatedCellUse(on_cell=cells.append))
    assert "signs of a2 and a3" in str(err.value) and "reported by the controller" in str(err.value)
    assert not [e for e in cells[0].controller.events if e.kind == "move"]
    assert not (tmp_path / "runs").exists()  # refused before a run folder was made
