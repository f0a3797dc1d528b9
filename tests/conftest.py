import copy
import math
import os
import tempfile
from pathlib import Path

# One BLAS thread per process: `make test`'s workers already fill two cores, and OpenBLAS's own threads (one
# per core by default, spinning while they wait) only compete with them and with the simulated controllers'
# clocks. Measured on the numeric files (test_systematics, test_stream_gaps, test_segmentation_speeds), load
# 4-6: 14.6-15.4 s of CPU with the default, 11.6 s with one thread. Set before numpy loads OpenBLAS here, in
# the xdist workers and in the CLI subprocesses (they inherit it); a value already set is kept.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import sys

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]

# Compiled bytecode kept for the suite's processes: with PYTHONDONTWRITEBYTECODE set (as the shells on this
# project's machines have it) every process compiles the project's modules from source (the installed packages
# come compiled), and the suite starts about a hundred (simulated controllers, UR children, CLI runs) besides its
# three workers, each of which also rewrites and compiles every test file it collects. So the workers (from their
# next import on) and every subprocess (they inherit the environment) write and read bytecode as Python does by
# default: __pycache__ beside the sources (git-ignored), checked against each source's mtime and size.
if os.environ.pop("PYTHONDONTWRITEBYTECODE", None):
    sys.dont_write_bytecode = False

# State follows the robot into $XDG_STATE_HOME (payload_agent.configuration.paths): the suite gets its
# own, so it never reads or writes the user's baselines, calibrations or history (subprocesses inherit it).
_XDG = Path(tempfile.mkdtemp(prefix="payload-agent-tests-"))
os.environ["XDG_STATE_HOME"] = str(_XDG / "state")
os.environ["XDG_CONFIG_HOME"] = str(_XDG / "config")
os.environ.pop("PAYLOAD_AGENT_ROBOTS", None)

from benchmarks.sim_start import start_at_first_move  # noqa: E402 (tests import it from here)


@pytest.fixture
def stall_probe():
    """Measures how long the host stalls this process (host_stall.py): the safety tests' stop deadlines excuse it."""
    from host_stall import StallProbe

    probe = StallProbe().start()
    yield probe
    probe.close()


@pytest.fixture(scope="session")
def chromium():
    """One headless Chromium for the report's screenshot tests in this process (tests/headless_chromium.py),
    started when a test first asks. Without it those tests skip, except where a browser is required (.ci/run
    sets PAYLOAD_AGENT_REQUIRE_BROWSER=1 after installing it): there a missing browser fails."""
    from headless_chromium import HeadlessChromium, chromium_path

    path = chromium_path()
    if path is None:
        if os.environ.get("PAYLOAD_AGENT_REQUIRE_BROWSER"):
            pytest.fail("Chromium is required (PAYLOAD_AGENT_REQUIRE_BROWSER is set) but not installed: "
                        ".ci/run could not install the Debian package 'chromium' (apt unreachable?)")
        pytest.skip("Chromium is not installed (apt-get install chromium); .ci/run installs it")
    browser = HeadlessChromium(path)
    yield browser
    browser.close()


@pytest.fixture
def sim_ec66_data():
    """The simulated EC66 config as a dict, to be tweaked per test; without the inertia part (its wrist moves
    double a session's moves: tests/test_wrist_*.py turn it on)."""
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data["procedure"]["inertia"] = False
    return data


@pytest.fixture
def ec66_data():
    return yaml.safe_load((ROOT / "configs" / "ec66.yaml").read_text())


def tweak(data, path, value):
    """Return a deep copy with ``path`` ("a.b[2].c") set to value; value=DELETE removes the key."""
    data = copy.deepcopy(data)
    node = data
    parts = path.replace("]", "").replace("[", ".").split(".")
    for p in parts[:-1]:
        node = node[int(p)] if isinstance(node, list) else node[p]
    last = parts[-1]
    if value is DELETE:
        del node[last]
    elif isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return data


DELETE = object()


def fast_start(data):
    """A copy of a simulated robot's YAML dict for a test whose subject is not the approach: the arm starts at
    the plan's first move (benchmarks/sim_start.py), and the first move of each phase (the loaded run's, from
    where the empty run ended: 12-25 s at the shipped 5 % on the EC66) runs at 15 %, still below the travel
    speed (20 %) so that the two stay told apart."""
    return start_at_first_move(tweak(data, "safety.approach_speed_percent", 15))


def short_session(data):
    """``fast_start`` with procedures/j2_pair.yaml, for a test whose subject is neither the procedure nor the
    approach: two joint-2 sweeps a phase instead of paper_bd's four sweeps and three travel moves (23 s of
    simulated motion a phase instead of 43 s on the EC66).

    j2_pair was chosen for 2 g / 1 mm (1σ) on the EC66 simulator (docs/benchmarks.md), so the sessions' 30 g /
    5 mm assertions keep their meaning; its two orientations still give the quality gate two poses to compare.
    The three-step solver needs paper_bd's sweeps: a test that solves with it takes ``fast_start``.
    """
    return fast_start(tweak(data, "procedure.name", "j2_pair"))


def cell_program_turns_joint_1(cell, degrees: float = 2.0) -> None:
    """The simulated cell's own program (not the agent) turns joint 1 by ``degrees`` and leaves the arm there;
    returns once it stands at the new angle (or after 30 s), for tests of what a session does when someone else
    moved the arm."""
    import time

    import numpy as np

    q = np.asarray(cell.robot.snapshot().q, float)
    cell.robot.move_joints(q + np.radians([degrees, 0, 0, 0, 0, 0]), 0.2, 1.0)
    deadline = time.monotonic() + 30
    while (cell.robot.snapshot().moving or not math.isclose(cell.robot.snapshot().q[0], q[0] + math.radians(degrees),
                                                             abs_tol=1e-3)) and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)


EC66_Q0 = [0.0, -math.pi / 2, math.pi / 2, 0.0, math.pi / 2, 0.0]  # the fakes' tests start the EC66 here
EC66_TIME_SCALE = 40.0


@pytest.fixture
def ec66_sim():
    """A running simulated EC66 (no payload) at EC66_Q0, 40x faster than wall time; closed afterwards."""
    from payload_agent.fakes.arms import ec66_spec
    from payload_agent.fakes.sim_robot import SimRobot

    robot = SimRobot(ec66_spec(), q0_rad=EC66_Q0, tick_s=0.008, time_scale=EC66_TIME_SCALE)
    robot.start()
    yield robot
    robot.close()


# The slowest files first (worker seconds per file, from --durations / junit times; README.md): with
# `--dist loadfile` a worker takes the next file while its last two tests still run, so a long file collected
# late leaves the other worker idle at the end. xdist would order files by their number of tests (which puts
# the few-but-long session files last); `make test` passes --no-loadscope-reorder so this order stands.
# Every file over 10 s of worker time, slowest first (a `make test`-like run with per-test times, 2026-11-28, session
# 21, at load 9-17 beside other helpers' benchmarks: driver_conformance 137 s, cli_session 120 (92 after its two
# calibrate tests were cut), ur_driver 69, cable_spring 67, workflow 66, plan_target 58, shared_baseline 58, ...
# decoders_modbus 10; the files left, alphabetical, are under 10 s). The two workers then ended 2 s apart; three
# (session 22, the same order, load 7-13) ended within 1 s of each other.
SLOWEST_FIRST = ("test_driver_conformance.py", "test_cli_session.py", "test_ur_driver.py", "test_cable_spring.py",
                 "test_workflow.py", "test_plan_target.py", "test_shared_baseline.py", "test_report_inertia.py",
                 "test_length_response.py", "test_modbus_rtu.py", "test_noise_scatter.py", "test_report.py",
                 "test_three_step_scatter.py", "test_calibration_shares.py", "test_friction_split.py",
                 "test_plan_quarter.py", "test_run_format.py", "test_calibration_zeros.py", "test_verify.py",
                 "test_ur_end_to_end.py", "test_calibration.py", "test_minimal_driver.py",
                 "test_segmentation_speeds.py", "test_session_collision.py", "test_canopen_driver.py",
                 "test_reference_friction.py", "test_opcua_server.py", "test_physics_config_and_remedies.py",
                 "test_quality.py", "test_planned_terms.py", "test_architecture.py", "test_stored_candidate.py",
                 "test_systematics.py", "test_end_to_end.py", "test_durability.py", "test_analysis_core.py",
                 "test_empty_run_check.py", "test_ur_script_restart.py", "test_ur_payload_inertia.py",
                 "test_ur_fake.py", "test_elite_fake.py", "test_physics_design.py", "test_api.py",
                 "test_canopen_end_to_end.py", "test_plan_loop.py", "test_elite_driver.py", "test_modbus_driver.py",
                 "test_three_step_noise.py", "test_target_advice.py", "test_bidirectional.py",
                 "test_decoders_modbus.py")


def pytest_collection_modifyitems(session, config, items):
    """Files in SLOWEST_FIRST order, then the rest as collected; each file's tests keep their own order."""
    rank = {name: i for i, name in enumerate(SLOWEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
