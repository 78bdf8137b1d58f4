"""Pose to pose: key poses captured from the puppet into a shot, and edits of a shot.

A shot is a take with its keys on a channel of their own (``puppet.take.keys`` holds the
format); ``play``, ``export``, ``batch`` and ``play --view`` show it through
``puppet.take.Playback`` like any take, its in-betweens solved by FAST from joint rotations
interpolated between the keys (``puppet.take.inbetween``).
"""

from puppet.keys.shot import (insert_key, interpolate, read_shot, remove_key, replace_key,
                              retime, write_shot)

__all__ = ["insert_key", "interpolate", "read_shot", "remove_key", "replace_key", "retime",
           "write_shot"]
