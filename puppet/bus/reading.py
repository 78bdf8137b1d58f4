"""Re-export of ``puppet.reading.Reading`` (its home since takes stopped importing the bus)."""

from puppet.reading import Reading

__all__ = ["Reading"]
