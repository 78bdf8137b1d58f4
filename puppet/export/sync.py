"""What an export carries of the take's sync: its sound's file, offset and rate, the frame rate
and the start timecode, as one flat dict of names every format writes in its own place (glTF:
the scene's and the animation's ``extras``; USD: the layer's ``customLayerData``; BVH: a comment
line after HIERARCHY, which importers skip).

  puppet_fps, puppet_frame_start   the file's frame rate; frame 1 is the take's time 0
  puppet_sound_file, _path, _sha256, _rate, _offset_s
                                   the sound (its time at the take's time 0: offset_s)
  puppet_sound_frame               the file's frame on which the sound's sample 0 plays,
                                   1 − offset_s · fps (Blender: the sound strip's frame_start)
  puppet_timecode_start, _rate     the label of frame 1, at the file's rate when fps is a
                                   timecode rate (23.976, 24, 25, 29.97, 30), else the take's

A clip of a take (``export --clip IN OUT``, a studio segment) starts at take time IN: its frame 1
is there, so its sound offset and start timecode are the take's moved on by IN (``start_s``).
"""

from __future__ import annotations

import dataclasses

from puppet.timecode import rate_of_fps


def sync_fields(fps: float, sound=None, timecode=None, start_s: float = 0.0) -> dict:
    """The flat dict above. sound: ``puppet.take.sync.SoundRef`` or None; timecode:
    ``puppet.timecode.StartTimecode`` or None; fps: the file's frames per second; start_s: the
    take time of the file's frame 1 (a clip's in point; 0: the whole take). Empty for a take
    with neither (its files are as before sound)."""
    if sound is None and timecode is None:
        return {}
    if start_s:
        if sound is not None:
            sound = dataclasses.replace(sound, offset_s=sound.offset_s + start_s)
        if timecode is not None:
            timecode = timecode.later(start_s)
    fields = {"puppet_fps": float(fps), "puppet_frame_start": 1}
    if sound is not None:
        fields.update({
            "puppet_sound_file": sound.name, "puppet_sound_path": sound.path,
            "puppet_sound_sha256": sound.sha256, "puppet_sound_rate": int(sound.rate),
            "puppet_sound_offset_s": float(sound.offset_s),
            "puppet_sound_frame": round(1.0 - sound.offset_s * fps, 6),
        })
    if timecode is not None:
        rate = rate_of_fps(fps)
        start = timecode.at_rate(rate) if rate is not None else timecode
        fields.update({"puppet_timecode_start": start.label,
                       "puppet_timecode_rate": start.rate.name})
    return fields
