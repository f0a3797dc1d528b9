"""What a driver's ``_move_status`` hook answers while the base class waits for a move: running, done
(the controller reports it finished), or aborted with the reason (the base then stops the arm and
raises MotionAbortedError with it). ``_start_move`` may answer refused: the controller took nothing,
so the base sends no stop (the arm may be moving for someone else) and raises MotionAbortedError."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class MoveStatus:
    """One look at the controller during a move."""

    state: str  # "running" | "done" | "aborted" | "refused"
    # aborted: why, as the operator reads it; a callable is asked only after the stop went out (its text may
    # need another round trip to the controller, which must not delay the stop)
    reason: str | Callable[[], str] = ""

    @property
    def running(self) -> bool:
        return self.state == "running"

    @property
    def done(self) -> bool:
        return self.state == "done"

    def describe(self) -> str:
        """The reason as text; a reason that cannot be read (the controller went away meanwhile) says so."""
        if not callable(self.reason):
            return self.reason
        try:
            return self.reason()
        except Exception as exc:
            return f"the move was {self.state} (why could not be read: {type(exc).__name__}: {exc})"


RUNNING = MoveStatus("running")
DONE = MoveStatus("done")


def aborted(reason: str | Callable[[], str]) -> MoveStatus:
    """The move ended abnormally (the controller stopped it, a fault, a refusal): the base stops the arm."""
    return MoveStatus("aborted", reason)


def refused(reason: str | Callable[[], str]) -> MoveStatus:
    """The controller refused the move before taking it (busy, a rejected command): nothing to stop."""
    return MoveStatus("refused", reason)
