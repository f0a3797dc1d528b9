"""The CiA 402 power state machine, as the master drives it: every drive to OPERATION ENABLED.

The driver's ``_activate`` (the template calls it before the first move after connect and after any move
that ended abnormally, under the armed supervision; never from ``connect()``, so ``doctor`` and ``plan
--connect`` leave the power stages off). A step at a time, for all drives together, each step confirmed from
the statuswords their TPDOs bring (``DriveMonitor.wait_for``), the supervision polled while waiting. A drive
in FAULT is never reset here (only at connect, with ``driver.clear_faults: true``); one in QUICK STOP ACTIVE
leaves it through SWITCH ON DISABLED, never straight back (docs/sources.md, "CANopen CiA 402").

The canopen library's ``BaseNode402.state = 'OPERATION ENABLED'`` does the same walk for one node but does
not fit: it resets a FAULT on the way (controlword 0x80), takes transition 16 out of QUICK STOP ACTIVE,
sends its controlword through the first RPDO that maps 0x6040 (here the synchronous set-point RPDO, which it
then does not transmit), waits drive after drive within fixed class-level timeouts (0.4 s a step, 0.8 s
in all), and its timeout names no drive.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from payload_agent.drivers.canopen.cia402 import FAULTY, OPERATION_ENABLED, describe_code, enable_step, state_of
from payload_agent.errors import RobotNotReadyError

if TYPE_CHECKING:
    from payload_agent.drivers.canopen.driver import CANopenDriver

MAX_STEPS = 6  # at most 4 transitions from SWITCH ON DISABLED / QUICK STOP ACTIVE


def enable_all(drv: "CANopenDriver") -> None:
    """OPERATION ENABLED on every drive (the mode of operation is set at connect:
    ``device.set_profile_position_mode``); RobotNotReadyError names the drive that cannot get there."""
    m, timeout = drv.monitor, drv.options.enable_timeout_s
    # no power stage is energised on a drive whose SDO server is gone (its error code, its stop confirmation)
    drv.sdo_watch.confirm_alive(drv.check_drives)
    for _ in range(MAX_STEPS):
        states = m.states()
        todo = [j for j, st in enumerate(states) if st != OPERATION_ENABLED]
        if not todo:
            break
        for j in todo:
            if states[j] in FAULTY:
                code = m.last_emcy_code(j)
                raise RobotNotReadyError(f"{drv.labels[j]} is in {states[j]} (error code "
                                         f"{describe_code(code) if code else 'not reported'}); it cannot be enabled")
            if enable_step(states[j]) is None:
                raise RobotNotReadyError(f"{drv.labels[j]} is in {states[j]}: the power state machine has no "
                                         "command out of it; check the drive's power supply")
        drv.check_drives()
        stuck = drv.command_drives({j: enable_step(states[j]) for j in todo},
                                   lambda j, sw: state_of(sw) != states[j], timeout, drv.check_drives)
        if stuck:
            j = stuck[0]
            raise RobotNotReadyError(f"{drv.labels[j]} stayed in {states[j]} for {timeout:g} s after controlword "
                                     f"0x{enable_step(states[j]):04X}")
    else:
        raise RobotNotReadyError("the drives did not reach OPERATION ENABLED: "
                                 + ", ".join(f"{lbl}: {st}" for lbl, st in zip(drv.labels, m.states())))
    m.expect_enabled = [True] * drv.n
