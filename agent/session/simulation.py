"""Starts the simulated controller a sim-*.yaml asks for, in-process, on loopback.

The agent then talks to it exactly as to a real controller, through the driver and
the real protocol. Tool changes between the empty and the loaded run happen here.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from payload_agent.configuration.config import Config, SimulationConfig
from payload_agent.errors import ConfigError


class SimulatedCell:
    """A fake controller + simulated robot built from ``config.simulation``."""

    def __init__(self, config: Config, start_q: np.ndarray | None = None):
        from payload_agent.fakes.arms import SPECS
        from payload_agent.fakes.physics import FrictionParams, PayloadTruth
        from payload_agent.fakes.sim_robot import SimRobot

        sim: SimulationConfig = config.simulation
        if sim is None:
            raise ConfigError("simulation", "this config has no simulation section")
        self.sim = sim
        self.config = config
        spec = SPECS[sim.arm]()
        self.truth = PayloadTruth.point(sim.payload.mass_kg, sim.payload.cog_mm)
        self.friction = FrictionParams(np.array(sim.coulomb_nm), np.array(sim.viscous_nm_s_rad),
                                       np.array(sim.load_ratio))
        q0 = np.radians(sim.start_deg) if start_q is None else np.asarray(start_q, float)
        kind = config.driver_type
        tick = {"elite_ec": 0.008, "ur_rtde": 0.002}.get(kind)
        if tick is None:
            raise ConfigError("driver.type", f"no simulated controller for driver {kind!r}")
        self.options: dict[str, Any] = dict(config.driver)
        if kind == "elite_ec":
            from payload_agent.fakes.elite_ec import FakeEliteController

            self.robot = SimRobot(spec, q0_rad=q0, tick_s=tick, time_scale=sim.time_scale, friction=self.friction,
                                  noise_nm=np.array(sim.noise_nm), seed=sim.seed, payload=None)
            self.controller = FakeEliteController(
                self.robot, host=str(self.options.get("host", "127.0.0.1")),
                rpc_port=int(self.options.get("rpc_port", 8055)),
                monitor_port=int(self.options.get("monitor_port", 8056)),
                rated_torque_nm=spec.rated_torque_nm, gain_error=sim.drive_gain_error)
        else:
            # ur_rtde's constructors hold the GIL while waiting for replies: the fake UR runs in a
            # child process and .robot forwards the SimRobot calls (set_payload, set_friction_scale,
            # snapshot, ...) to it. The drives report current = torque / gain with the config's
            # own gains (times drive_gain_error), so the config describes the simulated robot
            # exactly; sensor noise is simulation.noise_nm on the torque (no extra current noise).
            from payload_agent.fakes.ur_controller import FakeURController

            if config.effort.unit != "A":
                raise ConfigError("effort.unit", f"the simulated UR controller reports motor current in A, "
                                  f"not {config.effort.unit!r}")
            host = self.options.get("host")
            self.controller = FakeURController(
                host=None if host in (None, "", "auto") else str(host), spec=spec, q0_rad=tuple(q0), tick_s=tick,
                time_scale=sim.time_scale, friction=self.friction, noise_nm=tuple(sim.noise_nm),
                seed=sim.seed, payload=None, gain_error=tuple(sim.drive_gain_error),
                gains_nm_per_a=tuple(config.effort.gains_nm_per_unit), current_noise_a=0.0)
            self.robot = self.controller.robot

    def start(self) -> "SimulatedCell":
        self.robot.start()
        self.controller.start()
        if self.config.driver_type == "elite_ec":  # ports may have been 0 (ephemeral)
            self.options["rpc_port"] = self.controller.rpc_port
            self.options["monitor_port"] = self.controller.monitor_port
        else:  # the fake may have picked a free 127.0.0.x itself ("auto")
            self.options["host"] = self.controller.host
        return self

    def close(self) -> None:
        for part in (self.controller, self.robot):
            try:
                part.close()
            except Exception:
                pass

    def change_tool(self, mass_kg: float, cog_mm: tuple[float, float, float]) -> None:
        """Swap the simulated tool for another (the truth of the next loaded run); used by tests and demos."""
        from payload_agent.fakes.physics import PayloadTruth

        self.truth = PayloadTruth.point(mass_kg, cog_mm)

    def mount_tool(self, mounted: bool) -> None:
        """The simulated tool change; friction drifts by ``friction.drift`` between the runs."""
        self.robot.set_payload(self.truth if mounted else None)
        self.robot.set_friction_scale(1.0 + (self.sim.friction_drift if mounted else 0.0))

    @property
    def truth_json(self) -> dict[str, Any]:
        return {"mass_kg": self.truth.mass_kg, "cog_mm": [1000 * v for v in self.truth.cog_m]}
