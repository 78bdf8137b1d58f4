"""Finding a take's sound, and keeping a copy of it beside the takes.

A take stores a reference to its sound (``puppet.take.sync.SoundRef``: hash, name, path,
offset, rate), not the sound itself: many takes of one shot share one sound, a take stays the
small append-only file it is written as, and the sound stays a plain file that an editor
(Blender, ffmpeg) opens directly. ``keep_copy`` puts a copy in the takes' folder (a session's),
named by the file and checked by its hash, so a session moved elsewhere keeps its sound.

``find_take_sound`` looks, in order, at the stored path, then beside the take (its folder and
its ``sounds/`` folder) under the stored name; a file counts only when its SHA-256 is the
stored one. A take whose sound is nowhere plays silent: the caller says the warning once.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from puppet.atomic import commit, temporary_sibling
from puppet.sound.decode import Sound, file_sha256, load_sound
from puppet.sound.errors import SoundError

SOUNDS_FOLDER = "sounds"
"""Where ``keep_copy`` puts sounds, inside the takes' folder."""


def candidates(ref, take_path) -> list[Path]:
    """Where a take's sound may be, in the order they are tried (no duplicates)."""
    folder = Path(take_path).absolute().parent
    found: list[Path] = []
    for path in (Path(ref.path), folder / ref.name, folder / SOUNDS_FOLDER / ref.name):
        if path not in found:
            found.append(path)
    return found


def find_take_sound(ref, take_path) -> tuple[Sound | None, str | None]:
    """(the take's sound, None), or (None, a warning in words) when it is missing or changed.

    ref: the take's SoundRef (None: (None, None), a take without sound); take_path: the take.
    A file with the stored name but other content is passed over (named in the warning).
    """
    if ref is None:
        return None, None
    changed = []
    for path in candidates(ref, take_path):
        if not path.is_file():
            continue
        try:
            if file_sha256(path) != ref.sha256:
                changed.append(str(path))
                continue
        except OSError:
            continue
        return load_sound(path), None
    where = ", ".join(str(p) for p in candidates(ref, take_path))
    other = f"; {', '.join(changed)} has other content (its hash differs)" if changed else ""
    return None, (f"{take_path}: its sound {ref.name} (sha256 {ref.sha256[:12]}...) is not at "
                  f"{where}{other}: playing silent")


def keep_copy(sound: Sound, folder) -> Path:
    """A copy of ``sound`` in ``folder``/sounds (made when missing), named as the file; a file of
    that name with other content is kept and the copy is named <stem>-<sha256[:8]><suffix>.
    Written to a temporary file and renamed: never a half copy, never a file written over."""
    target_folder = Path(folder) / SOUNDS_FOLDER
    try:
        target_folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SoundError(target_folder, f"cannot make the sounds folder: {err.strerror or err}") from None
    names = [sound.name, f"{sound.path.stem}-{sound.sha256[:8]}{sound.path.suffix}"]
    for name in names:
        target = target_folder / name
        if target.exists():
            if target.is_file() and file_sha256(target) == sound.sha256:
                return target
            continue
        temporary = temporary_sibling(target)
        try:
            shutil.copyfile(sound.path, temporary)
            if os.path.exists(target):  # made meanwhile: keep it, try the next name
                temporary.unlink()
                continue
            commit(temporary, target)
        except OSError as err:
            temporary.unlink(missing_ok=True)
            raise SoundError(target, f"cannot copy the sound here: {err.strerror or err}") from None
        return target
    raise SoundError(target_folder, f"both {names[0]} and {names[1]} exist with other content")


def sound_for_take(reader, given=None) -> tuple[Sound | None, float, str | None]:
    """(sound, offset_s, warning) to play a take with.

    reader: the take's TakeReader; given: a sound file the user named (``--sound FILE``), or None
    for the take's own (``find_take_sound``). offset_s: the take's stored offset (0 for a take
    recorded without sound). warning: one line when the take's sound is missing (then sound is
    None: it plays silent), else None. A given file that cannot be decoded is a SoundError.
    """
    ref = getattr(reader.metadata, "sound", None)
    offset = ref.offset_s if ref is not None else 0.0
    if given is not None:
        return load_sound(given), offset, None
    sound, warning = find_take_sound(ref, reader.path)
    return sound, offset, warning
