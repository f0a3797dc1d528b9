"""The faults the simulated UR controller can inject (names from ``fakes.base.FAULTS``).

What each one does here:

- ``drop_connections``: every open client connection (RTDE, dashboard, script ports) is shut
  down at once; the ports keep listening, as after a network blip. The running program (and
  its move) goes on, as ur_rtde's control script does when its client vanishes.
- ``stall_stream``: the RTDE sample stream sessions send nothing; the control interface's
  session (the command channel) and the dashboard keep working. Cleared: the stream resumes.
- ``garbage``: sample stream sessions send data packages whose content is random bytes
  (``mode="payload"``, default) or bytes that are not RTDE at all (``mode="framing"``).
- ``nan_values``: joint angles, speeds and currents are NaN in every package.
- ``protective_stop`` / ``emergency_stop``: as the safety system does (motion stops, the
  program is stopped; the e-stop powers the arm off). Cleared: the stops are reset.
- ``leave_remote``: the pendant takes control (Local mode); the running program is stopped
  (assumption, UNVERIFIED: PolyScope stops a program started from the network when the mode
  changes) and programs from the network are ignored. Cleared: Remote Control again.
- ``slow_reply`` / ``no_reply`` / ``never_finish``: the control script's command handling
  (see ``control_script``); the dashboard keeps answering, it is the independent way in.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from payload_agent.fakes.ur.controller import URControllerCore

UR_FAULTS = frozenset({"drop_connections", "stall_stream", "garbage", "nan_values", "protective_stop",
                       "emergency_stop", "leave_remote", "slow_reply", "no_reply", "never_finish"})
STREAM_FAULTS = ("stall_stream", "garbage")


class FaultState:
    """The faults active on one controller, and their effects when they start and end."""

    def __init__(self, ctrl: "URControllerCore"):
        self.ctrl = ctrl
        self.active: dict[str, dict[str, Any]] = {}

    def apply(self, name: str, params: dict[str, Any] | None = None) -> None:
        if name not in UR_FAULTS:
            raise ValueError(f"the simulated UR controller cannot inject {name!r}; it can: "
                             f"{', '.join(sorted(UR_FAULTS))}")
        c = self.ctrl
        self.active[name] = dict(params or {})
        c.note(f"fault injected: {name} {params or ''}")
        if name == "drop_connections":
            c.drop_connections()
            self.active.pop(name, None)  # a one-off event
        elif name == "protective_stop":
            c.trigger_protective_stop()
        elif name == "emergency_stop":
            c.trigger_estop()
        elif name == "leave_remote":
            c.set_remote_control(False)
            c.stop_program("the pendant took control (Local mode)", wait=False)

    def clear(self, name: str) -> None:
        if self.active.pop(name, None) is None:
            return
        c = self.ctrl
        c.note(f"fault cleared: {name}")
        if name in ("protective_stop", "emergency_stop"):
            c.reset_safety()
        elif name == "leave_remote":
            c.set_remote_control(True)

    def clear_all(self) -> None:
        for name in list(self.active):
            self.clear(name)

    def is_active(self, name: str) -> bool:
        return name in self.active

    def params(self, name: str) -> dict[str, Any]:
        return self.active.get(name, {})

    @property
    def stream_fault(self) -> str | None:
        """The stream fault acting on sample stream sessions now, if any."""
        for name in STREAM_FAULTS:
            if name in self.active:
                return name
        return None
