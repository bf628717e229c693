"""The lab's devices: the seams between a driver and its device (base.py: the RobotLink and Emulator
protocols), the driver bases that own the safety sequence (robot_base.py, ft_base.py), the
shared tare, cycle log, device paths and limits, and one folder per device (ati_netft/, kuka_rsi/,
modbus_robot/, can_ft/), each with its protocol, link, driver node and emulator.

Importing this package loads nothing: each driver imports its own library (python-can, pymodbus)
only where it uses it."""
