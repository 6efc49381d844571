"""Errors every backend raises the same way, so the CLI can turn them into one-line messages."""


class TwinError(Exception):
    """Base of the errors the CLI reports as one line and a non-zero exit."""


class ConfigError(TwinError, ValueError):
    """A parameter, object or config file is invalid; raised before anything is simulated."""


class DeviceError(TwinError):
    """A device failed while in use."""


class DeviceNotConnectedError(DeviceError, ConnectionError):
    """A device method needs a connection that is not open."""


class DeviceNotConfiguredError(DeviceError):
    """A hardware device was asked for but the rig names no port or file for it."""


class SimulationUnstableError(TwinError):
    """The physics diverged (MuJoCo reset its state): the model is too stiff or too damped for its step."""


class RunDirectoryLostError(TwinError):
    """The run directory was removed or replaced while the run was being written."""


class WorkerLostError(TwinError):
    """A worker process of a parallel computation ended abruptly (killed, or out of memory)."""


class RunWarning(UserWarning):
    """A run that completed, but not quite as declared: a hardware hand loop below its rate, or hand
    cycles the driver had to recover. The API warns with it (`warnings.warn`); the CLI prints the line."""
