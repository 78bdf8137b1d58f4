"""hw_sim: a simulated Dynamixel Protocol 2.0 bus on a pseudo-terminal.

The real ``dynamixel_sdk`` opens the bus's port path like a serial port. This package
imports nothing from ``puppet``.
"""

__version__ = "0.1.0"
