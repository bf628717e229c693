"""Bags and a running graph: the recorder (the logger). `bag play` is dockhil.bags.play.

The recorder subscribes to topics of a running graph and writes each message's
wire bytes as they came (no re-encoding) to an MCAP bag (`dockhil.bags`).
The log time of a message is its receive time in wall time; in sim time it is
the message's header stamp, so a sim-time bag carries sim times and the same
run recorded twice gives the same bag. It runs in three ways:

- `dockhil launch FILE --bag PATH`: the launcher starts it as a helper process (`python -m
  dockhil.bags.live record PATH --graph-pid PID [--n-ticks N]`) counted as a subscriber of every
  topic, so sim time waits for it before tick 0. In sim time it exits by itself once it holds tick
  N-1 of every topic. In wall time it is told at the end what each topic's publisher sent, and
  counts what never came as lost (dockhil.bags.tail).
- `dockhil launch FILE --composed --bag PATH`: a tap in the one process
  (dockhil.bags.tap) encodes each message and writes it; the bytes are the same.
- `dockhil bag record PATH [--topics ...]`: joins graphs that are already running (found in the
  registry), until Ctrl-C or until they stop. It is an observer (`dockhil.runtime.transport`): if
  it falls behind it loses messages, counts them and says so, and the graph's own deliveries go on.

Chunks are closed by size, by age and on a 0.5 s timer, so a recorder killed with SIGKILL loses at
most the chunk it was filling. On SIGTERM or SIGINT it drains what its socket holds, then closes it.

Exit status: 2 (one line, nothing recorded) when the bag cannot be created;
the launcher checks the path before any node starts. 0 otherwise, also when
writing fails mid-run (full disk): the recorder says in one line that
recording stopped and why, keeps draining its socket so the graph runs on,
and at exit says how many messages are lost.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from dockhil.bags import runinfo
from dockhil.bags.format import BagError
from dockhil.bags.tail import SENT_WAIT_S, TAIL_MAX_S, TAIL_QUIET_S, missing, tail_lines
from dockhil.bags.writer import BagWriter
from dockhil.errors import DockhilError
from dockhil.log import Log, setup_child
from dockhil.msgs.codec import decode_header

if TYPE_CHECKING:
    from dockhil.runtime import executor, plan
    from dockhil.scene.graph import Graph
RECORDER_NAME = "bag-recorder"
FLUSH_EVERY_S = 0.5  # bounds what a SIGKILL loses when topics are quiet
DRAIN_QUIET_S = 0.2  # at stop: what still arrives within this is recorded
DRAIN_MAX_S = 2.0
FIND_GRAPH_TIMEOUT_S = 20.0  # as long as sim-time publishers wait for subscribers


_record_log = Log("dockhil bag record:").line  # lines whose first word may say their level


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


# --------------------------------------------------------------------------- recording


@dataclass
class Source:
    """A topic to record: where it is published and how its times are read."""

    topic: str
    endpoint: str
    type_name: str
    sim: bool  # the publishing graph runs in sim time: log time = header stamp
    graph_pid: int
    run_id: str
    key_file: str = ""  # the publishing graph's key file


def _graph_running(pid: int, run_id: str) -> bool:
    """A graph runs while its registry entry exists and its process lives (an exited
    child not yet reaped by its parent still answers to kill(pid, 0); the entry does not)."""
    from dockhil.runtime.registry import registry_dir

    return _alive(pid) and (registry_dir() / f"{run_id}.json").exists()


def find_sources(topics: list[str] | None = None, graph_pid: int | None = None) -> dict[str, Source]:
    """Topics of running graphs (of the one launched by `graph_pid` if given), or a one-line error."""
    from dockhil.runtime.registry import running_graphs

    graphs = [g for g in running_graphs() if graph_pid is None or g.get("pid") == graph_pid]
    if not graphs:
        raise DockhilError("no running graph found; start one with 'dockhil launch FILE'")
    found: dict[str, Source] = {}
    for g in graphs:
        for topic, t in sorted(g.get("topics", {}).items()):
            other = found.get(topic)
            if other is not None:
                _record_log(
                    f"note: topic {topic} is published by two running graphs; recording the one of pid "
                    f"{other.graph_pid}"
                )
                continue
            found[topic] = Source(
                topic, t["endpoint"], t["type"], g.get("clock") == "sim", g["pid"], g["run_id"], g.get("keys", "")
            )
    if topics is None:
        return found
    missing = [t for t in topics if t not in found]
    if missing:
        raise DockhilError(
            f"topic {missing[0]} is not published by any running graph; topics: {', '.join(sorted(found)) or 'none'}"
        )
    return {t: found[t] for t in topics}


class _TopicState:
    __slots__ = ("topic", "sim", "last_log", "last_index", "done", "received")

    def __init__(self, topic: str, sim: bool):
        self.topic = topic
        self.sim = sim
        self.received = 0  # messages (not empty ticks)
        self.last_log = 0  # ns; a message without a readable header reuses it in sim time
        self.last_index: int | None = None  # last header.tick (sim time)
        self.done = False


class Recorder:
    """Subscribes to `sources` and writes what arrives to a new bag at `path`.

    `n_ticks` (sim time): finished once tick n_ticks-1 of every topic is in.
    Counts: `lost` messages (received but not on disk, in sim time missing
    ticks, and for an `observer` what its publishers sent it that never
    arrived), `unreadable` messages (without a header to read; recorded if
    they are msgpack, counted in the bag's `messages_unencodable` if not).
    (header.seq is the tick: a wall-time node that has nothing new at a tick
    publishes nothing, so gaps in it are no loss. A graph member's losses are
    counted by the publisher, whose full queue refused the message.) In wall
    time, `await_sent` adds what the publishers sent that never arrived: the
    end of the run, which a recorder that fell behind would otherwise lose
    without a gap to show it (`tail`).
    """

    def __init__(
        self,
        path: str,
        sources: dict[str, Source],
        *,
        n_ticks: int | None = None,
        overwrite: bool = False,
        log: Callable[[str], None] = _record_log,
        observer: bool = False,
        runs: list[tuple[dict, dict]] | None = None,
    ):
        """runs: (run description, scene texts) of each recorded graph, written first (runinfo)."""
        import zmq

        from dockhil.runtime.transport import Subscriber

        self.path = path
        self.log = log
        self.n_ticks = n_ticks
        self.bag = BagWriter(path, overwrite=overwrite)
        try:
            for source in sources.values():
                self.bag.add_topic(source.topic, source.type_name)
            for run, texts in runs or []:
                runinfo.write_start(self.bag, run, texts)
        except BagError:
            self.bag.close()
            raise
        from dockhil.runtime.registry import graph_keys

        # A graph member in sim time trails: no tick waits for it, and it takes its messages in bursts.
        trailing = not observer and bool(sources) and all(s.sim for s in sources.values())
        self.sub = Subscriber(zmq.Context.instance(), observer=observer, trailing=trailing)
        try:
            for source in sources.values():
                keys = graph_keys({"run_id": source.run_id, "keys": source.key_file})
                self.sub.connect(source.endpoint, keys=keys)
        except DockhilError:
            self.sub.close()
            self.bag.close()
            raise
        self._state = {s.topic.encode(): _TopicState(s.topic, s.sim) for s in sources.values()}
        self._pending_topics = len(self._state) if n_ticks is not None else -1
        self.received = 0
        self.dropped = 0  # received while writing had stopped
        self.tick_gaps = 0
        self.unreadable = 0
        self.tail: dict[str, tuple[int, int]] = {}  # topic -> (messages that never arrived, of how many sent)
        self.error: str | None = None
        self._next_flush = time.monotonic() + FLUSH_EVERY_S
        self._listening = True

    @property
    def finished(self) -> bool:
        """Sim time with n_ticks: every topic has delivered its last tick."""
        return self._pending_topics == 0

    @property
    def lost(self) -> int:
        # An observer's lost message is also a missing tick in sim time: counted once.
        return (
            self.dropped
            + max(self.tick_gaps, self.sub.lost)
            + (self.bag.messages_written - self.bag.messages_flushed)
            + sum(m for m, _ in self.tail.values())
        )

    def handle(self, frames: list[bytes]) -> None:
        st = self._state.get(frames[0]) if frames else None
        if st is None:  # cannot happen with one endpoint per topic; counted, not guessed at
            self.received += 1
            self.dropped += 1
            return
        if len(frames) == 3 and not frames[1] and len(frames[2]) == 8:
            # Sim time: this tick has no message on the topic. Nothing to record, but the tick counts.
            self._tick(st, int.from_bytes(frames[2], "little"))
            return
        self.received += 1
        st.received += 1
        data = frames[1] if len(frames) == 2 else b"".join(frames[1:])
        header = decode_header(data)
        if header is None:
            self.unreadable += 1
            log_ns = st.last_log if st.sim else time.time_ns()
        elif st.sim:
            log_ns = round(header.stamp * 1e9)
            if not 0 <= log_ns < 2**64:
                log_ns = st.last_log
            self._tick(st, header.tick)
        else:
            log_ns = time.time_ns()
        st.last_log = log_ns
        if self.error is not None:
            self.dropped += 1
            return
        try:
            self.bag.write(st.topic, log_ns, log_ns, data)
        except BagError as exc:
            self._stopped(exc)

    def _tick(self, st: _TopicState, k: int) -> None:
        if st.last_index is not None and k > st.last_index + 1:
            self.tick_gaps += k - st.last_index - 1
        st.last_index = k
        if self.n_ticks is not None and not st.done and k >= self.n_ticks - 1:
            st.done = True
            self._pending_topics -= 1

    def _stopped(self, exc: BagError) -> None:
        self.error = str(exc)
        self.log(f"error: {exc}; the graph keeps running")

    def flush_if_due(self, now: float) -> None:
        if now < self._next_flush:
            return
        self._next_flush = now + FLUSH_EVERY_S
        if self.error is None and self.bag.messages_written > self.bag.messages_flushed:
            try:
                self.bag.flush()
            except BagError as exc:
                self._stopped(exc)

    def _burst(self) -> int:
        """Handle what is queued now, without waiting; returns how many."""
        n = 0
        recv = self.sub.recv_nowait
        while n < 2000:  # bounded, so the flush timer still runs under load
            frames = recv()
            if frames is None:
                break
            self.handle(frames)
            n += 1
        return n

    def run(self, stop: executor.Stop, alive: Callable[[], bool] | None = None) -> str:
        """Record until finished (sim time), stopped by a signal, or `alive()` turns false.
        Returns why it ended."""
        next_check = time.monotonic() + 0.5
        why = "stopped"
        while not stop.requested:
            frames = self.sub.recv(0.1)
            if frames is not None:
                self.handle(frames)
                self._burst()
            if self.finished:
                return "finished"
            now = time.monotonic()
            self.flush_if_due(now)
            if alive is not None and now >= next_check:
                next_check = now + 0.5
                if not alive():
                    why = "the graph stopped"
                    break
        self.drain()
        return why

    def drain(self) -> None:
        """Record what is still in flight: until quiet for a moment, at most DRAIN_MAX_S."""
        end = time.monotonic() + DRAIN_MAX_S
        quiet_until = time.monotonic() + DRAIN_QUIET_S
        while not self.finished:
            now = time.monotonic()
            if now >= end or now >= quiet_until:
                break
            if self._burst():
                quiet_until = time.monotonic() + DRAIN_QUIET_S
            else:
                frames = self.sub.recv(min(0.02, max(0.0, quiet_until - now)))
                if frames is not None:
                    self.handle(frames)
                    quiet_until = time.monotonic() + DRAIN_QUIET_S

    def await_sent(
        self,
        sent: Callable[[], dict[str, int] | None],
        *,
        clock: Callable[[], float] = time.monotonic,
        wait_s: float = SENT_WAIT_S,
        quiet_s: float = TAIL_QUIET_S,
        most_s: float = TAIL_MAX_S,
    ) -> None:
        """Wall time, after `run`: record on until `sent()` (None until told) says what each topic's
        publisher sent and all of it is in; what never came is lost (`tail`). Bounded: `wait_s` for the
        counts, then `quiet_s` without a message, `most_s` in all."""
        counts = None
        end = clock() + wait_s
        quiet_until = end
        while True:
            now = clock()
            if counts is None and (counts := sent()) is not None:
                end, quiet_until = now + most_s, now + quiet_s
            if counts is not None and (now >= end or now >= quiet_until or not self._missing(counts)):
                break
            if counts is None and now >= end:
                self.log(
                    f"warning: not told within {wait_s:g} s what the publishers sent; whether the bag misses "
                    f"the end of the run is not known"
                )
                return
            got = self._burst()
            if not got and (frames := self.sub.recv(0.02)) is not None:
                self.handle(frames)
                got = 1
            if got:
                quiet_until = clock() + quiet_s
            self.flush_if_due(now)
        self.tail = missing(counts, self._received())
        for line in tail_lines(self.tail, sorted(st.topic for st in self._state.values() if st.topic not in counts)):
            self.log(line)

    def _received(self) -> dict[str, int]:
        return {st.topic: st.received for st in self._state.values()}

    def _missing(self, counts: dict[str, int]) -> bool:
        return bool(missing(counts, self._received()))

    def stop_listening(self) -> None:
        """Receive no more and put every message on disk: the bag then holds the whole recording,
        open for the run's verdict (`close`)."""
        if self._listening:
            self._listening = False
            self.sub.close()
        if self.error is None:
            try:
                self.bag.flush()
            except BagError as exc:
                self._stopped(exc)

    def close(self, verdict: dict[str, str] | None = None, why_not_told: str = "") -> str:
        """Write the run's verdict (dockhil.bags.runinfo; without one, `why_not_told`) and close the
        bag; returns the one-line report (also logged)."""
        self.stop_listening()
        if self.error is None:
            try:
                self.bag.add_metadata(
                    runinfo.VERDICT, runinfo.with_loss(verdict or runinfo.not_told(why_not_told), self.lost)
                )
            except BagError as exc:
                self._stopped(exc)
        try:
            self.bag.close()
        except BagError as exc:
            self._stopped(exc)
        on_disk = self.bag.messages_flushed
        line = f"recorded {on_disk} messages on {len(self._state)} topics to {self.path}; {self.lost} lost"
        if self.tail:
            line += f" ({sum(m for m, _ in self.tail.values())} at the end of the run, never arrived)"
        if self.error is not None:
            line += " (recording stopped early, see above)"
        if self.sub.lost:
            line += (
                f" ({self.sub.lost} not taken in time: recording from outside the graph, it drops what it "
                f"cannot keep up with rather than slow the graph)"
            )
        if self.unreadable:
            line += f"; {self.unreadable} without a readable header"
        if self.bag.messages_unencodable:
            line += f"; {self.bag.messages_unencodable} not recorded: not msgpack, so no JSON for them"
        self.log(line)
        return line


def record(args: argparse.Namespace) -> int:
    """`dockhil bag record PATH [--topics ...] [--overwrite]`: record running graphs until Ctrl-C."""
    from dockhil.runtime.executor import Stop

    sources = find_sources(args.topics)
    stop = Stop()
    stop.install()
    runs = [registered_run(run_id, recorded_by="bag record") for run_id in sorted({s.run_id for s in sources.values()})]
    recorder = Recorder(args.path, sources, overwrite=args.overwrite, observer=True, runs=runs)
    graphs = {(s.graph_pid, s.run_id) for s in sources.values()}
    _record_log(f"recording {len(sources)} topics to {args.path} (Ctrl-C to stop)")
    try:
        why = recorder.run(stop, alive=lambda: any(_graph_running(*g) for g in graphs))
    finally:  # also on a publisher that failed authentication: what was recorded is kept
        recorder.close(
            why_not_told="recorded from outside the run (dockhil bag record), which is not told its "
            "verdict: the launch that ran it says it"
        )
    if why == "the graph stopped":
        _record_log("the recorded graph stopped")
    if recorder.lost:
        _record_log(f"error: {recorder.lost} message(s) lost; the recording is incomplete")
        return RECORDER_LOST_EXIT
    return 0


def registered_run(run_id: str, recorded_by: str) -> tuple[dict, dict]:
    """(run description, scene texts) a running graph registered; what it did not register is said so."""
    from dockhil.runtime.registry import registry_dir
    from dockhil.scene.provenance import iso_utc

    try:
        entry = json.loads((registry_dir() / f"{run_id}.json").read_text())
    except (OSError, ValueError):
        entry = {}
    run = entry.get("run")
    now = time.time_ns()
    if not isinstance(run, dict):  # a graph of an older dockhil, or `bag play`: its scene is not known
        run = {
            "scene": "",
            "clock": entry.get("clock", ""),
            "graph": entry.get("file", ""),
            "scene_known": "false: the graph registered no scene (an older dockhil, or bag play)",
        }
    run = {**run, "recorded_by": recorded_by}
    if recorded_by == "bag record":  # it joined the run when it started, not when the graph did
        run.update(joined=iso_utc(now), joined_ns=f"{now:019d}")
    texts = entry.get("scene_files")
    return run, texts if isinstance(texts, dict) else {}


def check_bag_path(path: str) -> None:
    """Refuse, with one line, a bag path the recorder could not create (before any node starts)."""
    if os.path.lexists(path) and not os.path.isdir(path):
        raise BagError(f"bag {path} already exists; choose another name or remove it")
    BagWriter(path).close()  # raises BagError: no such directory, permission, disk full
    os.remove(path)


def recorder_process(
    path: str, graph: Graph, clock: str, n_ticks: int | None, quiet: bool = False, topics: tuple[str, ...] = ()
) -> plan.ExtraProcess:
    """The recorder as a launcher helper process, subscribed to `topics` of `graph` (those it has; every
    topic when none is given or it has none of them); the launcher tells it the run's verdict before it
    closes the bag. quiet: a bag the user did not ask for (the summary's), whose path and count are said
    only at debug level."""
    from dockhil.runtime.plan import ExtraProcess

    argv = [sys.executable, "-m", "dockhil.bags.live", "record", path, "--graph-pid", str(os.getpid()), "--verdict"]
    recorded = [t for t in topics if t in graph.publishers] or list(graph.publishers)
    if len(recorded) < len(graph.publishers):
        argv += ["--topics", *recorded]
    if quiet:
        argv.append("--quiet")
    if clock == "sim" and n_ticks is not None:
        argv += ["--n-ticks", str(n_ticks)]
    if clock == "wall":
        argv.append("--sent-counts")
    return ExtraProcess(RECORDER_NAME, argv, recorded, verdict=True)


RECORDER_LOST_EXIT = 4  # the recorder process: it ran, but messages are missing from the bag


def _recorder_main(argv: list[str]) -> int:
    """The launcher's helper process: find the graph, subscribe, say ready, record."""
    from dockhil.runtime.executor import Stop
    from dockhil.runtime.process import READY, die_with_parent

    p = argparse.ArgumentParser(prog="python -m dockhil.bags.live record")
    p.add_argument("path")
    p.add_argument("--graph-pid", type=int, required=True, help="pid of the launcher whose graph to record")
    p.add_argument("--n-ticks", type=int, help="sim time: stop after tick N-1 of every topic")
    p.add_argument("--topics", nargs="+")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--quiet", action="store_true", help="info lines at debug level")
    p.add_argument(
        "--verdict",
        action="store_true",
        help="once recorded, say RECORDED and read the run's verdict (one JSON line) on stdin before closing",
    )
    p.add_argument(
        "--sent-counts",
        action="store_true",
        help="wall time, with --verdict: once stopped, read what each topic's publisher sent on stdin, "
        "record until it is all in (bounded) and count what never came as lost",
    )
    args = p.parse_args(argv)
    die_with_parent()
    stop = Stop()
    stop.install()
    setup_child()  # its records go to the launcher, which logs them
    out = Log(f"[{RECORDER_NAME}]").line
    if args.quiet:  # its warnings and errors still show
        import logging

        from dockhil.log import level_of

        say = out
        out = lambda text: say(text if level_of(text)[0] > logging.INFO else "debug: " + text)  # noqa: E731
    try:
        deadline = time.monotonic() + FIND_GRAPH_TIMEOUT_S
        while True:  # the launcher registers its graph just after starting its processes
            try:
                sources = find_sources(args.topics, args.graph_pid)
                break
            except DockhilError:
                if time.monotonic() > deadline or stop.requested or not _alive(args.graph_pid):
                    raise
                time.sleep(0.02)
        runs = [registered_run(next(iter(sources.values())).run_id, "launch")] if sources else []
        recorder = Recorder(args.path, sources, n_ticks=args.n_ticks, overwrite=args.overwrite, log=out, runs=runs)
    except DockhilError as exc:
        out(f"error: {exc}")
        return 2
    told = None
    if args.verdict:
        from dockhil.bags.tail import Told

        told = Told(sys.stdin)
    print(READY, flush=True)
    out(f"recording {len(sources)} topics to {args.path}")
    run_id = next(iter(sources.values())).run_id if sources else None
    try:
        recorder.run(
            stop, alive=lambda: _alive(args.graph_pid) and (run_id is None or _graph_running(args.graph_pid, run_id))
        )
        if told is not None and args.sent_counts:
            recorder.await_sent(told.sent)
    except DockhilError as exc:  # a publisher that failed authentication: what was recorded is kept
        out(f"error: {exc}")
        recorder.close(why_not_told=f"the recorder stopped: {exc}")
        return 2
    verdict = None
    if told is not None:
        from dockhil.runtime.launcher import RECORDED

        recorder.stop_listening()
        print(RECORDED, flush=True)
        verdict = _read_verdict(told.verdict_line())
    recorder.close(verdict, why_not_told="the launch ended without telling the recorder the run's verdict")
    if recorder.lost:  # a recording that misses messages is not the run: fail, with the count
        out(f"error: {recorder.lost} message(s) lost; the recording of this run is incomplete")
        return RECORDER_LOST_EXIT
    return 0


def _read_verdict(line: str) -> dict[str, str] | None:
    try:
        found = json.loads(line) if line.strip() else None
    except ValueError:
        return None
    return {str(k): str(v) for k, v in found.items()} if isinstance(found, dict) else None


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] != ["record"]:
        print("usage: python -m dockhil.bags.live record PATH --graph-pid PID [--n-ticks N]", file=sys.stderr)
        return 2
    return _recorder_main(argv[1:])


if __name__ == "__main__":
    sys.exit(main())
