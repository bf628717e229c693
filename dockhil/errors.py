"""Errors a user can cause. The CLI prints them as one line, no traceback."""


class DockhilError(Exception):
    """A user-facing error: the message says what went wrong, where, and what to do."""


class LaunchError(DockhilError):
    """A launch file or launch argument is refused."""


class ParamError(DockhilError):
    """A node parameter is unknown, mistyped or out of range."""


class DeviceError(DockhilError):
    """A hardware device is missing, unreachable or misbehaving."""


def suggest(name: str, known, what: str) -> str:
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
        return (f"node {name!r} called sys.exit({exc.code!r}) at {where}; a node ends with its graph: "
                f"return from step, or raise to stop the graph with a line")
    if isinstance(exc, KeyboardInterrupt):
        return (f"node {name!r} raised KeyboardInterrupt at {where} (not a Ctrl-C, which stops the graph without one); "
                f"a node ends with its graph: return from step, or raise an Exception to stop the graph with a line")
    return f"node {name!r} failed at {where}: {type(exc).__name__}: {exc}"


def node_error(exc: BaseException, nodes: dict) -> DockhilError:
    """`exc`, which a node's own method raised and the runtime received as it came (a
    KeyboardInterrupt; a sys.exit in close), as that node's line: the node and where are read
    from the traceback (nodes: name -> node), as a node process would say them."""
    name, where = _raised_in(exc, nodes) or ("?", "an unknown place")
    line = DockhilError(failure_line(name, where, exc))
    line.__cause__ = exc
    return line


def _raised_in(exc: BaseException, nodes: dict) -> tuple[str, str] | None:
    """(node name, where): the outermost frame of the traceback that is a method of one of
    `nodes` names the node; where is that method ('setup', 'close'), or for step the tick it was
    given. None if no node's method raised `exc`."""
    names = {id(node): name for name, node in nodes.items()}
    tb = exc.__traceback__
    while tb is not None:
        frame, code = tb.tb_frame, tb.tb_frame.f_code
        name = names.get(id(frame.f_locals.get(code.co_varnames[0]))) if code.co_argcount else None
        if name is not None:
            if code.co_name != "step":
                return name, code.co_name
            tick = frame.f_locals.get(code.co_varnames[1]) if code.co_argcount > 1 else None
            return name, f"tick {tick.index}" if hasattr(tick, "index") else "step"
        tb = tb.tb_next
    return None
