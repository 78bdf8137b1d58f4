"""What a take (or shot) of a rig is written with: the one place a take's header is made."""

from __future__ import annotations

from pathlib import Path

RIG_SOURCE_MARK = "# puppet: recorded from rig file "
"""Last line added to the rig map text a take stores: where that rig file was when recording
began, so ``play``/``export`` without ``--rig`` find its character files (relative paths are
relative to it). A TOML comment: the stored text parses as the rig file did, same line numbers;
takes without it (older ones) still play."""

RIG_CHARACTER_MARK = "# puppet: recorded on character sha256 "
"""Line added before RIG_SOURCE_MARK: the checksum of the character the take was recorded on
(``puppet.rig.checksum.character_sha256``), so a take replayed without ``--rig`` is never solved on
a character changed since (its rig file's character edited or replaced). Older takes lack it."""



def take_header(rig) -> dict:
    """TakeWriter's keywords for a take of ``rig``: ids, models, rig_map_text (the rig file, its
    character's content hash and where the file was), calibration_text and rig_name."""
    from puppet.rig.checksum import character_sha256
    from puppet.rig.calibration import Calibration

    map_text = ""
    if rig.path is not None and rig.path.suffix == ".toml":
        map_text = rig.path.read_text(encoding="utf-8")
        map_text += ("" if map_text.endswith("\n") or not map_text else "\n")
        map_text += f"{RIG_CHARACTER_MARK}{character_sha256(rig)}\n"
        map_text += f"{RIG_SOURCE_MARK}{rig.path.resolve()}\n"
    calibration = Calibration.capture(rig.servo_map.ids, rig.servo_map.zero)
    return {"ids": [int(i) for i in rig.servo_map.ids], "models": dict(rig.servo_map.models),
            "rig_map_text": map_text, "calibration_text": calibration.to_record(),
            "rig_name": rig.name}


def check_take_path(take_path: str | Path, rig, *, force: bool, inputs=()) -> Path:
    """Refuse a take path that is one of the rig's files (or of ``inputs``), a device or FIFO,
    or an existing file without ``force`` (``puppet.atomic``'s rule)."""
    from puppet.atomic import check_output
    from puppet.rig.rig_file import loaded_files

    return check_output(take_path, kind="take", inputs=[*loaded_files(rig), *inputs], force=force,
                        keep_existing=True, what="take")


def take_writer(take_path: str | Path, rig, *, force: bool = False, sound=None, timecode=None):
    """A new TakeWriter for the rig's servos, with its header (and the take's sound reference
    and start timecode, when given). An existing file at take_path is replaced only with
    ``force``; a rig file never."""
    from puppet.take.writer import TakeWriter

    check_take_path(take_path, rig, force=force)
    return TakeWriter(take_path, **take_header(rig), overwrite=force, sound=sound,
                      timecode=timecode)
