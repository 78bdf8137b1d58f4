"""Sound: decoding (libsndfile via soundfile), the take's reference to its sound, finding it
again, the sound under a take (one window rule), muxing into MP4 and playing on a device.

One clock: the take's time 0 is its first reading (after the count-in); a sound's ``offset_s``
is the sound's time there, and the start timecode labels it (``puppet.timecode``).
"""

from __future__ import annotations

from puppet.sound.decode import SUFFIXES, Sound, file_sha256, load_sound
from puppet.sound.errors import SoundError
from puppet.sound.locate import find_take_sound, keep_copy, sound_for_take
from puppet.sound.window import take_window
from puppet.take.sync import SoundRef


def sound_ref(sound: Sound, offset_s: float = 0.0) -> SoundRef:
    """The reference a take stores to ``sound``, played from ``offset_s`` (its time at the take's
    time 0, seconds)."""
    try:
        return SoundRef(sha256=sound.sha256, name=sound.name, path=str(sound.path),
                        offset_s=float(offset_s), rate=sound.rate, channels=sound.channels,
                        frames=sound.frames)
    except ValueError as err:
        raise SoundError(sound.path, f"cannot be the take's sound: {err}") from None


__all__ = ["SUFFIXES", "Sound", "SoundError", "SoundRef", "file_sha256", "find_take_sound",
           "keep_copy", "load_sound", "sound_for_take", "sound_ref", "take_window"]
