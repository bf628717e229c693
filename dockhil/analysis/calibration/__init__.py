"""The loop identified from a calibration run: the fits of the servo, contact and rest (servo_fit.py), the
controller's own cycles (device_cycles.py), and the loop they make together (loop.py)."""
