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
