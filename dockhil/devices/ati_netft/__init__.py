"""ATI Net F/T: RDT over UDP and netftapi2.xml (protocol.py), the driver node (driver.py), the box's
emulator (emulator.py) and its node (emulator_node.py)."""
