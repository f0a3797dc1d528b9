"""What a driver may offer beyond moving and streaming: the flange pose, the payload setting, digital
inputs, a tool-change trigger, joint temperatures, the controller's target current and moment
(``records_controller_targets``). The defaults say "not offered"; ``capabilities()``
lists what a driver overrides, so a session that needs one is refused before its first move."""

from __future__ import annotations

from typing import ClassVar

from payload_agent.errors import UnsupportedCapability
from payload_agent.types import FlangePose, PayloadSetting


class OptionalCapabilities:
    """The optional part of the driver contract (mixed into ``Driver``)."""

    name: ClassVar[str] = ""
    # records, with every sample, the controller's own target current and target moment (UR RTDE), from which a run
    # without a drive-gain calibration fits the controller's torque constants (``evaluation.controller_gains``);
    # a class attribute, known before connecting, so ``plan --target-std`` predicts the σ those constants bring
    records_controller_targets: ClassVar[bool] = False

    def flange_pose(self) -> FlangePose | None:
        """The flange pose the controller reports (TCP offset removed), or None if it has none."""
        return None

    OPTIONAL_CAPABILITIES: ClassVar[tuple[str, ...]] = ("read_payload", "write_payload", "read_digital_input",
                                                        "read_trigger")

    def capabilities(self) -> frozenset[str]:
        """The optional capabilities this driver offers with these options, known before connecting, so a
        session that needs one (``--apply``, a watch trigger) is refused before its first move. A driver
        whose options decide (a register map) narrows this; the default is the methods it implements."""
        return frozenset(n for n in self.OPTIONAL_CAPABILITIES
                         if getattr(type(self), n) is not getattr(OptionalCapabilities, n))

    def read_payload(self) -> PayloadSetting:
        raise UnsupportedCapability(f"driver {self.name!r} cannot read the payload setting")

    def write_payload(self, payload: PayloadSetting) -> None:
        raise UnsupportedCapability(f"driver {self.name!r} cannot write the payload setting")

    def payload_inertia_support(self) -> str:
        """"" when ``write_payload`` writes ``PayloadSetting.inertia_com_kgm2`` too (known once connected),
        else why it writes mass and centre of gravity only (a sentence for the run's output)."""
        return f"the {self.name} driver writes mass and centre of gravity only"

    def read_digital_input(self, index: int) -> bool:
        """State of the controller's general-purpose digital input ``index`` (for `watch`)."""
        raise UnsupportedCapability(f"driver {self.name!r} cannot read digital inputs")

    def read_trigger(self) -> int:
        """The controller's tool-change trigger register, for `watch`: 0 none; non-zero a tool change
        happened (and, where the cell's PLC writes it so, the new tool's number)."""
        raise UnsupportedCapability(f"driver {self.name!r} has no trigger register")

    def joint_temperatures_c(self) -> tuple[float, ...] | None:
        """Per-joint temperatures in °C as the controller reports them, or None if it does not."""
        return None
