"""KUKA RSI, Ethernet XML over UDP: the datagrams (protocol.py), the answering link (link.py), the
driver node (driver.py), the controller's emulator (emulator.py) and its node (emulator_node.py)."""
