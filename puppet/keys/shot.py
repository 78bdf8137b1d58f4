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


def write_shot(path, header: dict, keys: Keys) -> None:
    """Write a shot: one reading per key at its time, then the keys channel; whole or absent
    (a temporary file renamed over ``path``). The caller has checked ``path``
    (``puppet.atomic.check_output``)."""
    path = Path(path)
    check_frames([k.frame for k in keys.keys], path)
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
    if keys is None:
        raise TakeError(path, "not a shot: the take has no keys channel (/puppet/keys); "
                              "record keys with `puppet keys`")
    meta = reader.metadata
    header = {"ids": [int(i) for i in meta.ids], "models": dict(meta.models),
              "rig_map_text": meta.rig_map_text, "calibration_text": meta.calibration_text,
              "rig_name": meta.rig_name}
    return header, keys, reader


def _index(keys: Keys, index: int, source) -> int:
    if not 0 <= int(index) < len(keys.keys):
        raise TakeError(source, f"no key {index}: the shot has keys 0..{len(keys.keys) - 1}"
                        if keys.keys else f"no key {index}: the shot has no keys")
    return int(index)


def replace_key(keys: Keys, index: int, key: Key, source="shot") -> Keys:
    """Key ``index`` re-posed: ``key``'s ticks and ok at the old key's frame and interpolation."""
    i = _index(keys, index, source)
    new = list(keys.keys)
    new[i] = replace(new[i], ticks=key.ticks, ok=key.ok)
    return Keys(keys.fps, new)


def remove_key(keys: Keys, index: int, source="shot") -> Keys:
    """The keys without key ``index`` (the others keep their frames)."""
    i = _index(keys, index, source)
    return Keys(keys.fps, keys.keys[:i] + keys.keys[i + 1:])


def insert_key(keys: Keys, key: Key, source="shot") -> Keys:
    """The keys with ``key`` added at its frame (TakeError naming the key already there)."""
    frames = [k.frame for k in keys.keys]
    at = int(np.searchsorted(frames, key.frame))
    new = keys.keys[:at] + [key] + keys.keys[at:]
    check_frames([k.frame for k in new], source)
    return Keys(keys.fps, new)


def retime(keys: Keys, frames: dict[int, int], source="shot") -> Keys:
    """Keys moved to new frames ({index: frame}); TakeError naming both keys when that would
    reorder them or put two on one frame."""
    new = list(keys.keys)
    for index, frame in frames.items():
        i = _index(keys, index, source)
        new[i] = replace(new[i], frame=int(frame))
    check_frames([k.frame for k in new], source)
    return Keys(keys.fps, new)


def interpolate(keys: Keys, kinds: dict[int, str], source="shot") -> Keys:
    """Keys with new interpolations ({index: "linear" | "smooth" | "step"}: how the frames after
    each of those keys are filled)."""
    new = list(keys.keys)
    for index, kind in kinds.items():
        i = _index(keys, index, source)
        new[i] = replace(new[i], interpolation=check_interpolation(kind, source))
    return Keys(keys.fps, new)
