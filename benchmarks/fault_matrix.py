"""Fault matrix: every driver family x every fault its simulated controller can inject, mid-sweep.

Not a test: it prints the matrix and exits non-zero if any cell fails. Run
``.venv/bin/python -m benchmarks.fault_matrix [--drivers elite_ec,ur_rtde] [--faults stall_stream,...]``.
The test suite runs a fast subset (tests/test_fault_matrix.py).

Each cell runs a real session (the runner, the driver, the simulated controller over its real
protocol) and injects the fault through the simulated controllers' common fault interface
once the first sweep is under way. It then asserts all of:

- a stop reached the controller, and how long after the fault (the controller's own log);
- no motion command reached the controller after the fault;
- the samples up to the fault are on disk (the aborted sweep's file holds them);
- the manifest marks the run incomplete with the reason;
- the exit code and message are the documented ones (README: exit codes).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml

from payload_agent.configuration.config import parse_config
from payload_agent.drivers.settings import Supervision
from payload_agent.errors import PayloadAgentError
from payload_agent.recording.rundata import load_manifest
from payload_agent.session.runner import OperatorUI, RunOptions, SimulatedCellUse, run_identification

from benchmarks.sim_start import start_at_first_move

ROOT = Path(__file__).resolve().parents[1]
SIM_CONFIGS = {"elite_ec": "configs/sim-ec66.yaml", "ur_rtde": "configs/sim-ur5e.yaml",
               "modbus": "configs/sim-ur5e-modbus.yaml", "canopen": "configs/sim-canopen-arm.yaml"}
# documented exit codes: 4 motion aborted (stops, timeouts), 6 communication failure
EXPECTED_EXIT = {"drop_connections": 6, "stall_stream": 6, "garbage": 6, "nan_values": 6,
                 "protective_stop": 4, "emergency_stop": 4, "leave_remote": 4, "slow_reply": (4, 6),
                 "no_reply": (4, 6), "never_finish": 4}
MESSAGE = {"drop_connections": ("connection", "closed", "lost", "reach"), "stall_stream": ("stall", "no sample"),
           "garbage": ("stream", "parse", "garbage", "malformed", "frame"), "nan_values": ("finite", "nan"),
           "protective_stop": ("protective", "collision", "stop"),
           "emergency_stop": ("emergency", "e-stop", "emcy"),  # CiA 402 drives see safe torque off as a fault
           "leave_remote": ("remote", "teach", "local", "mode", "operation enabled"), "slow_reply": ("reply", "time", "respond"),
           "no_reply": ("reply", "time", "respond"), "never_finish": ("finish", "within", "time")}
# every controller's late replies come this late (each simulation has its own default; the Modbus one, 0.3 s, is under
# the reply limit, so whether and how a slow Modbus controller showed depended on the host's load)
FAULT_PARAMS = {"slow_reply": {"delay_s": 1.0}}
STOP_DEADLINE_S = 0.5
# a motion that never reports finished shows only after the arm has stood at its target this long
# (Supervision.finish_grace_s): its stop is due within STOP_DEADLINE_S after that
FINISH_GRACE_S = 0.5
TIME_SCALE = 2.0  # sweeps last long enough (1.5 s wall) to fault in the middle of one, gap limit included
# the watchdog's stream-gap limit for these runs. The simulated controllers share the agent's process and a busy
# host (both cores loaded) pauses their stream for a few hundred ms: with 200 ms the loaded matrix tripped on gaps
# of its own making before or instead of the injected fault. A stalled stream is found after this limit by
# definition; the stop is then due within STOP_DEADLINE_S, like every other trip.
GAP_LIMIT_MS = 500


@dataclasses.dataclass
class Cell:
    driver: str
    fault: str
    passed: bool = False
    applicable: bool = True  # False: this controller (with this config) cannot produce the fault
    stop_s: float | None = None
    exit_code: int | None = None
    problems: list[str] = dataclasses.field(default_factory=list)
    message: str = ""
    retried: list[str] = dataclasses.field(default_factory=list)  # attempts the host's load tripped before the fault


def load_sim_config(driver: str, storage: Path, at_first_move: bool = False, strict_heartbeat: bool = True):
    """The driver family's sim config for a cell: ephemeral ports, the matrix's time scale and gap limit;
    ``at_first_move``: the arm starts where the plan's approach goes (benchmarks.sim_start);
    ``strict_heartbeat=False`` keeps the sim config's allowance for a loaded host on the CANopen drives' watch of
    the agent's heartbeat (for tests whose subject is not that watch)."""
    data = yaml.safe_load((ROOT / SIM_CONFIGS[driver]).read_text())
    data["simulation"]["time_scale"] = min(float(data["simulation"]["time_scale"]), TIME_SCALE)
    data["safety"]["max_stream_gap_ms"] = GAP_LIMIT_MS
    # CANopen drives cut off from the agent stop themselves after their consumer time of its heartbeat: the
    # matrix uses the driver's real default (150 ms), not the sim config's allowance for a loaded host
    if strict_heartbeat:
        data["driver"].pop("master_heartbeat_timeout_ms", None)
    data["storage"] = {"runs_dir": str(storage / "runs"), "state_dir": str(storage / "state")}
    for key in ("rpc_port", "monitor_port", "port"):  # ephemeral ports: cells never collide with other sims
        if key in data["driver"] and data["driver"].get("transport", "tcp") == "tcp":
            data["driver"][key] = 0
    data.pop("watch", None)
    if at_first_move:
        data = start_at_first_move(data, base_dir=ROOT / "configs")
    return parse_config(data, source=SIM_CONFIGS[driver], base_dir=ROOT / "configs")


def stop_limit_s(fault: str) -> float:
    """How long after the injection the stop must reach the controller: STOP_DEADLINE_S after the fault can
    be seen (a stalled stream after the gap limit, a silent controller after the reply limit, which follows the
    gap limit (session.connection.supervision), a never-finished move after the finish grace)."""
    gap = GAP_LIMIT_MS / 1000
    reply = max(gap, Supervision.max_reply_wait_s)
    return STOP_DEADLINE_S + {"never_finish": FINISH_GRACE_S, "stall_stream": gap, "slow_reply": reply,
                              "no_reply": reply}.get(fault, 0.0)


def run_cell(driver: str, fault: str, storage: Path) -> Cell:
    cell = Cell(driver, fault)
    config = load_sim_config(driver, storage, at_first_move=True)  # the fault mid-sweep is the subject
    seen: dict = {}

    def inject_mid_sweep(sim_cell) -> None:
        ctrl = sim_cell.controller
        seen["ctrl"] = ctrl
        if fault not in ctrl.faults:
            return

        def watch() -> None:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                if _sweep_recording(config.storage.runs_dir) and ctrl.robot.snapshot().moving:
                    time.sleep(0.1)
                    seen["fault_t"] = time.monotonic()
                    ctrl.inject_fault(fault, **FAULT_PARAMS.get(fault, {}))
                    if fault == "never_finish":  # the fault shows only once the arm has arrived
                        while ctrl.robot.snapshot().moving and time.monotonic() < deadline:
                            time.sleep(0.002)
                        seen["fault_t"] = time.monotonic()
                    return
                time.sleep(0.005)
        threading.Thread(target=watch, daemon=True, name="fault-injector").start()

    lines: list[str] = []
    try:
        run_identification(config, RunOptions(assume_yes=True, report=False),
                                   OperatorUI(progress=False, out=lines.append),
                                   SimulatedCellUse(on_cell=inject_mid_sweep))
        cell.problems.append("the run finished although the fault was injected")
    except PayloadAgentError as exc:
        cell.exit_code, cell.message = exc.exit_code, str(exc)
    except Exception as exc:  # noqa: BLE001 - an unexpected exception is itself a failed cell
        cell.exit_code, cell.message = 1, f"{type(exc).__name__}: {exc}"
    ctrl = seen.get("ctrl")
    if ctrl is None:
        cell.problems.append("the simulated controller never started")
        return cell
    if fault not in ctrl.faults:  # e.g. NaN on a map of integer registers: no value can carry it
        cell.applicable = False
        return cell
    fault_t = seen.get("fault_t")
    if fault_t is None:
        cell.problems.append("the fault was never injected (no sweep started)")
        return cell
    stop = ctrl.first_event_after("stop", fault_t)
    if stop is None:
        cell.problems.append("no stop reached the controller")
    else:
        cell.stop_s = stop.t - fault_t
        limit = stop_limit_s(fault)
        withheld = ctrl.first_event_after("withheld", fault_t)
        if withheld is not None:  # asked only now and then (CANopen's SDO liveness): the limit runs from the ask
            limit += withheld.t - fault_t
        if cell.stop_s > limit:
            cell.problems.append(f"stop after {cell.stop_s:.3f} s (limit {limit} s)")
    late = [e for e in ctrl.events if e.kind == "move" and e.t > fault_t]
    if late:
        cell.problems.append(f"{len(late)} motion command(s) after the fault")
    expected = EXPECTED_EXIT[fault]
    if cell.exit_code not in (expected if isinstance(expected, tuple) else (expected,)):
        cell.problems.append(f"exit code {cell.exit_code}, expected {expected}")
    if not any(w in cell.message.lower() for w in MESSAGE[fault]):
        cell.problems.append(f"message does not say what happened: {cell.message[:120]!r}")
    cell.problems += _check_run_folder(storage / "runs")
    cell.passed = not cell.problems
    return cell


def run_cell_untripped(driver: str, fault: str, attempts: int = 3) -> Cell:
    """A cell, run again (up to ``attempts``) when the session stopped before the fault could be injected or show:
    the in-process simulation paused past the gap or reply limit on a loaded host and the supervision stopped the
    arm (exit 6, where the fault is a motion fault with exit 4), which tests the supervision but not this fault.
    Every such attempt is listed in the cell (``retried``)."""
    retried: list[str] = []
    for _ in range(attempts):
        with tempfile.TemporaryDirectory(prefix="fault-matrix-") as tmp:
            cell = run_cell(driver, fault, Path(tmp))
        expected = EXPECTED_EXIT[fault]
        tripped_early = cell.exit_code == 6 and (
            any("never injected" in p for p in cell.problems)  # before the fault was injected
            or (6 not in (expected if isinstance(expected, tuple) else (expected,))  # a motion fault, not a
                and "motion stopped by the supervision" in cell.message))  # communication one: before it showed
        if not tripped_early:
            break
        retried.append(cell.message[:160])
    cell.retried = retried
    return cell


def _sweep_recording(runs: Path) -> bool:
    """Whether the run folder's manifest shows a sweep being recorded (samples going to its file now)."""
    for manifest in runs.glob("*/manifest.json") if runs.exists() else []:
        try:
            phases = json.loads(manifest.read_text()).get("phases", {})
        except (OSError, ValueError):
            continue
        if any(s.get("status") == "recording" for ph in phases.values() for s in ph.get("sweeps", [])):
            return True
    return False


def _check_run_folder(runs: Path) -> list[str]:
    dirs = sorted(runs.iterdir()) if runs.exists() else []
    if not dirs:
        return ["no run folder was kept"]
    manifest = load_manifest(dirs[-1])
    problems = []
    if manifest.get("status") != "incomplete" or not manifest.get("stopped_because"):
        problems.append(f"manifest status {manifest.get('status')!r} without the reason")
    sweeps = [s for ph in manifest.get("phases", {}).values() for s in ph.get("sweeps", [])]
    if not sweeps or sweeps[-1].get("status") == "complete":
        problems.append("no aborted sweep in the manifest")
    else:
        last = sweeps[-1]
        rows = (dirs[-1] / last["file"]).read_text().count("\n") - 1
        if last.get("samples", 0) <= 0 or rows != last["samples"]:
            problems.append(f"aborted sweep: {rows} rows on disk, manifest says {last.get('samples')}")
    return problems


def available_drivers() -> list[str]:
    return [d for d, path in SIM_CONFIGS.items() if (ROOT / path).exists()]


def faults_of(driver: str) -> list[str]:
    from payload_agent.drivers.registry import simulator_class

    from payload_agent.fakes.base import FAULTS

    return [f for f in FAULTS if f in simulator_class(driver).faults]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--drivers", help="comma-separated driver names (default: every driver with a sim config)")
    p.add_argument("--faults", help="comma-separated fault names (default: every fault each controller supports)")
    args = p.parse_args(argv)
    drivers = args.drivers.split(",") if args.drivers else available_drivers()
    cells: list[Cell] = []
    for driver in drivers:
        faults = args.faults.split(",") if args.faults else faults_of(driver)
        for fault in faults:
            c = run_cell_untripped(driver, fault)
            cells.append(c)
            print(f"  {driver:9s} {fault:17s} {'n/a ' if not c.applicable else 'pass' if c.passed else 'FAIL'}"
                  + (f"  stop {1000 * c.stop_s:.0f} ms" if c.stop_s is not None else "")
                  + ("" if c.passed or not c.applicable else f"  {'; '.join(c.problems)}")
                  + "".join(f"\n      (an earlier attempt tripped before the fault: {r})" for r in c.retried),
                  flush=True)
    print_matrix(cells)
    retried = sum(len(c.retried) for c in cells)
    if retried:
        print(f"{retried} attempt(s) tripped on the host's own pauses before the fault was injected and were run again")
    return 0 if cells and all(c.passed or not c.applicable for c in cells) else 1


def print_matrix(cells: list[Cell]) -> None:
    drivers = list(dict.fromkeys(c.driver for c in cells))
    faults = list(dict.fromkeys(c.fault for c in cells))
    by = {(c.driver, c.fault): c for c in cells}
    print("\n| fault | " + " | ".join(drivers) + " |")
    print("|---" * (len(drivers) + 1) + "|")
    for f in faults:
        row = []
        for d in drivers:
            c = by.get((d, f))
            if c is None or not c.applicable:
                row.append("n/a")
            else:
                stop = f" {1000 * c.stop_s:.0f} ms" if c.stop_s is not None else ""
                row.append(("pass" if c.passed else "FAIL") + stop)
        print(f"| {f} | " + " | ".join(row) + " |")
    failed = [c for c in cells if c.applicable and not c.passed]
    na = sum(not c.applicable for c in cells)
    print(f"\n{len(cells) - len(failed) - na} passed, {len(failed)} failed" + (f" ({na} not applicable)" if na else ""))


if __name__ == "__main__":
    sys.exit(main())
