"""The range of docking hardware: a gram-scale probe to a space station, pushed by at most a
large thruster. Outside it the contact models are not the tool, and the products and quotients
the loop and its checks form (omega = sqrt(k/m), rates, impulses) leave floating point. Node
parameters (`Param(scale=...)`) and `dockhil params` refuse values outside it in one line."""

MASS = (1e-6, 1e12)  # [kg], magnitude of a nonzero mass
STIFFNESS = (0.0, 1e12)  # [N/m]
DAMPING = (0.0, 1e12)  # [N s/m]
FORCE = (0.0, 1e9)  # [N], magnitude of a constant thrust
SPEED = (0.0, 1e3)  # [m/s], magnitude of an initial velocity
DISTANCE = (0.0, 1e6)  # [m], magnitude of an initial position
