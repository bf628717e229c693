"""Every device's driver set up against its emulator in this process, built one way for the contract
every driver keeps (tests/test_device_contract.py): a `Rig` starts the emulator, sets the driver up
in graph GRAPH and steps it on a ManualClock the test advances, one period a step. The devices run
on their own clocks (the emulators' threads, the drivers' receive and link threads): where a test
waits for one, it waits for the outcome, with a deadline.

Each rig says how its device is silenced, how a malformed and a foreign datagram or frame reach the
driver (or the controller), and where it counts them.
"""

from __future__ import annotations

import contextlib
import itertools
import socket
import struct
import threading
import time

from dockhil.devices.ati_netft import protocol as rdt
from dockhil.devices.ati_netft.driver import FtNetFtDriver
from dockhil.devices.ati_netft.emulator import ContactModel, NetFtBox
from dockhil.devices.ati_netft.emulator_node import NetFtEmulator
from dockhil.devices.can_ft import frames as ff
from dockhil.devices.can_ft.driver import FtCanDriver
from dockhil.devices.can_ft.emulator import FtSensorEmulator
from dockhil.devices.kuka_rsi import protocol as rsi
from dockhil.devices.kuka_rsi.driver import RobotRsiDriver
from dockhil.devices.kuka_rsi.emulator import START_POSE, RsiControllerEmulator
from dockhil.devices.kuka_rsi.emulator_node import RsiControllerEmulatorNode
from dockhil.devices.modbus_robot import registers as mm
from dockhil.devices.modbus_robot.driver import RobotModbusDriver
from dockhil.devices.modbus_robot.emulator_node import RobotControllerEmulatorNode
from dockhil.msgs import Header, Pose, RobotCommand, Twist, Vector3, Wrench, WrenchStamped
from dockhil.node import ManualClock, Node, NodeContext, Tick
from dockhil.runtime import ownership
from tests.conftest import free_port, udp_port, wait_for

GRAPH, OTHER_GRAPH = "contract-one", "contract-two"  # the graph that owns the device, and one that may not
DT = 0.001  # s: the driver's period, and how far each step moves its clock
STALE = 0.3  # s: each device's stale data or controller timeout here
_channels = itertools.count()


@contextlib.contextmanager
def in_graph(run_id: str):
    """Claim devices as a node of graph `run_id` does (the node process sets it from its spec)."""
    ownership.set_graph(run_id)
    try:
        yield
    finally:
        ownership.set_graph("")


class Rig:
    """One driver set up against its device's emulator; the test steps it (`step`, `until`)."""

    name: str
    robot = False
    published: str  # the output port whose message shows what the device measured
    driver: Node

    def __init__(self) -> None:
        self.clock = ManualClock(100.0)
        self.logs: list[str] = []
        self.k = 0
        self.fresh_at: float | None = None  # the driver's time of the last step that published
        self._built: list[Node] = []

    # -- the device's part ------------------------------------------------------------
    def start_emulator(self) -> None:
        raise NotImplementedError

    def build(self, logs: list[str] | None = None) -> Node:
        """A driver of this device (not set up), logging to `logs` (the rig's own by default)."""
        raise NotImplementedError

    def silence(self) -> None:
        """The device stops sending (the box stops streaming, the controller stops, the sensor is quiet)."""
        raise NotImplementedError

    def send_malformed(self) -> None:
        raise NotImplementedError

    def send_foreign(self) -> None:
        raise NotImplementedError

    def rejected(self) -> dict[str, int | None]:
        """What the driver (or the controller) counted of those: {'malformed': n, 'foreign': n}; None
        where the device does not count that kind (the test says why)."""
        raise NotImplementedError

    def stop_emulator(self) -> None:
        raise NotImplementedError

    def claimed(self) -> str:
        """How a refused second driver names the device it could not claim."""
        raise NotImplementedError

    def second_emulator(self) -> tuple[Node, str]:
        """An emulator node of this same device (not set up), and how it names the device when refused."""
        raise NotImplementedError

    def emulator_ctx(self, name: str) -> NodeContext:
        return NodeContext(name, DT, sim_time=False, log=lambda line: None)

    def setup(self, driver: Node) -> None:
        driver.setup()

    def inputs(self) -> dict:
        return {}

    # -- common -------------------------------------------------------------------------
    def ctx(self, logs: list[str] | None = None) -> NodeContext:
        log = (self.logs if logs is None else logs).append
        return NodeContext("driver", DT, sim_time=False, log=log, clock=self.clock)

    def start(self) -> Rig:
        with in_graph(GRAPH):
            self.start_emulator()
            self.driver = self.build()
            self.setup(self.driver)
        return self

    def step(self) -> dict:
        """One period later on the driver's clock, one step with fresh inputs."""
        self.clock.advance(DT)
        out = self.driver.step(Tick(self.k, self.clock(), DT), self.inputs())
        self.k += 1
        if self.published in out:
            self.fresh_at = self.clock()
        return out

    def until(self, done, timeout: float = 20.0, seen: list | None = None) -> dict:
        """Step, about every millisecond of real time, until done(outputs); those outputs (and each
        step's in `seen`)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            out = self.step()
            if seen is not None:
                seen.append(out)
            if done(out):
                return out
            time.sleep(0.001)
        raise AssertionError(f"{self.name}: not done within {timeout} s (step {self.k}); log: {self.logs}")

    def close(self) -> None:
        for driver in self._built:
            driver.close()
        self.stop_emulator()


# -- F/T sensors --------------------------------------------------------------------------


class NetFtRig(Rig):
    """ft_netft against NetFtBox: an unloaded probe with a 1.5 N offset, streamed at 1 kHz."""

    name = "ft_netft"
    published = "wrench"

    def start_emulator(self) -> None:
        self.box = NetFtBox(ContactModel(1000.0, bias=1.5), port=0, http_port=0, rate=1000.0).start_thread()

    def build(self, logs=None) -> FtNetFtDriver:
        b = self.box
        d = FtNetFtDriver(
            self.ctx(logs), host="127.0.0.1", port=b.port, http_port=b.http_port, tare_samples=20, stale_timeout=STALE
        )
        self._built.append(d)
        return d

    def _to_driver(self, sock: socket.socket, data: bytes) -> None:
        sock.sendto(data, ("127.0.0.1", self.driver.sock.getsockname()[1]))

    def silence(self) -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
            c.sendto(rdt.encode_request(rdt.CMD_STOP), ("127.0.0.1", self.box.port))  # any client may stop it
        wait_for(lambda: self.box.counts["stops"] >= 1, what="the box's stop")

    def send_malformed(self) -> None:
        # From the box's own address and port: a record saying 900 N, cut short by a byte.
        self._to_driver(self.box.udp, rdt.encode_record(1, 1, 0, (900_000_000, 0, 0, 0, 0, 0))[:35])

    def send_foreign(self) -> None:
        # A well-formed record with 900 N, from another port of the box's host.
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
            stranger.bind(("127.0.0.1", 0))
            self._to_driver(stranger, rdt.encode_record(10**6, 10**6, 0, (900_000_000, 0, 0, 0, 0, 0)))

    def rejected(self) -> dict[str, int | None]:
        c = self.driver.counters()
        return {"malformed": c["bad datagrams"], "foreign": c["foreign datagrams"]}

    def stop_emulator(self) -> None:
        self.box.stop_thread()

    def claimed(self) -> str:
        return f"Net F/T box 127.0.0.1:{self.box.port}"

    def second_emulator(self) -> tuple[Node, str]:
        node = NetFtEmulator(self.emulator_ctx("netft_emulator"), port=self.box.port, http_port=0)
        return node, self.claimed()


class CanRig(Rig):
    """ft_can against ft_emulator on a python-can virtual bus: an unloaded probe with a 1.5 N offset;
    the emulator sends one sample per step of the rig (and streams in a thread while a driver tares)."""

    name = "ft_can"
    published = "wrench"

    def start_emulator(self) -> None:
        import can

        self.channel = f"contract-{next(_channels)}"
        self.emulator = FtSensorEmulator(
            NodeContext("ft_emulator", DT, sim_time=False, log=self.logs.append),
            interface="virtual",
            channel=self.channel,
            bias=1.5,
        )
        self.emulator.setup()
        self.sending = True
        self.injector = can.Bus(interface="virtual", channel=self.channel)
        self._can = can

    def build(self, logs=None) -> FtCanDriver:
        d = FtCanDriver(self.ctx(logs), interface="virtual", channel=self.channel, tare_samples=10, stale_timeout=STALE)
        self._built.append(d)
        return d

    def _emit(self) -> None:
        if self.sending:
            self.emulator.step(Tick(0, 0.0, DT), {"state": None})

    def setup(self, driver: Node) -> None:
        streaming = threading.Event()
        streaming.set()

        def stream():  # the sensor streams from power-on: the tare needs its samples
            while streaming.is_set():
                self._emit()
                time.sleep(0.001)

        thread = threading.Thread(target=stream, daemon=True)
        thread.start()
        try:
            driver.setup()
        finally:
            streaming.clear()
            thread.join()

    def step(self) -> dict:
        self._emit()  # the virtual bus delivers at once: the driver reads this sample in its step
        return super().step()

    def silence(self) -> None:
        self.sending = False

    def _send(self, arbitration_id: int, data: bytes) -> None:
        self.injector.send(self._can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))

    def send_malformed(self) -> None:
        # The sensor's force ID, three data bytes instead of eight.
        self._send(ff.DEFAULT_BASE_ID, b"\x7f\xff\x00")

    def send_foreign(self) -> None:
        # Another device's IDs, in the sensor's layout, saying 300 N.
        for arbitration_id, data in ff.encode_sample((300.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0, base_id=0x2A0):
            self._send(arbitration_id, data)

    def rejected(self) -> dict[str, int | None]:
        return {"malformed": self.driver.bad_frames, "foreign": None}

    def stop_emulator(self) -> None:
        self.injector.shutdown()
        self.emulator.close()

    def claimed(self) -> str:
        return f"F/T adapter (virtual {self.channel})"

    def second_emulator(self) -> tuple[Node, str]:
        node = FtSensorEmulator(self.emulator_ctx("ft_emulator"), interface="virtual", channel=self.channel)
        return node, f"CAN bus virtual {self.channel}"


# -- robots --------------------------------------------------------------------------------


class RobotRig(Rig):
    """A robot driver fed a fresh command (toward `target` along x, m) and a fresh unloaded wrench
    every step. The measured-speed limits are off: the robot moves on the device's clock, the driver
    reads it on the test's (those limits are tested on a controlled clock in test_hardware_safety.py)."""

    robot = True
    published = "state"
    target = 0.0

    def sent_x(self) -> float:
        """What the link last sent the controller toward the command, x [m]."""
        raise NotImplementedError

    def inputs(self) -> dict:
        k = self.k
        header = Header(self.clock(), k, k, "")
        return {
            "command": RobotCommand(
                header=Header(self.clock(), k, k, "target"), pose=Pose(Vector3(self.target)), twist=Twist(Vector3())
            ),
            "wrench": WrenchStamped(header=header, wrench=Wrench()),
        }


class ModbusRig(RobotRig):
    """robot_modbus against the robot_emulator node (RobotControllerEmulator: Modbus TCP on a free port,
    in a thread)."""

    name = "robot_modbus"

    def start_emulator(self, port: int = 0) -> None:
        # As a launch runs it: a node on a port of its own, claimed for the graph.
        self.emulator = RobotControllerEmulatorNode(
            NodeContext("robot_emulator", DT, sim_time=False, log=self.logs.append), port=port or free_port(), tau=0.005
        )
        self.emulator.setup()
        self.controller = self.emulator.emulator

    def build(self, logs=None) -> RobotModbusDriver:
        # 1 s per request: a busy machine's slow round trip is not a lost connection
        d = RobotModbusDriver(
            self.ctx(logs),
            port=self.controller.port,
            timeout=1.0,
            reconnect_timeout=STALE,
            max_actual_speed=0.0,
            max_actual_angular_speed=0.0,
        )
        self._built.append(d)
        return d

    def servo(self, attribute: str):
        return self.controller.call(lambda: getattr(self.controller.servo, attribute))

    def holding(self) -> mm.HostWrite:
        return mm.decode_holding(self.controller.call(lambda: list(self.controller.servo.holding)[: mm.HR_COUNT]))

    def sent_x(self) -> float:
        """The setpoint the controller was last written, x [m]."""
        return self.holding().setpoint[0]

    def silence(self) -> None:
        self.emulator.close()
        wait_for(lambda: not self.driver.link.connected, what="the lost connection")

    def _request(self, pdu: bytes) -> bytes:
        """One Modbus TCP request on a connection of its own (another host); the response PDU."""
        with socket.create_connection(("127.0.0.1", self.controller.port), timeout=5.0) as s:
            s.sendall(struct.pack(">HHHB", 7, 0, len(pdu) + 1, 1) + pdu)
            head = s.recv(7)
            _, _, length, _ = struct.unpack(">HHHB", head)
            body = b""
            while len(body) < length - 1:
                body += s.recv(length - 1 - len(body))
            return body

    def _write_setpoint(self, byte_count_delta: int = 0) -> bytes:
        # A setpoint 50 mm along x with the enable bit, as a host that moves the robot writes it.
        values = mm.encode_write(mm.CONTROL_ENABLE, 1, (0.05, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0))
        n = len(values)
        return self._request(struct.pack(f">BHHB{n}H", 16, 0, n, 2 * n + byte_count_delta, *values))

    def send_malformed(self) -> None:
        # A write whose byte count disagrees with its register count: exception 3 (illegal data value).
        self.answers = [self._write_setpoint(byte_count_delta=-2)]

    def send_foreign(self) -> None:
        # A well-formed setpoint write from a connection that holds no claim: exception 6 (device busy).
        self.answers = getattr(self, "answers", []) + [self._write_setpoint()]

    def rejected(self) -> dict[str, int | None]:
        return {"malformed": None, "foreign": self.servo("refused")}

    def stop_emulator(self) -> None:
        self.emulator.close()

    def claimed(self) -> str:
        return f"robot controller (Modbus TCP 127.0.0.1:{self.controller.port})"

    def second_emulator(self) -> tuple[Node, str]:
        node = RobotControllerEmulatorNode(self.emulator_ctx("robot_emulator"), port=self.controller.port)
        return node, f"robot controller emulator port 127.0.0.1:{self.controller.port}"


class RsiRig(RobotRig):
    """robot_rsi against RsiControllerEmulator (UDP, 4 ms cycle, in a thread), which records every
    correction it is answered (`answers`, RKorr X Y Z A B C) and those it took in time (`applied`); a
    late answer is not taken, and the robot keeps the correction it had."""

    name = "robot_rsi"

    def __init__(self) -> None:
        super().__init__()
        self.port = udp_port()

    def start_emulator(self, ipoc0: int = 1_000_000) -> None:
        em = RsiControllerEmulator(port=self.port, max_late=10**9, ipoc0=ipoc0)
        em.answers, em.applied = [], []
        receive, apply = em._receive, em._apply

        def received(deadline):
            got = receive(deadline)
            if got is not None and got[1] == em.host:
                with contextlib.suppress(rsi.RsiError):
                    em.answers.append(rsi.parse_sen(got[0])[1])
            return got

        def applied(korr, now):
            em.applied.append(tuple(korr))
            apply(korr, now)

        em._receive, em._apply = received, applied
        em.start_thread()
        self.controller = em

    def build(self, logs=None) -> RobotRsiDriver:
        d = RobotRsiDriver(
            self.ctx(logs),
            port=self.port,
            host="127.0.0.1",
            controller_timeout=STALE,
            max_speed=0.01,  # 0.04 mm a cycle: the correction takes a second of real time to reach 10 mm
            max_actual_speed=0.0,
            max_actual_angular_speed=0.0,
        )
        self._built.append(d)
        return d

    def sent_x(self) -> float:
        """The correction the link answers with, along BASE X = the scene's x [m]."""
        return self.driver.link.korr[0][0] / 1000.0

    def silence(self) -> None:
        self.controller.stop_thread()

    def _to_driver(self, bind: str, data: bytes) -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind((bind, 0))
            s.sendto(data, ("127.0.0.1", self.port))

    def _far_datagram(self) -> bytes:
        # The robot 50 mm along X, in a cycle after the controller's latest.
        x, *rest = START_POSE
        return rsi.build_rob(self.controller.ipoc + 400, (x + 50.0, *rest), delay=0)

    def send_malformed(self) -> None:
        self._to_driver("127.0.0.1", self._far_datagram()[:40])  # from the controller's address, cut short

    def send_foreign(self) -> None:
        self._to_driver("127.0.0.2", self._far_datagram())  # well-formed, from another address

    def rejected(self) -> dict[str, int | None]:
        counted = self.driver.link.counted
        return {"malformed": counted["malformed"], "foreign": counted["foreign"]}

    def stop_emulator(self) -> None:
        self.controller.stop_thread()

    def claimed(self) -> str:
        return f"KUKA RSI port {self.port}"

    def second_emulator(self) -> tuple[Node, str]:
        return RsiControllerEmulatorNode(self.emulator_ctx("rsi_emulator"), port=self.port), self.claimed()


RIGS = {rig.name: rig for rig in (CanRig, NetFtRig, ModbusRig, RsiRig)}
