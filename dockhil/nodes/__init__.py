"""The simulation and graph node types, one module each; dockhil/node_types.py names them for launch
files (the device drivers and emulators are in dockhil/devices/)."""
