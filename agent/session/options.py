"""What a session is asked to do, and how it talks to the operator: two types, never mixed.

``RunOptions`` is the policy (which mode, may it ask, may it write the controller, which solver...):
what the CLI's flags, the Python API, `watch` and the PLC server decide. ``OperatorUI`` is how the
session reaches a person (lines out, questions in, the live progress line). ``SimulatedCellUse`` is
only for simulated robots: an already running simulated cell to use, and who is told when it runs
(the CLI mounts the calibration's reference payload there; tests inject faults).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, TextIO

from payload_agent.types import PayloadSetting


@dataclass(frozen=True)
class RunOptions:
    """The policy of one session."""

    mode: str = "identify"  # identify | baseline | calibrate (session/modes.py)
    unattended: bool = False  # never prompt: fail where a person would have to be asked
    assume_yes: bool = False  # interactive, but the plan (and --apply) are accepted without asking
    apply: bool = False  # write the result to the controller (only when the quality gates pass)
    fresh_baseline: bool = False  # record the empty run in this session even if a stored one fits
    tool: str | None = None  # the operator's label for the mounted tool (history, report)
    reference: PayloadSetting | None = None  # calibrate: the known payload mounted for this run
    result_path: Path | None = None
    solver: str | None = None
    report: bool = True
    retry_sweeps: int = 0  # redo a sweep whose sample stream had a gap, up to this many times per phase
    resume: Path | None = None  # an incomplete run folder to finish (only its unfinished sweeps are recorded)
    # end with a travel move back to where the arm stood when the session started (part of the plan the gate
    # approves whole): a tool change hands the arm back where the cell had it, near the next verify's start
    return_to_start: bool = False
    # end the last run with a travel move back to the plan's first pose (``motion.planner.parked``; `calibrate
    # --park`): the arm waits there for the tool change, and a run of the same plan then needs no approach
    park: bool = False

    @property
    def asks(self) -> bool:
        """Whether a person confirms (the plan, the tool change, --apply) before it happens."""
        return not (self.unattended or self.assume_yes)


@dataclass(frozen=True)
class OperatorUI:
    """How the session talks to the operator."""

    out: Callable[[str], None] = print
    ask: Callable[[str], str] = input
    detail: Callable[[str], None] | None = None  # per-move lines (the CLI shows them with -v); default: out
    progress: bool | None = None  # live progress line; None: only when the output is a terminal
    progress_stream: TextIO | None = None  # where the live progress line is drawn (default sys.stdout)

    @property
    def say_detail(self) -> Callable[[str], None]:
        return self.detail or self.out


@dataclass(frozen=True)
class SimulatedCellUse:
    """For a robot YAML with a ``simulation`` section: the cell to use (None: the session starts its own and
    closes it afterwards; a given one is left running) and who is told once it runs."""

    cell: Any = None
    on_cell: Callable[[Any], None] | None = None


QUIET = OperatorUI(out=lambda _line: None, progress=False)
