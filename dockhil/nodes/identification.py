"""Identification excitation: a scripted, slow and small profile on /robot/command for `dockhil calibrate`.

The robot driver stays between this node and the robot, with every safety limit of the scene in
force; the profile keeps well inside them (a fraction of max_speed and max_force, inside the
workspace). In order, each phase announced on /calibration/phase as it starts:

    backoff   move back by `backoff` from the start pose (the probe starts free, in front of the
              compliance's surface, which lies ahead in +x)
    rest      hold still: the F/T sensor's bias and noise
    steps     small position steps back and forth (speed-limited ramps), then
    chirp     a sine sweep from chirp_f0 to chirp_f1 of bounded speed: the delay and lag
    approach  move slowly forward until the force rises above the noise band measured at rest
              (the surface: the penetration's zero)
    press     press on, at the same speed, to force_fraction x max_force (or press_depth)
    hold      hold the press
    release   back out at the same speed to the backed-off pose
    done      hold there until the graph stops (`duration()` is the longest the profile can take)

No contact within `search` of the start, or a force above half of max_force, stops the graph with
one line (the driver holds the robot).
"""

from __future__ import annotations

import math
from typing import Any

from dockhil.errors import DeviceError
from dockhil.msgs import NodeStatus, Pose, RobotCommand, RobotState, Twist, Vector3, WrenchStamped
from dockhil.node import Input, Node, Output, Param, Tick

PHASES = ("backoff", "rest", "steps", "chirp", "approach", "press", "hold", "release", "done")
SETTLE_S = 0.3  # after a move: the robot answers up to a delay and a lag later
TAPER_S = 0.5  # the chirp's amplitude fades in and out over this


def chirp_position(t: float, amplitude: float, speed: float, f0: float, f1: float, length: float) -> float:
    """Offset [m] of the chirp at time t in [0, length]: a linear sweep f0 -> f1 [Hz] whose amplitude is
    the smaller of `amplitude` and speed / (2 pi f) (so its speed stays near `speed`), faded in and out."""
    if not 0.0 <= t <= length:
        return 0.0
    f = f0 + (f1 - f0) * t / length
    phase = 2.0 * math.pi * (f0 * t + 0.5 * (f1 - f0) * t * t / length)
    fade = min(1.0, t / TAPER_S, (length - t) / TAPER_S)
    fade = 0.5 - 0.5 * math.cos(math.pi * max(fade, 0.0))  # smooth: no jump in speed
    return fade * min(amplitude, speed / (2.0 * math.pi * f)) * math.sin(phase)


class Identification(Node):
    """Scripted identification profile for dockhil calibrate: rest, steps, chirp, press and release."""

    # The profile runs open loop but for finding the surface; the drivers' own watchdogs (ft_timeout,
    # stale_timeout, stall_timeout) guard the robot, so a busy machine's late message need not stop the run.
    inputs = {
        "state": Input(RobotState, "/robot/state", feedthrough=False, max_age=0.5, help="actual pose read back"),
        "wrench": Input(WrenchStamped, "/ft/wrench", feedthrough=False, max_age=0.5, help="measured wrench, untared"),
    }
    outputs = {
        "command": Output(RobotCommand, "/robot/command", help="setpoint of the profile"),
        "phase": Output(NodeStatus, "/calibration/phase", help="the phase that starts (state), on each change"),
    }
    params = {
        "max_speed": Param(
            float,
            0.1,
            unit="m/s",
            help="the robot driver's max_speed; the profile moves at half of it at most",
            gt=0.0,
            le=10.0,
        ),
        "max_force": Param(float, 200.0, unit="N", help="the robot driver's max_force", gt=0.0, le=1e5),
        "x_max": Param(float, 0.1, unit="m", help="the robot driver's workspace bound in +x", ge=-2000.0, le=2000.0),
        "force_fraction": Param(float, 0.35, help="press up to this fraction of max_force", gt=0.0, le=0.5),
        "backoff": Param(float, 0.015, unit="m", help="move back this far from the start first", gt=0.0, le=0.1),
        "rest": Param(float, 2.0, unit="s", help="time at rest for the bias and noise", ge=0.5, le=60.0),
        "step": Param(float, 0.005, unit="m", help="amplitude of the position steps", gt=0.0, le=0.05),
        "steps": Param(int, 4, help="number of position steps (back and forth)", ge=2, le=40),
        "step_hold": Param(float, 0.5, unit="s", help="time each step is held", gt=0.0, le=10.0),
        "chirp": Param(float, 6.0, unit="s", help="length of the chirp (0: none)", ge=0.0, le=60.0),
        "chirp_f0": Param(float, 0.5, unit="Hz", help="chirp start frequency", gt=0.0, le=100.0),
        "chirp_f1": Param(float, 8.0, unit="Hz", help="chirp end frequency", gt=0.0, le=100.0),
        "press_speed": Param(float, 0.02, unit="m/s", help="speed of the approach, press and release", gt=0.0, le=1.0),
        "search": Param(
            float, 0.03, unit="m", help="how far beyond the start pose the surface may lie", gt=0.0, le=0.5
        ),
        "press_depth": Param(float, 0.04, unit="m", help="deepest press beyond the surface", gt=0.0, le=0.5),
        "hold": Param(float, 0.5, unit="s", help="time the press is held", ge=0.0, le=10.0),
        "contact_force": Param(
            float,
            0.5,
            unit="N",
            help="least force rise that counts as contact (and at least 6 noise standard deviations)",
            gt=0.0,
            le=1000.0,
        ),
    }

    def setup(self) -> None:
        p = self.p
        self.v_move = 0.5 * p.max_speed
        self.press_speed = min(p.press_speed, self.v_move)
        self.phase = ""
        self.phase_t = 0.0
        self.x0: float | None = None  # the start pose
        self.x = 0.0  # the setpoint
        self.v = 0.0
        self.rest_sum = self.rest_sq = 0.0
        self.rest_n = 0
        self.bias = self.noise = 0.0
        self.x_contact: float | None = None
        self.x_deepest = 0.0
        self._announce: str | None = None
        self._last_t: float | None = None

    @staticmethod
    def duration(params: dict) -> float:
        """The longest the profile can take [s], the wait for the first pose and force aside."""
        p = dict((name, spec.default) for name, spec in Identification.params.items()) | params
        v_move = 0.5 * p["max_speed"]
        v = min(p["press_speed"], v_move)
        travel = p["backoff"] + p["search"] + p["press_depth"]
        return (
            p["backoff"] / v_move
            + SETTLE_S
            + p["rest"]
            + p["steps"] * (p["step"] / v_move + p["step_hold"])
            + p["chirp"]
            + SETTLE_S
            + 2.0 * travel / v
            + p["hold"]
            + SETTLE_S
        )

    def _enter(self, phase: str, t: float) -> None:
        self.phase, self.phase_t = phase, t
        self._announce = phase

    def _move_toward(self, target: float, speed: float, dt: float) -> bool:
        """Move the setpoint toward target at speed; True once there."""
        step = speed * dt
        if abs(target - self.x) <= step:
            self.v = (target - self.x) / dt if dt > 0 else 0.0  # at most speed: the step was within reach
            self.x = target
            return True
        self.v = math.copysign(speed, target - self.x)
        self.x += self.v * dt
        return False

    def step(self, tick: Tick, inputs: dict[str, Any]) -> dict[str, Any]:
        state, wrench = inputs.get("state"), inputs.get("wrench")
        if state is None or wrench is None:
            return {}  # the driver holds until the first command; the profile starts from the pose read
        p, t = self.p, tick.t
        # The time since the previous tick, not the nominal step: in wall time a late tick moves the
        # setpoint by what the speed allows over the time that really passed, and says that speed.
        dt = min(max(t - self._last_t, 0.0), 10.0 * tick.dt) if self._last_t is not None else tick.dt
        self._last_t = t
        fx = wrench.wrench.force.x
        if self.x0 is None:
            self.x0 = self.x = state.pose.position.x
            self._enter("backoff", t)
        self.v = 0.0
        back = self.x0 - p.backoff
        elapsed = t - self.phase_t
        pushing = -(fx - self.bias)
        if self.phase not in ("backoff", "rest") and pushing > 0.5 * p.max_force:  # a robot moving on after the press
            raise DeviceError(
                f"identification: the press met {pushing:.1f} N, over half of max_force "
                f"{p.max_force:g} N; stopped (the robot holds)"
            )
        if self.phase == "backoff":
            if self._move_toward(back, self.v_move, dt) and elapsed > p.backoff / self.v_move + SETTLE_S:
                self._enter("rest", t)
        elif self.phase == "rest":
            self.rest_n += 1
            self.rest_sum += fx
            self.rest_sq += fx * fx
            if elapsed >= p.rest:
                self.bias = self.rest_sum / self.rest_n
                self.noise = math.sqrt(max(self.rest_sq / self.rest_n - self.bias**2, 0.0))
                self._enter("steps", t)
        elif self.phase == "steps":
            period = p.step / self.v_move + p.step_hold
            i = int(elapsed / period)
            if i >= p.steps:
                if self._move_toward(back, self.v_move, dt):
                    self._enter("chirp" if p.chirp else "approach", t)
            else:
                self._move_toward(back - p.step if i % 2 == 0 else back, self.v_move, dt)
        elif self.phase == "chirp":
            if elapsed >= p.chirp + SETTLE_S:
                self.x = back
                self._enter("approach", t)
            else:
                args = (0.5 * p.step, 0.8 * self.v_move, p.chirp_f0, p.chirp_f1, p.chirp)
                self.x = back + chirp_position(elapsed, *args)
                self.v = (chirp_position(elapsed + 1e-4, *args) - chirp_position(elapsed - 1e-4, *args)) / 2e-4
        elif self.phase in ("approach", "press"):
            limit = min(self.x0 + p.search + p.press_depth, p.x_max - 0.005)
            if self.phase == "approach":
                band = max(p.contact_force, 6.0 * self.noise)
                if pushing > band:
                    self.x_contact = state.pose.position.x
                    self._enter("press", t)
                elif self.x >= min(self.x0 + p.search, limit):
                    raise DeviceError(
                        f"identification: no contact within search {p.search:g} m of the start pose "
                        f"x = {self.x0:.4f} m (the force stayed within {band:.2f} N of its rest "
                        f"value): start with the probe closer to the compliance"
                    )
            else:
                deep = min(self.x_contact + p.press_depth, limit)
                if pushing >= p.force_fraction * p.max_force or self.x >= deep:
                    self._enter("hold", t)
            if self.phase in ("approach", "press"):
                self._move_toward(limit, self.press_speed, dt)
        elif self.phase == "hold":
            if elapsed >= p.hold:
                self._enter("release", t)
        elif self.phase == "release":
            if self._move_toward(back, self.press_speed, dt):
                self._enter("done", t)
        out: dict[str, Any] = {
            "command": RobotCommand(
                header=tick.header(), pose=Pose(position=Vector3(x=self.x)), twist=Twist(linear=Vector3(x=self.v))
            )
        }
        if self._announce is not None:
            out["phase"] = NodeStatus(header=tick.header(), node=self.ctx.name, state=self._announce)
            self._announce = None
        return out
