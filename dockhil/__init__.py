"""dockhil: hardware-in-the-loop docking simulation.

The runtime (transport, node API, clocks, launch, bags, CLI) lives here;
the contact-dynamics science lives in `dockhil.contact` and imports no
transport code.
"""

__version__ = "0.1.0"
