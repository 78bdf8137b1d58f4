"""Servo IO through dynamixel_sdk: scan, configure, group reads, recovery."""

from puppet.bus.reading import Reading

__all__ = ["Reading"]
