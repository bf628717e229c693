"""An observer (`topic echo` and `hz`, `bag record` from outside, the Foxglove bridge) may lose its
own messages, never the graph's: one that stops reading (a pager left open) neither slows nor
drops the graph's deliveries to its members; it loses its own, counts them and says so."""

import os
import signal
import subprocess
import time

import pytest
import zmq

from dockhil.runtime import transport
from dockhil.runtime.transport import GraphKeys, Publisher, Subscriber
from tests.conftest import dockhil_cmd, registered


@pytest.fixture
def small_queues(monkeypatch):
    """Small queues, so that an unread reader fills its own in a second, not in 45 s. (A graph
    member's may not be much smaller: a publisher sending in a burst learns of what was read only
    about every millisecond.)"""
    monkeypatch.setattr(transport, "HWM", 1000)
    monkeypatch.setattr(transport, "OBSERVER_HWM", 20)


def joined(pub: Publisher, member: bool, observer: bool, timeout: float = 20.0) -> None:
    """Until the publisher has seen the member's and the observer's subscriptions (on its two sockets)."""
    deadline = time.monotonic() + timeout
    while member and not (pub.sock.poll(20) and pub.sock.recv()[:1] == b"\x01"):
        assert time.monotonic() < deadline, "the member never joined"
    while observer and not pub.look():
        assert time.monotonic() < deadline, "the observer never joined"
        time.sleep(0.01)


def flood(pub: Publisher, member: Subscriber, n: int) -> list[bytes]:
    """Publish n messages, the member reading as it goes and never more than a quarter of its queue
    behind (a node that keeps up, as a graph's does: a publisher learns of what was read only every
    half queue); what it read."""
    got = []
    for k in range(n):
        pub.send(k.to_bytes(4, "little") + bytes(60))
        while (frames := member.recv_nowait()) is not None:
            got.append(frames[1][:4])
        while k + 1 - pub.dropped - len(got) > transport.HWM // 4 and (frames := member.recv(2.0)) is not None:
            got.append(frames[1][:4])
    while len(got) < n - pub.dropped and (frames := member.recv(2.0)) is not None:
        got.append(frames[1][:4])
    return got


@pytest.mark.parametrize("lossy", [True, False], ids=["wall-time", "sim-time"])
def test_an_unread_observer_loses_its_own_messages_and_the_graph_none(tmp_path, small_queues, lossy):
    ctx = zmq.Context.instance()
    keys = GraphKeys.make()
    endpoint = f"ipc://{tmp_path}/t"
    pub = Publisher(ctx, "/t", endpoint, keys=keys, lossy=lossy)
    pub.sock.setsockopt(zmq.SNDTIMEO, 10_000)  # sim time: a send that waited for the observer fails, not hangs
    member, observer = Subscriber(ctx), Subscriber(ctx, observer=True)
    try:
        for sub in (member, observer):
            sub.connect(endpoint, keys=keys)
        joined(pub, member=True, observer=True)
        n = 20_000  # far more than the observer's queues and its socket's kernel buffer hold
        got = flood(pub, member, n)
        assert pub.dropped == 0 and got == [k.to_bytes(4, "little") for k in range(n)]
        read = 0
        while observer.recv(0.5) is not None:  # now it reads: what its queues kept, then nothing
            read += 1
        pub.send(n.to_bytes(4, "little") + bytes(60))  # one more, so the gap before it shows
        assert observer.recv(5.0)[1][:4] == n.to_bytes(4, "little")
        read += 1
        assert 0 < read < n / 2 and observer.lost == n + 1 - read and observer.lost_on == {b"/t": observer.lost}
        print(
            f"graph member: {len(got)} of {n} delivered, publisher dropped {pub.dropped}; "
            f"observer read {read}, lost {observer.lost}"
        )
    finally:
        for s in (pub, member, observer):
            s.close()


def test_an_unread_member_is_the_graphs_business(tmp_path, small_queues):
    """The contrast that makes the observer's socket necessary: a graph member that stops reading
    (wall time) makes its publisher drop, counted, so the run is judged on it."""
    ctx = zmq.Context.instance()
    keys = GraphKeys.make()
    endpoint = f"ipc://{tmp_path}/t"
    pub = Publisher(ctx, "/t", endpoint, keys=keys, lossy=True)
    member, stuck = Subscriber(ctx), Subscriber(ctx)
    try:
        for sub in (member, stuck):
            sub.connect(endpoint, keys=keys)
        pub.wait_subscribers(2, 20.0)
        got = flood(pub, member, 20_000)
        assert pub.dropped > 0 and len(got) == 20_000 - pub.dropped
    finally:
        for s in (pub, member, stuck):
            s.close()


def test_an_observer_frame_carries_the_count_and_reads_as_the_message(tmp_path):
    """[topic, payload] as a member reads it; a count that starts again (a respawned publisher) is no loss."""
    ctx = zmq.Context.instance()
    observer = Subscriber(ctx, observer=True)
    try:
        frame = b"/a/b" + transport.OBSERVED
        assert observer._message(frame + (7).to_bytes(8, "little") + b"\x81\xa1a\x01") == [b"/a/b", b"\x81\xa1a\x01"]
        assert observer._message(frame + (10).to_bytes(8, "little") + b"\x80") == [b"/a/b", b"\x80"]
        assert observer.lost == 2
        assert observer._message(frame + (1).to_bytes(8, "little") + b"\x80") == [b"/a/b", b"\x80"]
        assert observer._message(b"/a/b" + transport.EMPTY_TICK + (2).to_bytes(8, "little")) == [
            b"/a/b",
            b"",
            (2).to_bytes(8, "little"),
        ]
        assert observer.lost == 2
    finally:
        observer.close()


def test_observer_endpoints_never_meet_a_topics():
    assert transport.observer_endpoint("ipc:///run/x/a.b") == "ipc:///run/x/a.b+observers"
    assert transport.observer_endpoint("tcp://10.0.0.2:5601") == "tcp://10.0.0.2:5602"
    assert transport.observer_endpoint("tcp://127.0.0.1:0") == "tcp://127.0.0.1:0"


def echo_beside_a_wall_time_run(tmp_path, attempt: int) -> tuple[int, str, int | None, str]:
    """hil.yaml in wall time with an echo of /satellite/state whose stdout nobody reads: the run's
    exit code and log, the echo's exit code and what it said."""
    log_path, err_path = tmp_path / f"launch-{attempt}.log", tmp_path / f"echo-{attempt}.err"
    run = subprocess.Popen(
        dockhil_cmd("launch", "launch/hil.yaml", "--wall-time", "--duration", "20", "rate:=250"),
        stdout=open(log_path, "w"),
        stderr=subprocess.STDOUT,
    )
    echo = None
    try:
        run_id = registered(run.pid, timeout=30)["run_id"]
        echo = subprocess.Popen(
            dockhil_cmd("topic", "echo", "/satellite/state", "--graph", run_id),
            stdout=subprocess.PIPE,
            stderr=open(err_path, "w"),
        )
        code = run.wait(timeout=90)
        echo_code = echo.wait(timeout=30)  # its output blocked, it still sees the graph end
        return code, log_path.read_text(), echo_code, err_path.read_text()
    finally:
        for p in (run, echo):
            if p is not None and p.poll() is None:
                os.kill(p.pid, signal.SIGKILL)
                p.wait()
        if echo is not None:
            echo.stdout.close()


@pytest.mark.wall_time
def test_a_topic_echo_nobody_reads_leaves_a_wall_time_run_valid(tmp_path):
    """`dockhil launch launch/hil.yaml --wall-time` beside `dockhil topic echo /satellite/state`
    whose stdout pipe is never read: the run ends valid (exit 0: no node dropped a message), and
    the echo, seeing the graph end, says how many messages it lost (its pipe, its own queues and
    its socket's buffer hold about 3000: 20 s at 250 Hz, the rate a busy 2-core machine keeps in
    real time, overflow them). A busy machine may pause every process for 0.1 s, which stops the
    graph on a stale input with or without an echo: then the run is tried once more."""
    code, log, echo_code, said = echo_beside_a_wall_time_run(tmp_path, 1)
    if code == 1 and "old > max_age" in log:
        code, log, echo_code, said = echo_beside_a_wall_time_run(tmp_path, 2)
    assert code == 0, log
    assert echo_code == 0 and "ended" in said and "message(s) lost by this echo" in said, said
    lost = int(said.split("/satellite/state: ")[1].split()[0])
    print(f"graph valid (no node dropped a message); echo lost {lost}")
    assert lost > 0


def _recorder(tmp_path, observer: bool):
    """A Recorder of /ft/wrench from a wall-time publisher in this process, as a graph member or an observer."""
    from dockhil.bags.live import Recorder, Source

    keys = GraphKeys.make()
    key_file = keys.write(tmp_path / f"graph-{observer}.keys")
    endpoint = f"ipc://{tmp_path}/ft.wrench"
    pub = Publisher(zmq.Context.instance(), "/ft/wrench", endpoint, keys=keys, lossy=True)
    lines: list[str] = []
    source = Source("/ft/wrench", endpoint, "dockhil/WrenchStamped", False, os.getpid(), "r", str(key_file))
    rec = Recorder(str(tmp_path / f"rec-{observer}.mcap"), {"/ft/wrench": source}, log=lines.append, observer=observer)
    joined(pub, member=not observer, observer=observer)
    return pub, rec, lines


def wrench(k: int) -> bytes:
    from dockhil.msgs import Header, WrenchStamped
    from dockhil.msgs.codec import encode

    return encode(WrenchStamped(header=Header(stamp=1.0 + k * 0.001, tick=k, seq=k)))


def test_a_wall_time_node_that_publishes_every_other_tick_loses_nothing(tmp_path):
    """header.seq is the tick: an F/T driver with no new sample at a tick publishes nothing (as
    ft_can does), so its seq skips numbers though every message arrives. No loss is claimed."""
    pub, rec, lines = _recorder(tmp_path, observer=False)
    try:
        for k in range(0, 200, 2):
            pub.send(wrench(k))
        while rec.received < 100 and (frames := rec.sub.recv(5.0)) is not None:
            rec.handle(frames)
    finally:
        line = rec.close()
        pub.close()
    assert rec.received == 100 and rec.lost == 0
    assert line.endswith("on 1 topics to " + str(tmp_path / "rec-False.mcap") + "; 0 lost"), line


def test_a_recorder_from_outside_that_falls_behind_counts_what_it_lost(tmp_path, small_queues):
    pub, rec, lines = _recorder(tmp_path, observer=True)
    n = 20_000
    try:
        for k in range(n):  # the recorder reads none of them yet
            pub.send(wrench(k))
        rec.drain()
        pub.send(wrench(n))  # the gap before it shows
        while (frames := rec.sub.recv(5.0)) is not None:
            rec.handle(frames)
            if rec.received + rec.sub.lost == n + 1:
                break
    finally:
        line = rec.close()
        pub.close()
    assert pub.dropped == 0 and 0 < rec.received < n / 2 and rec.lost == rec.sub.lost == n + 1 - rec.received
    assert f"; {rec.lost} lost ({rec.lost} not taken in time: recording from outside the graph" in line, line
