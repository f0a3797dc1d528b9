"""Starts the simulated controller a sim-*.yaml asks for, in-process, on loopback.

The driver registry names each driver's simulated controller (``Driver.simulator``); the
cell builds it from the robot YAML, starts it and points the driver options at it. The
agent then talks to it exactly as to a real controller, through the driver and the real
protocol. Tool changes between the empty and the loaded run happen here.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from payload_agent.configuration.config import Config
from payload_agent.drivers.base import DriverOptions
from payload_agent.drivers.registry import simulator_class
from payload_agent.errors import CommunicationError, ConfigError


class SimulatedCell:
    """A simulated controller (any protocol) built from ``config.simulation``."""

    def __init__(self, config: Config):
        if config.simulation is None:
            raise ConfigError("simulation", "this config has no simulation section")
        from payload_agent.fakes.arms import SPECS

        if config.simulation.arm not in SPECS:
            raise ConfigError("simulation.arm", f"unknown simulated arm {config.simulation.arm!r}; "
                                                f"known: {', '.join(sorted(SPECS))}", config.source)
        config = dataclasses.replace(config, simulation=dataclasses.replace(config.simulation,
                                                                            session=count_session(config)))
        self.config = config
        self.sim = config.simulation
        try:  # the simulated controller binds its ports as it is made
            self.controller = simulator_class(config.driver_type).from_config(config)
        except OSError as exc:
            raise _cannot_listen(config, exc) from None
        self.truth_mass_kg = self.sim.payload.mass_kg
        self.truth_cog_mm = tuple(self.sim.payload.cog_mm)
        self.truth_inertia_com = self.sim.payload.inertia_com_kgm2
        self.options: DriverOptions = config.driver_options

    def start(self) -> "SimulatedCell":
        try:
            self.controller.start()
        except OSError as exc:
            self.close()
            raise _cannot_listen(self.config, exc) from None
        self.options = self.controller.bound_options(self.config.driver_options)
        return self

    def close(self) -> None:
        try:
            self.controller.close()
        except Exception:
            pass

    @property
    def robot(self) -> Any:
        return self.controller.robot

    def change_tool(self, mass_kg: float, cog_mm: tuple[float, float, float]) -> None:
        """Swap the simulated tool for another (the truth of the next loaded run); used by tests and demos."""
        self.truth_mass_kg, self.truth_cog_mm = float(mass_kg), tuple(float(c) for c in cog_mm)
        self.truth_inertia_com = None

    def mount_tool(self, mounted: bool) -> None:
        """The simulated tool change; friction drifts by ``friction.drift`` between the runs."""
        from payload_agent.fakes.physics import PayloadTruth

        if self.truth_inertia_com is not None:
            truth = PayloadTruth.from_tensor(self.truth_mass_kg, [c / 1000.0 for c in self.truth_cog_mm],
                                             self.truth_inertia_com)
        else:
            truth = PayloadTruth.point(self.truth_mass_kg, self.truth_cog_mm)
        self.controller.set_payload(truth if mounted else None)
        self.controller.set_friction_scale(1.0 + (self.sim.friction_drift if mounted else 0.0))

    @property
    def truth_json(self) -> dict[str, Any]:
        truth: dict[str, Any] = {"mass_kg": self.truth_mass_kg, "cog_mm": list(self.truth_cog_mm)}
        if self.truth_inertia_com is not None:
            truth["inertia_com_kgm2"] = [list(row) for row in self.truth_inertia_com]
        return truth


def count_session(config: Config) -> int:
    """This session's number for the simulated robot, counted in the robot's state folder (0 the first time).

    A seeded simulation draws the same noise each time it starts; a calibration, a stored baseline and the run
    after them would then share their noise draws, which no real drive does, and their errors would cancel in the
    subtraction (session 19: the online CoM errors after ``calibrate`` were less than half the offline ones). Each
    session gets its own noise on the same arm (``SimRobot(session=...)``). A state folder that cannot be
    written counts nothing: 0, the seed's own noise.
    """
    from payload_agent.recording.state import RobotState

    path = RobotState.for_config(config).simulated_sessions_path
    try:
        done = int(path.read_text().strip() or 0) if path.exists() else 0
    except (OSError, ValueError):
        done = 0
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(f"{done + 1}\n")
    except OSError:
        return 0
    return done


def _cannot_listen(config: Config, exc: OSError) -> CommunicationError:
    return CommunicationError(f"the simulated {config.driver_type} controller could not listen: {exc}. "
                              "Another simulation may be using the address; stop it or set a free "
                              "driver.host / ports in the YAML.")
