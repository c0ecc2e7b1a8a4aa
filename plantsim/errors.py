"""The project's own failures, in one place (after laspy's ``errors.py``).

Plain argument errors stay ``ValueError`` / ``FileNotFoundError``; these are for
failures of plantsim's own work that a user can still act on.
"""


class PlantSimError(Exception):
    """Base class of every plantsim failure."""


class MeshError(PlantSimError):
    """A plant mesh cannot be used: unreadable, empty, or with bad vertices."""


class ConfigError(PlantSimError, ValueError):
    """A configuration value or file is invalid."""


class SceneError(PlantSimError):
    """The MuJoCo scene failed to compile or raised warnings."""


class SimulationError(PlantSimError):
    """A simulation diverged or could not run; nothing was written from it."""


class HardwareError(PlantSimError):
    """The physical rig (servo, port) failed or stopped answering."""


class ServoCommunicationError(HardwareError):
    """A servo did not answer, answered garbage, or the port failed or vanished."""


class ServoAlarmError(HardwareError):
    """A servo reported a hardware error (overload, overheating, ...) and dropped torque.

    Attributes:
        hardware_error_status: the Hardware Error Status register value.
    """

    def __init__(self, message: str, hardware_error_status: int = 0):
        super().__init__(message)
        self.hardware_error_status = hardware_error_status


class JournalError(PlantSimError):
    """A scan journal cannot be used: damaged, from another configuration, or in the way."""


class ScanInterruptedError(HardwareError):
    """A rig scan stopped on a hardware failure; the lines taken are safe in its journal.

    Attributes:
        journal_path: the journal to ``--resume`` from.
        lines_done: complete lines in the journal.
        n_lines: lines in the whole scan.
    """

    def __init__(self, message: str, *, journal_path: str, lines_done: int, n_lines: int):
        super().__init__(message)
        self.journal_path = journal_path
        self.lines_done = lines_done
        self.n_lines = n_lines


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP arrived while the rig was in use (see :mod:`plantsim.hardware.safety`).

    A ``KeyboardInterrupt`` on purpose: code that journals and cleans up after Ctrl-C
    does the same after ``kill``, and ``except Exception`` does not swallow it.

    Attributes:
        signum: the signal's number.
    """

    def __init__(self, signum: int):
        import signal

        super().__init__(f"terminated by {signal.Signals(signum).name}")
        self.signum = signum


class UnsafeStopError(HardwareError):
    """A safety stop could not confirm that the hardware is safe (torque, laser still on?).

    Attributes:
        report: the :class:`plantsim.hardware.safety.SafeStopReport`.
    """

    def __init__(self, message: str, *, report):
        super().__init__(message)
        self.report = report


class LidarError(HardwareError):
    """The real LiDAR (Hokuyo URG over SCIP 2.0) failed, refused a command, or is not the one expected."""


class LidarCommunicationError(LidarError):
    """The LiDAR's link failed: no reply, garbled replies, or the port vanished."""


class LidarTimeoutError(LidarCommunicationError):
    """The LiDAR did not answer (or stopped streaming) within the timeout."""


class LidarChecksumError(LidarCommunicationError):
    """The LiDAR's replies kept failing their checksums or framing after the retries."""


class LidarDisconnectedError(LidarCommunicationError):
    """The LiDAR's serial port failed or vanished (unplugged?)."""


class LidarStatusError(LidarError):
    """The LiDAR answered a command with an error status.

    Attributes:
        command: the command's symbol ("GD", "BM", ...).
        status: the 2-character status.
    """

    def __init__(self, message: str, *, command: str = "", status: str = ""):
        super().__init__(message)
        self.command = command
        self.status = status


class LidarModelError(LidarError):
    """The connected LiDAR is not the model (or geometry) the configuration expects."""
