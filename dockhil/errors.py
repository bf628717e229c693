"""Errors a user can cause. The CLI prints them as one line, no traceback."""

from collections.abc import Collection


class DockhilError(Exception):
    """A user-facing error: the message says what went wrong, where, and what to do."""


class LaunchError(DockhilError):
    """A launch file or launch argument is refused."""


class ParamError(DockhilError):
    """A node parameter is unknown, mistyped or out of range."""

    # A time beyond its physical range that reads as milliseconds given for seconds: (the value given,
    # what such a time is, the value in seconds meant); the launch layer names the argument it came from.
    slip: tuple[float, str, float] | None = None


class DeviceError(DockhilError):
    """A hardware device is missing, unreachable or misbehaving."""


class SafetyStop(DockhilError):
    """A safety limit tripped: the robot was told to hold and commanding stopped.

    The message is one line naming the limit and the value; `limit` and
    `value` carry them for programs.
    """

    def __init__(self, message: str, limit: str, value: float | str | None = None):
        super().__init__(message)
        self.limit = limit
        self.value = value


def suggest(name: str, known: Collection[str], what: str) -> str:
    """`did you mean 'x'? (what: a, b, c)` when a known name is close to `name`, else `what: a, b, c`."""
    import difflib

    near = difflib.get_close_matches(name, list(known), n=1)
    listed = f"{what}: {', '.join(sorted(known)) or 'none'}"
    return f"did you mean {near[0]!r}? ({listed})" if near else listed


_BREAKS = "\n\r\v\f\x1c\x1d\x1e\x85\u2028\u2029"  # every character str.splitlines() ends a line at


def one_line(text: str) -> str:
    """`text` with each character that would end a line written as its escape: a message quoting
    input (a name with a line break, say) stays one line."""
    return text.translate({ord(c): repr(c)[1:-1] for c in _BREAKS})


# What a node's own code may raise that the runtime turns into the node's line and a failed run.
# KeyboardInterrupt too: the runtime takes SIGINT as a request to stop (executor.Stop), so while a
# node runs a Ctrl-C never raises one; a node that raises it has failed.
NODE_RAISES = (Exception, SystemExit, KeyboardInterrupt)


def failure_line(name: str, where: str, exc: BaseException) -> str:
    """What node `name` did at `where` (a tick, setup, close): the one line a node process, a
    composed run and a container all give for a node's own exception, sys.exit or KeyboardInterrupt."""
    if isinstance(exc, SystemExit):
        return (
            f"node {name!r} called sys.exit({exc.code!r}) at {where}; a node ends with its graph: "
            f"return from step, or raise to stop the graph with a line"
        )
    if isinstance(exc, KeyboardInterrupt):
        return (
            f"node {name!r} raised KeyboardInterrupt at {where} (not a Ctrl-C, which stops the graph without one); "
            f"a node ends with its graph: return from step, or raise an Exception to stop the graph with a line"
        )
    return f"node {name!r} failed at {where}: {type(exc).__name__}: {exc}"
