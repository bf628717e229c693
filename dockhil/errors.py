"""Errors a user can cause. The CLI prints them as one line, no traceback."""


class DockhilError(Exception):
    """A user-facing error: the message says what went wrong, where, and what to do."""


class LaunchError(DockhilError):
    """A launch file or launch argument is refused."""


class ParamError(DockhilError):
    """A node parameter is unknown, mistyped or out of range."""


class DeviceError(DockhilError):
    """A hardware device is missing, unreachable or misbehaving."""
