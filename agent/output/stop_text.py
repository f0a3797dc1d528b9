"""Why a run stopped, as a sentence a person reads in the manifest and the report.

Exception class names ("KeyboardInterrupt: signal SIGTERM during a run") mean nothing to an
operator; the project's errors already carry a message, so the sentence is a plain kind of
stop plus that message. Only an unexpected error (a bug) keeps its class name, in parentheses,
for the bug report. Manifests written before this keep their text; ``readable`` rewrites the
``<ClassName>: message`` form when a report shows them.
"""

from __future__ import annotations

import re

from payload_agent.errors import (CommunicationError, ConfigError, DataError, MotionAbortedError, PayloadAgentError,
                                  PlanError, QualityGateError, RobotNotReadyError, SafetyError, Terminated)

# most specific first: the first matching kind names the stop
_KINDS: tuple[tuple[type[BaseException], str], ...] = (
    (MotionAbortedError, "motion aborted"), (CommunicationError, "communication failure"),
    (RobotNotReadyError, "robot not ready"), (SafetyError, "safety refusal"), (PlanError, "plan refused"),
    (ConfigError, "configuration error"), (QualityGateError, "quality gate failed"), (DataError, "data error"),
)
_CLASS_PREFIX = re.compile(r"^([A-Z][A-Za-z]*(?:Error|Interrupt|Exception|Trip|Stopped|NotFinished|Terminated)): ?")


def stop_sentence(exc: BaseException) -> str:
    """``exc`` (what ended a run or a phase) as one sentence without exception class names."""
    text = str(exc).strip()
    if isinstance(exc, Terminated):
        return "terminated by SIGTERM" + (f" ({text})" if text else "")
    if isinstance(exc, KeyboardInterrupt):  # Ctrl-C, or `watch`'s signal handler naming its signal
        return f"stopped by {text}" if text.startswith("signal ") else ("interrupted by Ctrl-C" + (
            f" ({text})" if text else ""))
    for cls, kind in _KINDS:
        if isinstance(exc, cls):
            return f"{kind}: {text}" if text else kind
    if isinstance(exc, PayloadAgentError):
        return text or "stopped by an error without a message"
    return f"unexpected error (a bug, {type(exc).__name__}): {text}" if text else \
        f"unexpected error (a bug, {type(exc).__name__})"


def readable(reason: str) -> str:
    """A stored stop reason with a leading ``<ClassName>:`` (older manifests) rewritten as a sentence."""
    m = _CLASS_PREFIX.match(reason)
    if not m:
        return reason
    name, rest = m.group(1), reason[m.end():].strip()
    if name == "KeyboardInterrupt":
        return f"stopped by {rest}" if rest.startswith("signal ") else "interrupted by Ctrl-C" + (
            f" ({rest})" if rest else "")
    words = re.sub(r"(?<!^)(?=[A-Z])", " ", name.removesuffix("Error")).lower()
    return f"{words}: {rest}" if rest else words
