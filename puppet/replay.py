"""Replaying a take: the rig it replays on (calibrated as it was recorded), and its video.

    rig, reader = open_take("take.mcap", None)          # the take's own rig; or a rig file / Rig
    summary = play_take(rig, reader, [VideoSink("take.mp4", 30)], fps=30)

``puppet play`` and ``puppet batch`` both call these, so a take replayed alone or in a batch
gives the same frames (the solve is deterministic: fixed iterations, warm start from rest); the
frames are ``puppet.take.Playback``'s, as every export's.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterable
from pathlib import Path

from puppet.rig import Rig
from puppet.take import TakeError, TakeReader
from puppet.take.header import RIG_CHARACTER_MARK, RIG_SOURCE_MARK


def _mark(meta, mark: str) -> str | None:
    """The value of the last line of the stored rig map starting with ``mark``; None if none."""
    found = None
    for line in meta.rig_map_text.splitlines():
        if line.startswith(mark):
            found = line[len(mark):].strip()
    return found


def recorded_rig_file(meta) -> str | None:
    """Where the rig file was when the take was recorded (RIG_SOURCE_MARK); None when the take
    does not say (a take of a rig made in memory, or an older take)."""
    return _mark(meta, RIG_SOURCE_MARK)


def recorded_character(meta) -> str | None:
    """The sha256 of the character the take was recorded on (RIG_CHARACTER_MARK), or None."""
    return _mark(meta, RIG_CHARACTER_MARK)


def take_inputs(take, rig: Rig, sound=None) -> list[Path]:
    """Every file a command replaying ``take`` on ``rig`` reads, which none of its outputs may
    be (``puppet.atomic.check_output``'s inputs): the take, the rig's files
    (``puppet.rig.rig_file.loaded_files``: for the rig the take stores, the character, buffers,
    images and calibration found for it) and its sound (``sound``: a SoundRef with a path: the
    take's stored one, or the --sound file given; None: none). The one list of a replay's
    inputs: add the files a take will name (its session files) here."""
    from puppet.rig.rig_file import loaded_files

    return [Path(take), *loaded_files(rig), *([Path(sound.path)] if sound is not None else [])]


def rig_from_take(take, meta) -> Rig:
    """The rig a take was recorded with, from the rig map text it stores.

    Its character files are looked for relative to where the rig file was when recording began
    (RIG_SOURCE_MARK), then next to the take, then (for a take of the built-in rig) in the
    built-in rig's folder; the error names the missing file and the --rig option. A take that
    recorded its character's checksum (RIG_CHARACTER_MARK) is refused (TakeError) when the
    character found is another one.
    """
    from puppet.rig.checksum import character_sha256
    from puppet.rig import builtin
    from puppet.rig.load import BUILTIN_RIG, builtin_name, load_rig_text

    text = meta.rig_map_text
    if not text.strip():
        if meta.rig_name == builtin_name():
            return builtin()
        raise TakeError(take, f"the take stores no rig map (recorded with rig {meta.rig_name!r} "
                              "loaded from a character file); pass --rig with that rig's file")
    recorded = recorded_rig_file(meta)
    bases = [Path(recorded).parent] if recorded else []
    bases.append(Path(take).resolve().parent)
    if meta.rig_name == builtin_name():
        bases.append(BUILTIN_RIG.parent)
    where = f"recorded with rig file {recorded}" if recorded else "recorded with a rig file"
    rig = load_rig_text(text, label=f"{take} (rig map)", bases=bases,
                        hint=f"{where}; pass --rig with that rig file")
    character = recorded_character(meta)
    if character is not None and character != character_sha256(rig):
        found = rig.source.path if getattr(rig, "source", None) is not None else None
        raise TakeError(take, f"the character found for its rig ({where}) is not the one it was "
                              "recorded on: its vertices, weights, skeleton or file changed since"
                              f"{f' ({found})' if found else ''}; pass --rig to solve it on a "
                              "rig of your choosing")
    return rig


def open_take(take, rig: Rig | str | Path | None) -> tuple[Rig, TakeReader]:
    """(rig, TakeReader) for a take, the rig's servos checked against the take's.

    rig: None for the rig the take stores (``rig_from_take``), a rig file to load, or a loaded
         Rig (a copy is calibrated and returned; the argument is left untouched).
    The returned rig carries the calibration the take was recorded with (its zero ticks).
    Raises TakeError (empty take, take from another rig) or RigError (the rig's, or the take's
    unreadable calibration record), each naming the file.
    """
    from puppet.rig import Calibration, load_rig

    reader = TakeReader(take)
    if len(reader) == 0:
        raise TakeError(take, "the take holds no readings")
    meta = reader.metadata
    if rig is None:
        rig = rig_from_take(take, meta)
    elif isinstance(rig, Rig):
        rig = copy.deepcopy(rig)  # the calibration below is this take's own
    else:
        rig = load_rig(rig)
    reader.check_rig([int(i) for i in rig.servo_map.ids], dict(rig.servo_map.models),
                     rig_name=rig.name)
    from puppet.take.layers import layer_notes

    notes = layer_notes(reader)  # a layer: its stack checked, what it says said once
    if notes:
        reader.report.notes.extend(notes)
        reader.recovery = reader.report.text()
    recorded = Calibration.from_record(meta.calibration_text, take)
    if recorded.zero_ticks:  # replay with the calibration the take was recorded with
        rig.servo_map.calibrate(recorded)
    return rig, reader


PLAY_SIZE = (640, 480)
"""(width, height) pixels of a played take's video and frames (``puppet play``, batch's mp4)."""


def play_take(rig: Rig, reader: TakeReader, sinks: Iterable, *, fps: float = 30.0,
              speed: float = 1.0, antialias: str = "msaa", size: tuple[int, int] = PLAY_SIZE,
              precompute=None, progress: Callable[[int, int], None] | None = None,
              should_stop: Callable[[], bool] = lambda: False, frames=None, solved: Iterable = (),
              layers=None):
    """Solve and render every frame of a take into ``sinks`` (objects with ``write(image)``).

    fps: frames per second of the output; speed: playback speed factor; the frames are
    ``puppet.take.Playback``'s (``frames``: one made earlier, e.g. shared with exports; None:
    made here from fps, speed and ``layers``, a layered take's ``LayerOptions``). size: (width, height) pixels; precompute: a shared
    ``RigPrecompute`` of ``rig`` (None: built here). solved: more per-frame sinks of the solve,
    objects with ``write(pipeline)`` called after each frame's solve (batch's
    ``puppet.export.ExportWriters``: one solve for the video and every export). progress:
    called with (frames done, frames in all) after each frame. should_stop() (Ctrl-C, SIGTERM)
    ends it after a whole frame. Returns the pipeline's Summary. The caller closes the sinks.
    """
    from puppet.loop import Pipeline, run_frames
    from puppet.take import Playback

    if frames is None:
        frames = Playback.of_take(reader, rig.servo_map.ids, fps=fps, speed=speed, rig=rig,
                                  layers=layers)
    solved = list(solved)
    with Pipeline(rig, overlay=True, antialias=antialias, width=size[0], height=size[1],
                  precompute=precompute) as pipeline:
        total = len(frames)
        done = [0]

        def on_frame(solved_pipeline) -> None:
            for sink in solved:
                sink.write(solved_pipeline)
            done[0] += 1
            if progress is not None:
                progress(done[0], total)

        return run_frames(pipeline, frames, sinks=sinks, on_frame=on_frame,
                          should_stop=should_stop)
