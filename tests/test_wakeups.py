"""What a tick of a graph of processes costs the scheduler, counted, not timed: each node counts its
threads' context switches from /proc over its ticks (dockhil.runtime.switches, in its loop figures).

In sim time a lock-step node's loop blocks once a tick for the message it computes from, and its
ZeroMQ I/O thread wakes once for each message that comes in and once for each that goes out to a
reader waiting for it: three wake-ups a tick for hil.yaml's dynamics and impedance, which hand each
other one message each way. What no tick waits for (the recorder's copies, the delayed robot's and
the F/T sensor's bursts) goes out in bursts and adds a fraction. A recorder served on the graph's
own sockets woke the publishers' I/O threads once more per message (impedance: 4.4 a tick)."""

from __future__ import annotations

import json
import os
import subprocess
import threading
import time

from dockhil.bags.reader import BagReader
from dockhil.runtime import switches
from dockhil.runtime.keys import name_os_thread
from tests.conftest import dockhil_cmd

TICKS = 1000
# node -> (messages a tick its loop waits for, messages a tick it sends to a reader that waits): one
# wake-up of its loop a tick, one of its I/O thread per message.
LOCK_STEP = {
    "dynamics": (1, 1),  # waits for /impedance/wrench, sends /satellite/state
    "impedance": (1, 1),  # waits for /satellite/state, sends /impedance/wrench
}
BURSTS = 0.5  # a tick's share of the wake-ups for what goes in bursts (F/T, robot command, the recorder's)


def test_a_lock_step_node_wakes_once_a_tick_and_once_per_message_with_a_recorder(tmp_path):
    reports, bag = tmp_path / "reports", tmp_path / "run.mcap"
    reports.mkdir()
    r = subprocess.run(
        dockhil_cmd("launch", "hil.yaml", "--duration", f"{(TICKS - 1) * 1e-3:g}", "--bag", bag, "--quiet"),
        env=dict(os.environ, DOCKHIL_TIMING_DIR=str(reports)),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    # The recorder, which no tick waits for, still has every tick of every topic.
    with BagReader(bag) as reader:
        topics = {t["topic"]: t["count"] for t in reader.summary()["topics"]}
    assert topics["/impedance/wrench"] == topics["/satellite/state"] == topics["/energy"] == TICKS, topics
    for node, (waits, sends) in LOCK_STEP.items():
        report = json.loads((reports / f"{node}.json").read_text())
        assert report["ticks"] == TICKS
        by_thread = report["switches"]
        assert {"main", "ZMQbg/IO/0"} <= set(by_thread), by_thread
        wakeups = sum(voluntary for voluntary, _ in by_thread.values()) / TICKS
        bound = 1 + waits + sends + BURSTS
        per_thread = {name: round(v / TICKS, 2) for name, (v, _) in by_thread.items()}
        assert wakeups <= bound, f"{node}: {wakeups:.2f} wake-ups a tick > {bound}: {per_thread}"
        assert by_thread["main"][0] / TICKS <= 1 + BURSTS / 2, per_thread  # its loop: once a tick


def test_a_threads_wake_ups_are_counted_under_its_name():
    """Twenty sleeps of a named thread are twenty voluntary switches of that name (and a few for its
    start and its wait); the other threads' counts do not go down."""
    slept, measured = threading.Event(), threading.Event()

    def sleeper() -> None:
        name_os_thread("wakeup-test")
        for _ in range(20):
            time.sleep(0.001)
        slept.set()
        measured.wait()

    before = switches.by_thread()
    thread = threading.Thread(target=sleeper)
    thread.start()
    try:
        assert slept.wait(30)
        after = switches.by_thread()
    finally:
        measured.set()
        thread.join()
    counted = switches.since(before, after)
    assert 20 <= counted["wakeup-test"][0] <= 30, counted
    assert all(v >= 0 and n >= 0 for v, n in counted.values()), counted


def test_a_trailing_reader_gets_every_frame_in_bursts_apart_from_the_members(tmp_path):
    """A trailing reader (the launch's recorder) is counted at the start barrier with the members, gets
    nothing while fewer than TRAIL_BURST frames are held, then every frame in order, messages and
    empty ticks alike, and the rest when the run's end sends it; a member reads the graph's socket and
    gets each message at once, and no trailing frame."""
    import zmq

    from dockhil.runtime.transport import EMPTY_TICK, MESSAGE, TRAIL_BURST, GraphKeys, Publisher, Subscriber

    ctx = zmq.Context.instance()
    endpoint, keys = f"ipc://{tmp_path}/t", GraphKeys.make()
    pub = Publisher(ctx, "/t", endpoint, keys=keys, trailing=True)
    member, trailing = Subscriber(ctx), Subscriber(ctx, trailing=True)
    for sub in (member, trailing):
        sub.connect(endpoint, keys=keys)
    try:
        pub.wait_subscribers(2, 20.0)
        assert (pub.subscribers, pub.trailing_readers) == (2, 1)
        frames = []
        for k in range(TRAIL_BURST + 10):
            if k % 3:
                payload = k.to_bytes(2, "little")
                pub.send(payload)
                frames.append(b"/t" + MESSAGE + payload)
            else:
                pub.send_empty(k)
                frames.append(b"/t" + EMPTY_TICK + k.to_bytes(8, "little"))
            if k == TRAIL_BURST - 2:
                assert trailing.recv_frame(0.1) is None  # held: one short of a burst
        assert [member.recv_frame(5.0) for _ in frames] == frames  # each at once, in order
        assert [trailing.recv_frame(5.0) for _ in range(TRAIL_BURST)] == frames[:TRAIL_BURST]
        assert trailing.recv_frame(0.1) is None  # the last 10 held until the run ends
        pub.flush_trailing()
        assert [trailing.recv_frame(5.0) for _ in range(10)] == frames[TRAIL_BURST:]
        assert member.recv_frame(0.1) is None and trailing.recv_frame(0.1) is None  # nothing twice, nothing crossed
    finally:
        for s in (member, trailing, pub):
            s.close()


def test_a_trailing_readers_threads_are_put_under_sched_batch():
    """Sim time: the launcher puts every thread of the recorder's process under SCHED_BATCH (no tick
    waits for it, and a batch thread's wake-up never preempts a lock-step node); a thread it makes
    afterwards inherits the policy."""
    import sys

    from dockhil.runtime import realtime

    child = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import os, sys, threading, time\n"
            "threading.Thread(target=time.sleep, args=(30,), daemon=True).start()\n"
            "print('up', flush=True)\n"
            "sys.stdin.readline()\n"
            "threading.Thread(target=time.sleep, args=(30,), daemon=True).start()\n"
            "print(len(os.listdir('/proc/self/task')), flush=True)\n"
            "time.sleep(30)\n",
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout.readline().strip() == "up"
        before = os.listdir(f"/proc/{child.pid}/task")
        assert len(before) == 2 and all(os.sched_getscheduler(int(t)) == os.SCHED_OTHER for t in before)
        assert realtime.trailing(child.pid)
        child.stdin.write("go\n")
        child.stdin.flush()
        assert child.stdout.readline().strip() == "3"
        tids = os.listdir(f"/proc/{child.pid}/task")
        assert len(tids) == 3 and all(os.sched_getscheduler(int(t)) == os.SCHED_BATCH for t in tids), tids
    finally:
        child.kill()
        child.wait()
    assert not realtime.trailing(child.pid)  # gone: nothing to set, no error


def test_a_sim_time_nodes_zeromq_io_threads_are_niced_and_its_loop_is_not():
    """Sim time: each node process's ZeroMQ I/O threads get a nice of IO_NICE (the executor, once its
    sockets started them), so that the wake-up carrying a send does not preempt the loop that sent it;
    the loop's own thread keeps its priority."""
    import sys

    from dockhil.runtime import realtime

    script = (
        "import json, os, zmq\n"
        "from dockhil.runtime import realtime\n"
        "sock = zmq.Context.instance().socket(zmq.PUB)\n"  # starts the I/O thread
        "lowered = realtime.lower_io_threads()\n"
        "nice = {}\n"
        "for tid in os.listdir('/proc/self/task'):\n"
        "    name = open(f'/proc/self/task/{tid}/comm').read().strip()\n"
        "    nice[name if int(tid) != os.getpid() else 'main'] = os.getpriority(os.PRIO_PROCESS, int(tid))\n"
        "print(json.dumps({'lowered': lowered, 'nice': nice}))\n"
        "sock.close(0)\n"
    )
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    own = os.getpriority(os.PRIO_PROCESS, 0)
    assert out["lowered"] and out["nice"]["ZMQbg/IO/0"] == max(own, realtime.IO_NICE), out
    assert out["nice"]["main"] == own, out
