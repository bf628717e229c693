"""The 6-axis F/T sensor on CAN: its frames (frames.py), slcan adapters on pseudo-terminals
(slcan_pty.py, slcan_reader.py), frames over UDP multicast (multicast.py), the driver node (driver.py)
and the sensor's emulator node (emulator.py)."""
