"""An observer on one of a running graph's topics, read without blocking by the launcher's watch loop:
how far the graph is (the tick its messages' headers carry: the progress bar), and whether a node said
a state on a status topic (a wall-time run that ends when its profile is done: `dockhil calibrate`)."""

from __future__ import annotations

from pathlib import Path

from dockhil.runtime.transport import GraphKeys, Subscriber


class Probe:
    def __init__(self, endpoint: str, key_file: Path):
        import zmq

        self.sub = Subscriber(zmq.Context.instance(), observer=True)
        self.sub.connect(endpoint, keys=GraphKeys.read(key_file))
        self.tick: int | None = None  # the newest tick read
        self.states: list[str] = []  # the NodeStatus states read, in order (a status topic)

    def read(self, status: bool = False) -> None:
        """Take what arrived: each message's tick, and with `status` its NodeStatus state."""
        from dockhil.msgs import NodeStatus
        from dockhil.msgs.codec import DecodeError, decode, decode_header

        while (frames := self.sub.recv_nowait()) is not None:
            if len(frames) != 2:
                continue
            header = decode_header(frames[1])
            if header is not None:
                self.tick = header.tick
            if status:
                try:
                    self.states.append(decode(frames[1], NodeStatus).state)
                except DecodeError:  # not a status: nothing said
                    pass

    def close(self) -> None:
        self.sub.close()
