"""The robot controller on Modbus TCP: the register map (registers.py), the link thread and claim
(link.py), the driver node (driver.py), the controller's emulator (emulator.py, on its own server,
server.py) and its node (emulator_node.py)."""
