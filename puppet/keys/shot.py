"""A shot on disk, and its edits: write it whole (atomically), read it, and replace, insert,
remove, retime or re-interpolate keys (each edit returns new Keys; the file is written by write_shot).

header: the TakeWriter keywords a shot is written with (ids, models, rig_map_text,
calibration_text, rig_name): ``puppet.take.header.take_header(rig)`` for a new shot, ``read_shot``'s
for an edited one.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from puppet.atomic import commit, temporary_sibling
from puppet.reading import Reading
from puppet.take import TakeError, TakeReader, TakeWriter
from puppet.take.keys import Key, Keys, check_frames, check_interpolation


SHOT_SUFFIX = ".mcap"
"""A shot is a take (MCAP): its file is named *.mcap, as ``play``, ``export`` and ``batch`` find
takes."""


def check_shot_path(path) -> Path:
    """``path``, or TakeError unless it is named *.mcap (a shot is a take)."""
    path = Path(path)
    if path.suffix.lower() != SHOT_SUFFIX:
        raise TakeError(path, f"a shot is a take: name it *{SHOT_SUFFIX} (e.g. shot.mcap)")
    return path


def write_shot(path, header: dict, keys: Keys) -> None:
    """Write a shot: one reading per key at its time, then the keys channel; whole or absent
    (a temporary file renamed over ``path``). The caller has checked ``path``
    (``puppet.atomic.check_output``)."""
    path = Path(path)
    check_frames([k.frame for k in keys.keys], path, keys.fps, [k.id for k in keys.keys])
    ids = np.asarray(header["ids"], np.int64)
    temporary = temporary_sibling(path)
    try:
        with TakeWriter(temporary, **header, fsync_interval_s=None, overwrite=True) as writer:
            for key, t_ns in zip(keys.keys, keys.times_ns()):
                writer.write(Reading(int(t_ns), ids, key.ticks, key.ok))
            writer.keys(keys)
        commit(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def read_shot(path) -> tuple[dict, Keys, TakeReader]:
    """(header, keys, reader) of a shot; TakeError naming it when it has no keys channel."""
    reader = TakeReader(path)
    keys = reader.keys()
    if keys is None and reader.truncated:
        raise TakeError(path, f"no keys: the file is cut short ({reader.report.end}) before its "
                              "keys channel (/puppet/keys), written at a shot's end; its "
                              f"{len(reader)} key pose(s) still play as a take (`puppet play`, "
                              "`puppet export`)")
    if keys is None:
        raise TakeError(path, "not a shot: the take has no keys channel (/puppet/keys); "
                              "record keys with `puppet keys`")
    meta = reader.metadata
    header = {"ids": [int(i) for i in meta.ids], "models": dict(meta.models),
              "rig_map_text": meta.rig_map_text, "calibration_text": meta.calibration_text,
              "rig_name": meta.rig_name}
    return header, keys, reader


def _keys(keys: Keys, new: list[Key]) -> Keys:
    """Edited keys: ``new``, with what reading the shot skipped (kept in the file)."""
    return Keys(keys.fps, new, damaged=list(keys.damaged))


def replace_key(keys: Keys, key_id: int, key: Key, source="shot") -> Keys:
    """Key ``key_id`` re-posed: ``key``'s ticks and ok at the old key's frame and interpolation."""
    i = keys.position(key_id, source)
    new = list(keys.keys)
    new[i] = replace(new[i], ticks=key.ticks, ok=key.ok)
    return _keys(keys, new)


def remove_key(keys: Keys, key_id: int, source="shot") -> Keys:
    """The keys without key ``key_id`` (the others keep their frames and ids)."""
    i = keys.position(key_id, source)
    return _keys(keys, keys.keys[:i] + keys.keys[i + 1:])


def insert_key(keys: Keys, key: Key, source="shot") -> Keys:
    """The keys with ``key`` added at its frame, with the next unused id (TakeError naming the
    key already there, or a frame past the shot's length)."""
    key = replace(key, id=keys.next_id())
    frames = [k.frame for k in keys.keys]
    if key.frame in frames:
        there = keys.keys[frames.index(key.frame)]
        raise TakeError(source, f"key {key.id} (frame {key.frame}) would land on the same frame "
                                f"as key {there.id} (frame {there.frame}): keys must be in "
                                "strictly increasing frames")
    at = int(np.searchsorted(frames, key.frame))
    new = keys.keys[:at] + [key] + keys.keys[at:]
    check_frames([k.frame for k in new], source, keys.fps, [k.id for k in new])
    return _keys(keys, new)


def retime(keys: Keys, frames: dict[int, int], source="shot") -> Keys:
    """Keys moved to new frames ({key id: frame}); TakeError naming the keys when that would
    reorder them, put two on one frame, or a key past the shot's length
    (``puppet.limits.SHOT_SECONDS``)."""
    new = list(keys.keys)
    for key_id, frame in frames.items():
        i = keys.position(key_id, source)
        new[i] = replace(new[i], frame=int(frame))
    check_frames([k.frame for k in new], source, keys.fps, [k.id for k in new])
    return _keys(keys, new)


def interpolate(keys: Keys, kinds: dict[int, str], source="shot") -> Keys:
    """Keys with new interpolations ({key id: "linear" | "smooth" | "step"}: how the frames
    after each of those keys are filled)."""
    new = list(keys.keys)
    for key_id, kind in kinds.items():
        i = keys.position(key_id, source)
        new[i] = replace(new[i], interpolation=check_interpolation(kind, source))
    return _keys(keys, new)
