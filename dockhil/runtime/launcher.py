"""Start a validated graph as one process per node, watch it, stop it safely.

The launcher assigns each topic an endpoint, hands each node its spec,
logs what each node says under the node's name (dockhil.log: its records,
forwarded at the launcher's level, and any other line it prints), forwards SIGINT and
SIGTERM, and when a node dies stops the rest of the graph and exits non-zero.
While a graph runs, a small JSON file in the runtime directory describes it,
so that `dockhil topic` and `dockhil node` can find it.

Each run gets a private directory (0700) holding its ipc sockets and the
graph's CURVE key file (0600); nodes receive the key file's path in their
spec, never the keys themselves on a command line.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, cast

import msgspec

from dockhil import log
from dockhil.runtime.blame import blame, first_stale
from dockhil.runtime.executor import STALE, TIMING
from dockhil.runtime.plan import ExtraProcess, assign_endpoints, is_local, processes, run_specs
from dockhil.runtime.process import READY
from dockhil.runtime.registry import describe_nodes, describe_subscribers, write_entry

if TYPE_CHECKING:  # the graph module loads the launch-file parser (yaml): a recorder or `dockhil topic` needs neither
    from dockhil.progress import Progress
    from dockhil.runtime.probe import Probe
    from dockhil.scene.graph import Graph

POLL_S = 0.05  # the watch loop's longest sleep when no child speaks or exits
RECORDED = "DOCKHIL-RECORDED"  # a verdict helper has everything on disk and waits for the verdict on stdin
# Wall time, to a verdict helper's stdin once the nodes have exited: this, then JSON topic -> messages its
# publisher sent over the run (sent_counts). The recorder counts what of them never reached it.
SENT = "DOCKHIL-SENT "
END_AFTER_S = 1.0  # a run's end after its end_on state is said: what answered the last commands still arrives
HELPER_WAIT_S = 10.0  # for a helper to finish its recording, and to close it once told the verdict


@dataclass
class _Child:
    name: str
    argv: list[str]
    proc: subprocess.Popen | None = None
    ready: bool = False
    go_sent: bool = False
    respawn: bool = False
    respawn_delay: float = 1.0
    respawn_at: float | None = None  # when a scheduled respawn is due (monotonic)
    finished: bool = False
    host: str = ""  # another machine: started there by hand, not watched from here
    reader: threading.Thread | None = None
    verdict: bool = False  # an ExtraProcess told the run's verdict
    recorded: bool = False  # ... which has said RECORDED
    starts: int = 0  # how many times it was started (a respawned node: more than once)
    reports: int = 0  # ... and how many exit reports (TIMING lines) it gave: a killed node gives none
    sent: dict[str, int] = field(default_factory=dict)  # topic -> messages sent, over all its runs
    stale: dict | None = None  # the input it stopped on as stale (executor.STALE), when ("at") and whose fault


class Launcher:
    def __init__(
        self,
        graph: Graph,
        *,
        clock: str = "sim",
        duration: float | None = None,
        transport: str = "ipc",
        extra: list[ExtraProcess] | None = None,
        progress: bool = False,
        realtime: bool = False,
        judge: Callable[[int], dict] | None = None,
        end_on: tuple[str, str] | None = None,
    ):
        """judge: exit code -> the run's verdict (str -> str), asked once the nodes are done and
        the verdict helpers have recorded everything. end_on: (topic, state): in wall time the run
        ends as at its duration END_AFTER_S after a NodeStatus on that topic says that state."""
        self.graph = graph
        self.judge = judge
        self._sparing = True  # while the graph runs, stopping it leaves the verdict helpers to _judged
        self.clock = clock
        self.extra = extra or []
        dt = graph.scene.dt
        self.n_ticks = None if duration is None else int(round(duration / dt)) + 1
        self.duration = duration
        self.endpoints = assign_endpoints(graph, transport)
        # Wall time: the launcher stops the whole graph at once when the duration is up, so no driver
        # sees its device (an emulator) stop first and mistakes that for a fault.
        self.wall_duration = duration if clock == "wall" else None
        self.end_on = end_on if clock == "wall" else None
        self._end_said_at: float | None = None
        self.units = processes(graph)
        self.specs = run_specs(
            graph, self.endpoints, clock, self.n_ticks if clock == "sim" else None, self.extra, self.units
        )
        # --realtime in wall time: the recorders favoured too (a nice of realtime.RECORD_NICE), or a busy
        # machine leaves them seconds behind the graph, and what a stopped graph still had queued for them
        # never reaches the bag.
        self.realtime_wall = realtime and clock == "wall"
        for name, spec in self.specs.items():
            spec.realtime = realtime
            # Wall time: every local node starts its fixed-rate loop when all are ready, so none runs
            # against nodes still importing or opening devices. (A node on another host cannot be told.)
            members = [graph.nodes[m] for m in self.units[name]]
            spec.wait_for_go = (
                clock == "wall"
                and all(is_local(gn.host) for gn in members)
                and not all(gn.cls.free_running for gn in members)
            )
        self._all_ready_at: float | None = None
        # Set by a child's reader when it says READY or its output ends (it exits): the watch loop
        # wakes at once rather than at its next poll, so a run's end and a wall-time start wait for nothing.
        self._wake = threading.Event()
        self.progress = progress and clock == "sim" and self.n_ticks is not None
        self._stop_signal: int | None = None
        self.children: list[_Child] = []
        self.timings: dict[str, dict] = {}  # wall time: each node's loop figures, reported as it exits
        self._registered = False  # the registry entry is written (a respawn rewrites it)
        # Each respawn: (node, seconds into the run, its exit code). The run goes on, but its data has a gap.
        self.respawns: list[tuple[str, float, int]] = []
        self._started_at = time.monotonic()
        for name, spec in self.specs.items():
            argv = [sys.executable, "-m", "dockhil.process", msgspec.json.encode(spec).decode()]
            gn = graph.nodes[self.units[name][0]]  # a container's members are local and not respawned
            self.children.append(
                _Child(
                    name,
                    argv,
                    respawn=gn.respawn and clock == "wall",
                    respawn_delay=gn.respawn_delay,
                    host="" if is_local(gn.host) else gn.host,
                )
            )
        for proc in self.extra:
            self.children.append(_Child(proc.name, proc.argv, verdict=proc.verdict and judge is not None))

    # -- output ----------------------------------------------------------------
    say = log.Log("[launch]")

    def _read(self, child: _Child, proc: subprocess.Popen) -> None:
        assert proc.stdout is not None  # started with a pipe for it (_start)
        for raw in proc.stdout:
            line = raw.rstrip("\n")
            if line == READY or line == RECORDED:
                child.ready = child.ready or line == READY
                child.recorded = child.recorded or line == RECORDED
                self._wake.set()
                continue
            if line.startswith(STALE):
                try:
                    child.stale = json.loads(line[len(STALE) :])
                    # Whose fault, as the publisher is now: once stopped, it may be resumed, or exit, by the end.
                    child.stale.update(at=time.monotonic(), fault=self._blame(child))
                except ValueError:
                    pass
                continue
            if line.startswith(TIMING):
                try:
                    report = self.timings[child.name] = json.loads(line[len(TIMING) :])
                    for topic, n in (report.get("published") or {}).items():
                        child.sent[topic] = child.sent.get(topic, 0) + int(n)
                    child.reports += 1
                except (ValueError, TypeError, AttributeError):
                    pass
                continue
            log.replay(line, f"[{child.name}]")
        try:  # its output ends as it exits: reap it, so the watch loop it wakes sees the exit code
            proc.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            pass
        self._wake.set()

    # -- processes -------------------------------------------------------------
    def _start(self, child: _Child) -> None:
        env = log.child_env(dict(os.environ, PYTHONUNBUFFERED="1"))
        # Nodes multiply matrices of a few elements: BLAS worker threads would only spin on the shared cores.
        env.setdefault("OPENBLAS_NUM_THREADS", "1")
        child.ready = child.go_sent = False
        child.starts += 1
        child.proc = subprocess.Popen(
            child.argv,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.PIPE if child.verdict else subprocess.DEVNULL,
            text=True,
            bufsize=1,
            start_new_session=True,
            env=env,
        )
        if self.realtime_wall and child.name not in self.specs:
            from dockhil.runtime import realtime

            realtime.favour(child.proc.pid, f"{child.name!r}", self.say.warning)
        elif self.clock == "sim" and child.name not in self.specs:
            from dockhil.runtime import realtime

            realtime.trailing(child.proc.pid)  # the recorder: no tick waits for it
        child.reader = threading.Thread(target=self._read, args=(child, child.proc), daemon=True)
        child.reader.start()
        self.say.debug(f"started {child.name!r} (pid {child.proc.pid})")
        if self._registered:  # a respawned node: its new pid for `node list` and `node info`
            self._write_registry()

    def _announce_remote(self, child: _Child) -> None:
        """A node on another machine: say how to start it there. Sim time waits for it as for any
        subscriber; its exit is not seen from here."""
        import shlex

        child.ready = child.finished = True
        keys = self.endpoints.key_file
        argv = ["python3", "-m", "dockhil.process", "--keys", str(keys), *child.argv[3:]]
        command = " ".join(shlex.quote(a) for a in argv)
        # Warning level: the graph waits for this node, so the line shows at any --log-level but error.
        self.say.warning(
            f"node {child.name!r} runs on {child.host}: copy the key file {keys} to the same path "
            f"there (mode 0600, over a private channel such as scp) and start it there with: {command}",
            tag="",
        )

    def _write_registry(self) -> Path:
        from dockhil.scene.provenance import run_fields, scene_texts

        scene = self.graph.scene
        readers = describe_subscribers(self.graph, self.extra)
        info = {
            # What a recorder writes first in its bag (dockhil.bags.runinfo), for the launch's and any other.
            "run": run_fields(
                scene, clock=self.clock, duration=self.duration, started_ns=self.started_ns, recorded_by="launch"
            ),
            "scene_files": scene_texts(scene),
            "run_id": self.endpoints.run_id,
            "pid": os.getpid(),
            "file": self.graph.scene.path,
            "clock": self.clock,
            "keys": str(self.endpoints.key_file),
            "nodes": {
                c.name: {
                    "type": self.specs[c.name].type_name if c.name in self.specs else "process",
                    "pid": c.proc.pid if c.proc else None,
                    "members": self.units.get(c.name, [c.name]),
                }
                for c in self.children
            },
            "topics": {
                t: {
                    "type": self.endpoints.types[t],
                    "endpoint": e,
                    "publisher": self.graph.publishers[t].node,
                    "subscribers": readers.get(t, []),
                }
                for t, e in self.endpoints.topics.items()
            },
            "graph_nodes": describe_nodes(self.graph, self.units),  # each node's ports and parameters
            # Inputs with no publisher at launch (an e-stop): nothing started later reaches them.
            "unconnected": {
                t: [f"{r.node}.{r.port}" for r in self.graph.unconnected if r.topic == t]
                for t in {r.topic for r in self.graph.unconnected}
            },
        }
        path = write_entry(info)
        self._registered = True
        return path

    def devices(self) -> dict[str, bool]:
        """Wall time: the local processes that report loop figures, each mapped to whether it
        stands for a device emulator (a container: when all its members do)."""
        return {child.name: self._is_emulator(child) for child in self.children[: len(self.specs)] if not child.host}

    def sent_counts(self) -> dict[str, int]:
        """Wall time, once the nodes have exited: topic -> messages its publisher's socket took over
        the run (a respawned node's runs added up), from the nodes' exit reports. A node that did not
        report every time it ran (killed, or on another host) leaves its topics out: what it sent is
        not known, and the recorder waits for none of it."""
        out: dict[str, int] = {}
        for child in self.children:
            if child.name in self.specs and not child.host and child.reports == child.starts:
                out.update(child.sent)
        return out

    def _tell_sent(self, helpers: list[_Child]) -> None:
        """Wall time: tell the verdict helpers (the recorder) what each topic's publisher sent, once
        every node's exit report is read, so that a recorder that fell behind waits for the rest and
        counts what never came (dockhil.bags.live). Sim time is lock-step: its recorder has every
        tick when it finishes, and is told nothing."""
        for child in self.children:
            if child.name in self.specs and child.reader is not None:
                child.reader.join(timeout=1.0)  # the node exited: its output ends
        line = SENT + json.dumps(self.sent_counts()) + "\n"
        for c in helpers:
            proc = c.proc
            if proc is not None and proc.poll() is None and proc.stdin is not None:
                try:
                    proc.stdin.write(line)
                    proc.stdin.flush()
                except OSError:  # it exited meanwhile: its exit code says why
                    pass

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        self._stop_signal = signum

    def _is_emulator(self, child: _Child) -> bool:
        return child.name in self.units and all(self.graph.nodes[m].cls.free_running for m in self.units[child.name])

    def stop_all(self, grace: float = 3.0) -> None:
        """SIGTERM every child and wait for it (then kill it). Drivers before the emulated devices they
        talk to: a device gone first fails its driver while it stops (a closed link) and leaves its robot
        unheld. A verdict helper, while the graph runs, is only told to stop recording: it waits for the
        verdict (`_judged`); else its stdin closes too."""
        live = [c for c in self.children if c.proc and c.proc.poll() is None]
        for c in [c for c in live if c.verdict]:
            if self._sparing:
                live.remove(c)
                if not c.recorded:
                    assert c.proc is not None  # live ones only
                    c.proc.send_signal(signal.SIGTERM)
            else:
                self._close_stdin(c)
        devices = {name for name, device in self.devices().items() if device}
        self._stop([c for c in live if c.name not in devices], grace)
        self._stop([c for c in live if c.name in devices], grace)

    def _stop(self, live: list, grace: float) -> None:
        from dockhil.runtime import realtime

        with realtime.signalling(self.realtime_wall):
            for c in live:
                try:
                    c.proc.send_signal(signal.SIGTERM)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + grace
        for c in live:
            try:
                c.proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.say.warning(f"node {c.name!r} did not stop within {grace:.0f} s; killing it")
                c.proc.kill()
                c.proc.wait()

    def run(self) -> int:
        """Run until every node finishes, a node dies, or a signal arrives. Returns the exit code."""
        old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        registry = None
        self.started_ns = time.time_ns()
        try:
            for child in self.children:
                if child.host:
                    self._announce_remote(child)
                else:
                    self._start(child)
            registry = self._write_registry()
            return self._judged(self._watch())
        finally:
            self._sparing = False
            self.stop_all()
            for child in self.children:
                if child.reader:
                    child.reader.join(timeout=1.0)
            for s, h in old.items():
                signal.signal(s, h)
            if registry is not None:
                registry.unlink(missing_ok=True)
            shutil.rmtree(self.endpoints.run_dir, ignore_errors=True)

    def _probe(self, topic: str) -> Probe:
        from dockhil.runtime.probe import Probe

        return Probe(self.endpoints.topics[topic], cast(Path, self.endpoints.key_file))  # plan() wrote the keys

    def _watch(self) -> int:
        bar = None
        probes: dict[str, Probe] = {}
        if self.progress and self.endpoints.topics:
            from dockhil.progress import Progress

            probes["progress"] = self._probe(next(iter(self.endpoints.topics)))
            bar = Progress(self.n_ticks, self.graph.scene.dt)
        if self.end_on is not None:
            probes["end"] = self._probe(self.end_on[0])
        try:
            return self._watch_children(probes, bar)
        finally:
            if bar is not None:
                bar.done()
            for probe in probes.values():
                probe.close()

    def _send_go(self) -> None:
        """Wall time: once every node is ready, tell each waiting one to start (again, after a respawn)."""
        nodes = [c for c in self.children if c.name in self.specs]
        if not all(c.ready for c in nodes):
            return
        from dockhil.runtime import realtime

        waiting = [c for c in nodes if c.proc is not None and not c.go_sent and self.specs[c.name].wait_for_go]
        if waiting:
            with realtime.signalling(self.realtime_wall):
                for c in waiting:
                    c.go_sent = True
                    assert c.proc is not None  # waiting ones only
                    try:
                        c.proc.send_signal(signal.SIGUSR1)
                    except ProcessLookupError:
                        pass
        if self._all_ready_at is None:
            self._all_ready_at = time.monotonic()

    def _duration_over(self, end: Probe | None) -> bool:
        if self.clock == "wall":
            self._send_go()
        if self.wall_duration is None or self._all_ready_at is None:
            return False
        now = time.monotonic()
        if end is not None and self.end_on is not None and self._end_said_at is None:
            end.read(status=True)
            if self.end_on[1] in end.states:
                self._end_said_at = now
                self.say.info(f"{self.end_on[0]} says {self.end_on[1]!r}: the run ends in {END_AFTER_S:g} s")
        if self._end_said_at is not None and now - self._end_said_at >= END_AFTER_S:
            return True
        return now - self._all_ready_at >= self.wall_duration

    def _stop_at_duration(self) -> int:
        self.stop_all()
        # A node still starting (a respawn under way) has no handler yet: our SIGTERM ends it, no fault of its own.
        failed = [
            c
            for c in self.children
            if c.proc
            and c.proc.returncode not in (0, None)
            and not (c.proc.returncode == -signal.SIGTERM and not c.ready)
        ]
        for c in failed:
            assert c.proc is not None  # failed ones only
            self.say.error(f"{c.name!r} exited with code {c.proc.returncode} while stopping", tag="")
        return 1 if failed else 0

    def _watch_children(self, probes: dict[str, Probe], bar: Progress | None) -> int:
        while True:
            self._wake.clear()  # before looking: what happens from here on wakes the wait below
            if bar is not None:  # made with its probe (_watch)
                probes["progress"].read()
                if probes["progress"].tick is not None:
                    bar.update(probes["progress"].tick + 1)
            if self._duration_over(probes.get("end")):
                return self._stop_at_duration()
            if self._stop_signal is not None:
                name = signal.Signals(self._stop_signal).name
                self.say.info(f"{name}: stopping the graph")
                self.stop_all()
                return 128 + self._stop_signal
            nodes_running = 0
            for child in self.children:
                if child.finished:
                    continue
                if child.respawn_at is not None:  # waiting to respawn: supervision goes on meanwhile
                    nodes_running += 1
                    if time.monotonic() >= child.respawn_at:
                        child.respawn_at = None
                        self._start(child)
                    continue
                assert child.proc is not None  # started, or on another host and so finished
                code = child.proc.poll()
                is_node = child.name in self.specs
                if code is None:
                    nodes_running += is_node
                    continue
                if child.reader:
                    child.reader.join(timeout=1.0)
                if code == 0:
                    child.finished = True
                    if is_node and self.clock == "wall":
                        # In wall time nodes run until the launcher stops them; an exit is a death.
                        return self._died(child, code)
                    continue
                if child.respawn and child.ready:
                    self.say.warning(
                        f"node {child.name!r} exited with code {code}; respawning in {child.respawn_delay:g} s", tag=""
                    )
                    child.respawn_at = time.monotonic() + child.respawn_delay
                    self.respawns.append(
                        (child.name, time.monotonic() - (self._all_ready_at or self._started_at), code)
                    )
                    nodes_running += 1
                    continue
                return self._died(child, code)
            if nodes_running == 0:
                return self._finish_extras()
            self._wake.wait(POLL_S)  # signals, respawns, progress and the wall-time duration: every POLL_S

    def _finish_extras(self, timeout: float = HELPER_WAIT_S) -> int:
        """Nodes are done: give helper processes (a recorder draining its queue) time to exit."""
        deadline = time.monotonic() + timeout
        for child in self.children:
            if child.name in self.specs or child.finished or child.verdict:
                continue
            assert child.proc is not None  # every helper runs here
            if self.clock == "wall":
                child.proc.send_signal(signal.SIGTERM)  # wall-time helpers run until told
            code = self._exited(child, deadline, timeout)
            if code is None:
                return 1
            if code != 0:
                return self._died(child, code)
        return 0

    def _exited(self, child: _Child, deadline: float, timeout: float) -> int | None:
        """The helper's exit code once it exits before `deadline`; None (said) if it does not."""
        assert child.proc is not None  # a started helper
        try:
            code = child.proc.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            self.say.error(f"{child.name!r} did not finish within {timeout:.0f} s; stopping it")
            return None
        child.finished = True
        return code

    def _judged(self, code: int) -> int:
        """The verdict helpers: once each has recorded everything, the run's verdict (`judge`) to each,
        then their exit. A helper that fails here fails the run (exit 1), as when it dies before."""
        helpers = [c for c in self.children if c.verdict and c.proc and not c.finished]
        if not helpers:
            return code
        if self.clock == "wall" or code != 0:
            self.stop_all()  # stops their recording; they keep the bag open for the verdict
        if self.clock == "wall":
            self._tell_sent(helpers)
        deadline = time.monotonic() + HELPER_WAIT_S
        while not all(c.recorded or c.proc.poll() is not None for c in helpers) and time.monotonic() < deadline:  # type: ignore[union-attr]  # helpers are started
            self._wake.clear()
            self._wake.wait(POLL_S)
        late = [c for c in helpers if not c.recorded and c.proc.poll() is None]  # type: ignore[union-attr]  # started
        if late and code == 0:  # its bag is not the whole run yet: no verdict is drawn from it
            self.say.error(f"{late[0].name!r} did not finish recording within {HELPER_WAIT_S:.0f} s; stopping it")
            code = 1
        assert self.judge is not None  # a helper is told the verdict only where there is a judge
        verdict = json.dumps(self.judge(code)) + "\n"
        deadline = time.monotonic() + HELPER_WAIT_S  # the judge may have read a long bag meanwhile
        for c in helpers:
            assert c.proc is not None and c.proc.stdin is not None  # started, with a pipe to its stdin
            if c.recorded and c.proc.poll() is None:
                try:
                    c.proc.stdin.write(verdict)
                except OSError:
                    pass
            self._close_stdin(c)
            exit_code = self._exited(c, deadline, HELPER_WAIT_S)
            if exit_code is None:
                return 1
            if exit_code != 0 and code == 0:  # the graph has stopped: nothing to stop, the line above says why
                self.say.error(f"node {c.name!r} exited with code {exit_code} after the run", tag="")
                return 1
        return code

    @staticmethod
    def _close_stdin(child: _Child) -> None:
        assert child.proc is not None  # a started helper
        try:
            if child.proc.stdin is not None:
                child.proc.stdin.close()
        except OSError:  # it exited: nothing to tell it
            pass

    def _blame(self, child: _Child) -> str:
        """Whose fault the stale input `child` stopped on was (runtime/blame.py)."""
        stale = child.stale
        pub = next((c for c in self.children if stale and c.name == stale.get("publisher")), None)
        return blame(stale, pub.name, pub.proc) if pub is not None and pub.proc is not None and stale else ""

    def _died(self, child: _Child, code: int) -> int:
        first = first_stale(child, self.children)  # a stalled node, resumed, finds its own inputs stale too
        child, code = first, (code if first is child else cast(int, cast(subprocess.Popen, first.proc).poll()))
        how = f"was killed by {signal.Signals(-code).name}" if code < 0 else f"exited with code {code}"
        when = "while running" if child.ready else "at start"
        fault = child.stale["fault"] if child.stale and "fault" in child.stale else self._blame(child)
        self.say.error(f"node {child.name!r} {how} {when}{fault}; stopping the graph", tag="")
        if not child.ready:
            # Let nodes still opening devices finish, so every missing device gets its own line.
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and any(
                c.proc and c.proc.poll() is None and not c.ready for c in self.children if c is not child
            ):
                time.sleep(0.05)
        self.stop_all()
        return 1
