"""One exception hierarchy; every message should tell the user what to do."""


class PayloadAgentError(Exception):
    """Base of every error payload-agent raises on purpose."""

    exit_code = 1


class ConfigError(PayloadAgentError):
    """The robot YAML (or a procedure file) is malformed; the message names the key path."""

    exit_code = 2

    def __init__(self, key_path: str, problem: str, source: str | None = None):
        self.key_path = key_path
        self.problem = problem
        self.source = source
        where = f"{source}: " if source else ""
        super().__init__(f"{where}{key_path}: {problem}")


class NoTerminalError(PayloadAgentError):
    """A question had to be asked but there is no one to answer it (stdin closed, not a terminal).

    Nothing moves; the message says which flag answers the question instead (--yes, --unattended).
    """

    exit_code = 2


class PlanError(PayloadAgentError):
    """The procedure cannot be turned into joint targets for this robot."""

    exit_code = 2


class SafetyError(PayloadAgentError):
    """The safety gate refused the plan or a single motion."""

    exit_code = 2


class RobotNotReadyError(PayloadAgentError):
    """The controller is connected but not in a state that allows motion."""

    exit_code = 3


class RobotBusyError(RobotNotReadyError):
    """Another payload-agent session holds this robot's session lock (one session per robot)."""

    exit_code = 3


class BaselineError(RobotNotReadyError):
    """No stored empty-flange baseline fits this run (missing, other robot, changed procedure, too old)."""

    exit_code = 3


class MotionAbortedError(PayloadAgentError):
    """A motion ended abnormally (stop, protective stop, e-stop, timeout, Ctrl-C)."""

    exit_code = 4


class QualityGateError(PayloadAgentError):
    """The data or the estimate failed a quality check; nothing is written to the robot."""

    exit_code = 5


class CommunicationError(PayloadAgentError):
    """The controller could not be reached, or answered something that could not be parsed."""

    exit_code = 6


class UnsupportedCapability(PayloadAgentError):
    """The driver cannot do what was asked (for example write the payload setting)."""

    exit_code = 2


class DataError(PayloadAgentError):
    """Recorded data is missing, inconsistent or insufficient for the analysis asked for."""

    exit_code = 5


class SupervisionTrip(CommunicationError):
    """The motion supervision stopped the arm: the sample stream or the command connection failed mid-move.

    ``stop_report`` (payload_agent.types.StopReport) says how fast the stop went out and whether
    the controller acknowledged it.
    """

    def __init__(self, message: str, stop_report=None):
        self.stop_report = stop_report
        super().__init__(message)


class MotionStopped(MotionAbortedError):
    """The controller or a drive stopped the motion itself (a fault it reported); the agent stopped the rest."""

    def __init__(self, message: str, stop_report=None):
        self.stop_report = stop_report
        super().__init__(message)


class MotionNotFinished(MotionAbortedError):
    """The controller never reported a move finished although the arm stood at its target; it was stopped."""

    def __init__(self, message: str, stop_report=None):
        self.stop_report = stop_report
        super().__init__(message)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C so every session stops the robot the same way."""


class ToolMismatchError(PayloadAgentError):
    """`verify`: the mounted tool does not match the expected payload (library entry or controller setting).

    The message says what differs and by how much; nothing is written to the controller.
    """

    exit_code = 7
