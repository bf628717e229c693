"""The end of a wall-time recording. A recorder that fell behind the graph may still hold the end of
the run in its queue when the graph stops, and a gap in what arrived cannot show the loss of it, as
nothing follows it. So each node reports, as it exits, how many messages each of its topics'
publishers sent (with its loop figures), and the launcher tells its recorder process, on standard
input, once the nodes have exited (one line, dockhil.runtime.launcher.SENT and JSON), then the run's
verdict (one JSON line). The recorder reads on until it has them all, for a bounded time, and
counts what never came as lost (dockhil.bags.live, Recorder.await_sent).

(Why counts at exit rather than a last frame on each topic that carries its count: every reader
of the graph, and any outside one, would have to learn a new kind of frame, a full queue could
refuse it, and a node that is killed sends none; the launcher reads the nodes' exit reports
already, knows which node was killed or respawned, and reaches the recorder without the wire.)
"""

from __future__ import annotations

import json
import queue
import threading
from typing import IO

# The recorder's waits at the end: for the launcher's counts of what was sent (it stops the nodes first:
# 3 s each at most, drivers then devices), then for what is missing: until none came for TAIL_QUIET_S (the
# publishers have exited: what is in flight is in its queue), at most TAIL_MAX_S (within the launcher's
# wait for the recording, dockhil.runtime.launcher.HELPER_WAIT_S).
SENT_WAIT_S = 15.0
TAIL_QUIET_S = 0.5
TAIL_MAX_S = 6.0


class Told:
    """The lines the launch writes to `stream` (the recorder's stdin), read by a thread as they come,
    so that the recording goes on meanwhile."""

    def __init__(self, stream: IO[str]):
        from dockhil.runtime.launcher import SENT

        self._prefix = SENT
        self._lines: queue.Queue[str | None] = queue.Queue()
        self._ended = False
        self._sent: dict[str, int] | None = None
        self._held: list[str | None] = []  # lines read while looking for the counts, in order
        threading.Thread(target=self._read, args=(stream,), daemon=True, name="told").start()

    def _read(self, stream: IO[str]) -> None:
        try:
            for line in stream:
                self._lines.put(line)
        except (OSError, ValueError):  # closed under us: nothing more will come
            pass
        self._lines.put(None)

    def sent(self) -> dict[str, int] | None:
        """Topic -> messages its publisher sent, once told (never waits); None until then. {} once
        the stream ended without it: nothing is known of what was sent."""
        while self._sent is None and not self._ended:
            try:
                line = self._lines.get_nowait()
            except queue.Empty:
                return None
            if line is not None and line.startswith(self._prefix):
                self._sent = _counts(line[len(self._prefix) :])
            else:
                self._held.append(line)
                self._ended = line is None
        return self._sent if self._sent is not None else {}

    def verdict_line(self) -> str:
        """The next line that is not the counts (waits for it); "" once the stream ended."""
        while True:
            line = self._held.pop(0) if self._held else self._lines.get()
            if line is None:
                self._held.insert(0, None)
                return ""
            if not line.startswith(self._prefix):
                return line


def _counts(text: str) -> dict[str, int]:
    """The counts of a SENT line; {} (nothing known) if it does not read as topic -> count."""
    try:
        found = json.loads(text)
        return {str(t): int(n) for t, n in found.items()} if isinstance(found, dict) else {}
    except (ValueError, TypeError):
        return {}


def missing(counts: dict[str, int], received: dict[str, int]) -> dict[str, tuple[int, int]]:
    """Topic -> (messages sent that never arrived, of how many sent), for the topics that miss some."""
    return {t: (n - received[t], n) for t, n in sorted(counts.items()) if t in received and n > received[t]}


def tail_lines(tail: dict[str, tuple[int, int]], unknown: list[str]) -> list[str]:
    """What the recorder says of the end of its recording: one line for what never arrived, one for
    the topics whose count is not known."""
    out = []
    if tail:
        each = ", ".join(f"{t}: {m} of the {n} message(s) sent" for t, (m, n) in tail.items())
        out.append(
            f"error: the end of the run is missing from the bag: {each} never arrived (the recorder fell behind)"
        )
    if unknown:
        out.append(
            f"note: not known what was sent on {', '.join(unknown)} (its node ended without its report: "
            f"killed, or crashed; or it runs on another host): whether the bag misses their end is not known"
        )
    return out
