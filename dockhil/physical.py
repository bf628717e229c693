"""The range of docking hardware: what a scene may be given, and what a run may reach.

Parameters (docs/SAFETY-limits.md, "Physical ranges"): from a 10 g laboratory probe to a target
two hundred times the ISS's mass, approached at a few metres per second at most. Outside it the
contact models are not the tool, and the products and quotients the loop and its checks form
(omega = sqrt(k/m), rates, impulses) leave floating point. Node parameters (`Param(scale=...)`,
each number of a list parameter too) and `dockhil params` refuse values outside it in one line,
before anything runs.

A run (docs/summary.md, "A run that leaves the physical range"): its largest force, its bodies'
positions and speeds, and the kinetic energy the loop gave them, each against the scene's own
scale (its ideal contact, thrust and force limits, its start). A run beyond any of them exploded
or means nothing, whatever else it says: it is INVALID (dockhil.analysis.summary.common.RangeMeter.reasons)."""

import math
from typing import NamedTuple


class Range(NamedTuple):
    """(low, high) with what a value outside it is mistaken for, said to the user: a time in seconds
    given in milliseconds (delay:=16 for 16 ms) reads as a physical value a thousand times too large."""

    low: float
    high: float
    what: str = ""


# (low, high): the magnitude of a nonzero value lies within this range.
MASS = (1e-2, 1e8)  # [kg] a body: 10 g probe to 1e5 t (the ISS is 4.2e5 kg, the paper's target 1e6 kg)
INERTIA = (1e-6, 1e13)  # [kg m^2] a principal moment or an entry of an inertia matrix
STIFFNESS = (0.0, 1e12)  # [N/m, N m/rad] contact, compliance, virtual springs
DAMPING = (0.0, 1e12)  # [N s/m, N m s/rad]
FORCE = (0.0, 1e6)  # [N] a thrust, a sensor's noise, bias, resolution or deadband
SPEED = (0.0, 5.0)  # [m/s] a body's initial velocity: docking hardware survives a few m/s at most
ANGULAR_SPEED = (0.0, 10.0)  # [rad/s] a body's initial spin: 1.6 turns a second
ANGLE = (0.0, 2.0 * math.pi)  # [rad] a component of a rotation vector (attitude, tilt)
DISTANCE = (0.0, 1e3)  # [m] an initial position, an interface or sensor offset
# [s] a robot's response delay and its jitter: a few ms (a servo cycle) to a few hundred (a slow controller
# behind a network); a second already makes the paper's loop a different experiment.
ROBOT_DELAY = Range(0.0, 1.0, "a robot delay is a few ms to a few hundred ms")
# [s] a robot servo's time constant: as short as its cycle, a few hundred ms for a sluggish one
TIME = Range(0.0, 1.0, "a servo time constant is a few ms to a few hundred ms")
FRICTION = (0.0, 10.0)  # [1] a Coulomb friction coefficient

# A run leaves the physical range when (each against the scene's own scale, dockhil.analysis.summary):
RUN_FORCE_FACTOR = 100.0  # |F| > 100 x (ideal peak, thrust, a driver's max_force)
RUN_ENERGY_FACTOR = 100.0  # the bodies' kinetic energy > 100 x (entry energy + thrust's share)
RUN_FORCE = 1e7  # [N] or, with no scale to judge by, |F| beyond what any docking hardware bears
RUN_DISTANCE = 1e4  # [m] a body more than 10 km from where it started: it flew away
RUN_SPEED = 50.0  # [m/s] a body ten times faster than the fastest contact speed a scene may give
RUN_SPEED_FLOOR = 0.01  # [m/s] a scene whose bodies start at rest is judged as if they closed in at 1 cm/s
