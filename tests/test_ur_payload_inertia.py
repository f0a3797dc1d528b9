"""The payload with its inertia through ur-rtde's setTargetPayload / getPayloadInertia, against the
simulated UR over loopback: the round trip, `--apply`'s write-back, a readback that differs, and
the controller versions that take mass and centre of gravity only."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rtde_control", reason="ur-rtde wheel not installed (CPython 3.11/3.12)")

from payload_agent.drivers.base import MotionLimits, Supervision  # noqa: E402
from payload_agent.drivers.ur_rtde.capabilities import tensor_to_ur_six  # noqa: E402
from payload_agent.drivers.ur_rtde.driver import URRTDEDriver  # noqa: E402
from payload_agent.errors import CommunicationError, MotionAbortedError  # noqa: E402
from payload_agent.fakes.ur import FakeURController  # noqa: E402
from payload_agent.session.apply import apply_result, payload_to_write  # noqa: E402
from payload_agent.solvers.results import Estimate, RunResult  # noqa: E402
from payload_agent.types import PayloadSetting  # noqa: E402

LIMITS = MotionLimits(max_joint_speed_rad_s=3.0, max_joint_accel_rad_s2=40.0)
# A 1.4 kg gripper, off axis, with products of inertia (positive definite, about its CoG, flange axes)
INERTIA = ((0.0041, -0.0003, 0.0006), (-0.0003, 0.0052, 0.0002), (0.0006, 0.0002, 0.0023))
TOOL = PayloadSetting(1.4, (0.018, -0.006, 0.072), inertia_com_kgm2=INERTIA)


def connected(fake: FakeURController) -> URRTDEDriver:
    d = URRTDEDriver(URRTDEDriver.parse_options({"type": "ur_rtde", "host": fake.host}), LIMITS,
                     Supervision(max_stream_gap_s=0.2))
    d.connect()
    return d


def result_with_inertia(inertia=INERTIA, **extra) -> RunResult:
    est = Estimate("general", TOOL.mass_kg, TOOL.cog_m)
    return RunResult("sim-ur5e", "run", est, extra={"inertia_com_kgm2": [list(r) for r in inertia], **extra})


# The tests with controllers of their own come before the module's controller (``ur511``) starts: it would
# idle beside them, connected (the simulated UR and ur-rtde's threads: about 0.5 s of CPU a second).

def test_a_readback_that_differs_is_refused_naming_the_likely_cause():
    with FakeURController(time_scale=1.0, keep_payload_inertia=True) as fake:
        d = connected(fake)
        try:
            with pytest.raises(CommunicationError) as err:
                d.write_payload(TOOL)
        finally:
            d.close()
    text = str(err.value)
    assert "set_target_payload ran but the controller reports" in text
    assert "inertia [0.0, 0.0, 0.0" in text and "inertia [0.0041, 0.0052, 0.0023" in text
    assert "Remote Control" in text and "NOT verified" in text


@pytest.mark.parametrize("version", [(5, 10, 0, 0), (5, 9, 4, 0)])
def test_a_version_without_inertia_writes_mass_and_cog_and_says_so(version):
    with FakeURController(time_scale=1.0, controller_version=version) as fake:
        d = connected(fake)
        try:
            reason = d.payload_inertia_support()
            assert f"PolyScope {'.'.join(map(str, version))}" in reason and "5.11" in reason
            lines: list[str] = []
            back = apply_result(d, result_with_inertia(), None, lines.append)
        finally:
            d.close()
    assert back.mass_kg == pytest.approx(1.4) and back.cog_m == pytest.approx(TOOL.cog_m)
    assert back.inertia_com_kgm2 is None  # no RTDE payload_inertia before 5.11
    assert any(line.startswith("Inertia not written: UR controller") for line in lines)


def test_set_target_payload_on_a_controller_before_5_10_does_nothing():
    """ur-rtde strips its script's set_target_payload lines (tagged 5.10) on an older controller, so the
    call succeeds and changes nothing: the reason the driver decides by version and reads back."""
    from test_ur_fake import call, control_interface

    with FakeURController(time_scale=1.0, controller_version=(5, 9, 4, 0)) as fake:
        with control_interface(fake.host) as ctl:
            assert call(ctl, "setTargetPayload", 1.2, [0.0, 0.0, 0.05], [0.01, 0.01, 0.01, 0.0, 0.0, 0.0])
            assert fake.controller_payload[0] == 0.0
            call(ctl, "stopScript")


@pytest.fixture(scope="module")
def ur511():
    with FakeURController(time_scale=1.0) as fake:  # PolyScope 5.11.1: set_target_payload and payload_inertia
        d = connected(fake)
        yield fake, d
        d.close()


def test_set_target_payload_round_trip_with_inertia(ur511):
    fake, d = ur511
    assert d.payload_inertia_support() == ""
    d.write_payload(TOOL)
    got = d.read_payload()
    assert got.mass_kg == pytest.approx(1.4) and got.cog_m == pytest.approx(TOOL.cog_m)
    assert np.asarray(got.inertia_com_kgm2) == pytest.approx(np.asarray(INERTIA), abs=1e-12)
    # the controller holds UR's order [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]: the off-diagonals are not swapped
    assert fake.controller_payload[0] == pytest.approx(1.4)
    assert tensor_to_ur_six(got.inertia_com_kgm2) == pytest.approx([0.0041, 0.0052, 0.0023, -0.0003, 0.0006, 0.0002])


def test_apply_writes_the_identified_inertia_and_reads_it_back(ur511):
    fake, d = ur511
    d.write_payload(PayloadSetting(0.0, (0.0, 0.0, 0.0)))
    lines: list[str] = []
    back = apply_result(d, result_with_inertia(), None, lines.append)
    assert np.asarray(back.inertia_com_kgm2) == pytest.approx(np.asarray(INERTIA), abs=1e-9)
    text = "\n".join(lines)
    assert "Applied and read back" in text and "0.004100, 0.005200, 0.002300" in text
    assert "not written" not in text


def test_apply_leaves_out_an_inertia_the_quality_check_refused(ur511):
    fake, d = ur511
    d.write_payload(TOOL)
    lines: list[str] = []
    result = result_with_inertia(inertia_unsupported={"reason": "σ too large"})
    back = apply_result(d, result, None, lines.append)
    assert back.mass_kg == pytest.approx(1.4)
    assert payload_to_write(result, d)[0].inertia_com_kgm2 is None
    assert "inertia [Ixx" not in lines[-1]


def test_an_impossible_inertia_is_refused_before_anything_is_sent(ur511):
    fake, d = ur511
    bad = ((0.001, 0.0, 0.0), (0.0, -0.002, 0.0), (0.0, 0.0, 0.001))
    with pytest.raises(ValueError, match="not positive semi-definite"):
        d.write_payload(PayloadSetting(1.0, (0.0, 0.0, 0.05), inertia_com_kgm2=bad))
    with pytest.raises(ValueError, match="not symmetric"):
        d.write_payload(PayloadSetting(1.0, (0.0, 0.0, 0.05), inertia_com_kgm2=((1e-3, 1e-4, 0), (0, 1e-3, 0), (0, 0, 1e-3))))


def test_the_simulated_controller_refuses_a_negative_diagonal_as_set_target_payload_does():
    from payload_agent.fakes.ur.urscript import ProgramError, check_target_payload_inertia

    check_target_payload_inertia([0.01, 0.02, 0.0, 0.001, 0.0, 0.0])
    with pytest.raises(ProgramError, match="must not be negative"):
        check_target_payload_inertia([0.01, -0.02, 0.03, 0.0, 0.0, 0.0])
    with pytest.raises(ProgramError, match="133"):
        check_target_payload_inertia([140.0, 1.0, 1.0, 0.0, 0.0, 0.0])


def test_a_driver_without_inertia_says_so_in_one_line():
    from payload_agent.drivers.capabilities import OptionalCapabilities

    class Plain(OptionalCapabilities):
        name = "modbus"

    assert Plain().payload_inertia_support() == "the modbus driver writes mass and centre of gravity only"
    lines: list[str] = []
    with pytest.raises(MotionAbortedError):  # the operator declines: nothing is written
        apply_result(_Declines(), result_with_inertia(), lambda _: "n", lines.append)
    assert "Inertia not written: the modbus driver writes mass and centre of gravity only." in lines


class _Declines:
    def read_payload(self):
        return PayloadSetting(0.0, (0.0, 0.0, 0.0))

    def payload_inertia_support(self):
        return "the modbus driver writes mass and centre of gravity only"

    def write_payload(self, payload):  # pragma: no cover - must not be reached
        raise AssertionError("written although declined")


def test_the_report_sentence_says_what_was_written_with_the_inertia():
    from payload_agent.output.pendant import payload_write_record, write_back_text

    back = PayloadSetting(1.4, (0.018, -0.006, 0.072), inertia_com_kgm2=INERTIA)
    text = write_back_text({"payload_write": payload_write_record(True, True, TOOL, back)})
    assert "1.400 kg at [18.0, -6.0, 72.0] mm, inertia [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] [0.004100, 0.005200" in text
    plain = PayloadSetting(1.4, (0.018, -0.006, 0.072))
    why = "Inertia not written: the modbus driver writes mass and centre of gravity only."
    text = write_back_text({"payload_write": payload_write_record(True, True, plain, plain, note=why)})
    assert "inertia [" not in text and text.endswith(why)
