"""The recorder of a composed run: a tap in the graph's one process that encodes each message
and writes it to the bag, the same bytes the recorder process (dockhil.bags.live) writes."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from dockhil import msgs
from dockhil.bags import runinfo
from dockhil.bags.format import BagError
from dockhil.bags.live import FLUSH_EVERY_S, RECORDER_NAME
from dockhil.bags.writer import BagWriter
from dockhil.log import Log

if TYPE_CHECKING:
    from dockhil.scene.graph import Graph


class TapRecorder:
    """The recorder of a composed run: a tap that encodes each message and writes it."""

    def __init__(
        self,
        path: str,
        graph: Graph,
        *,
        sim: bool,
        log: Callable[[str], None] | None = None,
        duration: float | None = None,
        recorded_by: str = "a composed graph",
    ):
        from dockhil.scene.provenance import run_fields, scene_texts

        self.path = path
        self.sim = sim
        self.log = log or Log(f"[{RECORDER_NAME}]").line
        self.bag = BagWriter(path)
        for topic, ref in graph.publishers.items():
            self.bag.add_topic(topic, msgs.type_name(ref.type))
        run = run_fields(
            graph.scene,
            clock="sim" if sim else "wall",
            duration=duration,
            started_ns=time.time_ns(),
            recorded_by=recorded_by,
        )
        runinfo.write_start(self.bag, run, scene_texts(graph.scene))
        self.dropped = 0
        self.error: str | None = None
        self._next_flush = time.monotonic() + FLUSH_EVERY_S

    def __call__(self, topic: str, msg: Any) -> None:
        from dockhil.msgs.codec import encode

        if self.error is not None:
            self.dropped += 1
            return
        log_ns = round(msg.header.stamp * 1e9) if self.sim else time.time_ns()
        try:
            self.bag.write(topic, log_ns, log_ns, encode(msg))
            now = time.monotonic()
            if now >= self._next_flush:
                self._next_flush = now + FLUSH_EVERY_S
                self.bag.flush()
        except BagError as exc:
            self.error = str(exc)
            self.log(f"error: {exc}; the graph keeps running")

    def flush(self) -> None:
        """Put every message on disk (then `lost` is final), the bag open for the run's verdict."""
        if self.error is None:
            try:
                self.bag.flush()
            except BagError as exc:
                self.error = str(exc)
                self.log(f"error: {exc}")

    def close(self, verdict: dict[str, str] | None = None) -> None:
        """Write the run's verdict (dockhil.bags.runinfo; without one, that it was not told) and close."""
        self.flush()
        try:
            if self.error is None:
                self.bag.add_metadata(
                    runinfo.VERDICT,
                    runinfo.with_loss(
                        verdict
                        or runinfo.not_told("the recorder of this composed graph was not told the run's verdict"),
                        self.lost,
                    ),
                )
            self.bag.close()
        except BagError as exc:
            self.error = str(exc)
            self.log(f"error: {exc}")
        self.log(
            f"recorded {self.bag.messages_flushed} messages on {len(self.bag.topics)} topics to {self.path}; "
            f"{self.lost} lost" + (" (recording stopped early, see above)" if self.error else "")
        )

    @property
    def lost(self) -> int:
        """Messages handed to the recorder that are not on disk."""
        return self.dropped + self.bag.messages_written - self.bag.messages_flushed
