"""The configuration a recorded run is analysed with: the run folder's own, and nothing else.

``payload-agent solve`` and ``report`` need only the parts of the robot YAML that the
analysis uses: the robot's name and DH kinematics, the effort unit and gains (the manifest's
``effort_unit`` / ``gains_nm_per_unit`` take precedence), and optionally ``procedure.solver``.
The driver section is not parsed (a run recorded with a driver whose client library is not
installed here can still be analysed), and no state folder is consulted: the analysis of a
run folder depends on the run folder alone (docs/run-format.md, "What solve reads").
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Mapping

from payload_agent.configuration.config import (DEFAULT_BASELINE_MAX_AGE_DAYS, DEFAULT_BASELINE_MAX_TEMPERATURE_DELTA_C,
                                                EFFORT_UNITS, KINEMATICS_KEYS, N_JOINTS, Config, EffortConfig,
                                                ProcedureConfig, RobotConfig, StorageConfig, parse_kinematics)
from payload_agent.configuration.yamlcheck import Node, check_number
from payload_agent.errors import ConfigError, DataError

SOLVERS = ("general", "three-step")
# a state folder that never exists: nothing from the current directory or the user's state leaks in
NO_STATE = Path(os.devnull) / "payload-agent-no-state"


def recorded_effort(manifest: Mapping[str, Any], snapshot: Mapping[str, Any], source: str) -> EffortConfig:
    """The effort unit and N·m gains the run's CSVs were recorded with.

    The manifest's ``effort_unit`` and ``gains_nm_per_unit`` describe the CSV columns and win;
    the config snapshot's ``effort`` section is the fallback. ``Nm`` needs no gains.
    """
    snap = snapshot.get("effort") if isinstance(snapshot.get("effort"), Mapping) else {}
    unit = manifest.get("effort_unit", snap.get("unit"))
    if unit not in EFFORT_UNITS:
        raise DataError(f"{source}: effort_unit is {unit!r}; expected one of {', '.join(EFFORT_UNITS)}")
    gains = manifest.get("gains_nm_per_unit")
    where = "gains_nm_per_unit"
    if gains is None and snap.get("unit") == unit:
        gains, where = snap.get("gains_nm_per_unit"), "config.effort.gains_nm_per_unit"
    if gains is None:
        if unit != "Nm":
            raise DataError(f"{source}: gains_nm_per_unit is missing: the effort columns are in {unit!r} and "
                            "nothing says how many N·m one unit is")
        gains = [1.0] * N_JOINTS
    if isinstance(gains, (int, float)) and not isinstance(gains, bool):
        gains = [gains] * N_JOINTS
    if not isinstance(gains, list) or len(gains) != N_JOINTS:
        raise DataError(f"{source}: {where} must be a list of {N_JOINTS} numbers, got {gains!r:.60}")
    try:
        values = tuple(check_number(g, f"{where}[{i}]", gt=0, source=source) for i, g in enumerate(gains))
    except ConfigError as exc:
        raise DataError(str(exc)) from None
    return EffortConfig(str(unit), values)


def parse_recorded_config(snapshot: Any, manifest: Mapping[str, Any], source: str) -> Config:
    """A Config fit for analysing a run (not for moving a robot): see the module docstring."""
    top = Node(snapshot, "config", source)
    robot_node = top.child("robot")
    name = robot_node.string("name")
    model = robot_node.string("model", "") if robot_node.has("model") else ""
    rows, length_std_mm, joints = parse_kinematics(robot_node.child("kinematics", keys=KINEMATICS_KEYS), robot_node)
    robot = RobotConfig(name, model, rows, ((-2 * math.pi, 2 * math.pi),) * N_JOINTS, math.inf, math.inf,
                        length_std_mm / 1000.0, joints)
    effort = recorded_effort(manifest, snapshot, source)
    proc = snapshot.get("procedure") if isinstance(snapshot.get("procedure"), Mapping) else {}
    solver = proc.get("solver", "general")
    if solver not in SOLVERS:
        raise ConfigError("config.procedure.solver", f"must be one of {', '.join(SOLVERS)}, got {solver!r}", source)
    procedure = ProcedureConfig(str(proc.get("name", manifest.get("procedure", "?"))), math.nan, math.nan, math.nan,
                                math.nan, math.nan, math.nan, bool(proc.get("bidirectional", False)), solver)
    storage = StorageConfig(NO_STATE / "runs", NO_STATE, DEFAULT_BASELINE_MAX_AGE_DAYS,
                            DEFAULT_BASELINE_MAX_TEMPERATURE_DELTA_C)
    driver = snapshot.get("driver") if isinstance(snapshot.get("driver"), Mapping) else {}
    return Config(source, robot, effort, dict(driver), procedure, None, storage, None,  # type: ignore[arg-type]
                  raw=snapshot)
