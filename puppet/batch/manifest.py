"""What a take's outputs were made from: the sidecar manifest ``OUT/<take>.batch.json``.

A take's outputs are a function of its content, its rig, its character and the settings that
shape them; the manifest records each as a checksum or value, with the outputs' sizes and
checksums, and ``--resume`` redoes a take when any of them differs (``changes`` says which, in
words, for its row). The driver writes it through ``puppet.atomic`` (a temporary file renamed
into place) after the take's outputs are in place; it records the outputs' own checksums, so a
manifest left beside outputs it does not describe (an interrupted run, a file replaced by hand)
never makes a take look up to date.

    {"manifest": 1, "puppet": "0.1.0",
     "take": {"path": "session/take01.mcap", "sha256": "..."},
     "rig": {"name": "critter", "file": ".../critter.toml", "sha256": "..."},
     "character": {"sha256": "..."},
     "settings": {"fps": 30.0, "up": "y"},
     "outputs": {"pc2": {"path": "take01.pc2", "bytes": 123, "sha256": "..."}}}
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import puppet
from puppet.atomic import atomic_output
from puppet.checksum import file_sha256

MANIFEST_SUFFIX = ".batch.json"
MANIFEST_VERSION = 1


def shaping_settings(settings) -> dict:
    """The settings (``task.Settings``) that shape the asked formats' bytes: fps always; up and
    space for PC2; keys and keys_units for glTF; size and antialias for the video. A setting no
    asked format uses is left out (changing --size does not redo a batch of exports); a layered
    take's --mute/--solo/--punch (None, as a manifest without it reads: every stack as recorded)."""
    formats = settings.formats
    shaping: dict = {"fps": float(settings.fps)}
    if "pc2" in formats:
        shaping["up"] = settings.up
        shaping["space"] = settings.space
    if "gltf" in formats:
        shaping["keys"] = settings.keys
        shaping["keys_units"] = settings.keys_units
    if "mp4" in formats:
        shaping["size"] = [int(settings.size[0]), int(settings.size[1])]
        shaping["antialias"] = settings.antialias
    shaping["layers"] = None if settings.layers is None else settings.layers.as_dict()
    return shaping


@dataclass(frozen=True)
class Made:
    """What a take's outputs are made from (everything but the outputs themselves).

    take: the take file; take_sha256: its bytes; rig_name, rig_file: the rig (file as the user
    knows it: the --rig file, or the rig file the take was recorded with); rig_sha256: the rig's
    text (the --rig file's bytes, or the rig map the take stores); character:
    ``puppet.rig.checksum.character_sha256``;
    settings: shaping_settings; version: puppet's version."""

    take: str
    take_sha256: str
    rig_name: str
    rig_file: str
    rig_sha256: str
    character: str
    settings: Mapping
    version: str = puppet.__version__

    def record(self, outputs: Mapping[str, Path]) -> dict:
        """The manifest for this take with its written ``outputs`` ({format: final path})."""
        return {"manifest": MANIFEST_VERSION, "puppet": self.version,
                "take": {"path": self.take, "sha256": self.take_sha256},
                "rig": {"name": self.rig_name, "file": self.rig_file, "sha256": self.rig_sha256},
                "character": {"sha256": self.character}, "settings": dict(self.settings),
                "outputs": {fmt: {"path": path.name, "bytes": path.stat().st_size,
                                  "sha256": file_sha256(path)}
                            for fmt, path in outputs.items()}}


def read(path: Path) -> dict | None:
    """The manifest at path; None when absent; {} when unreadable (not JSON, another version)."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError):
        return {}
    try:
        record = json.loads(text)
    except ValueError:
        return {}
    if not isinstance(record, dict) or record.get("manifest") != MANIFEST_VERSION:
        return {}
    return record


def changes(record: dict | None, made: Made, outputs: Mapping[str, Path]) -> list[str]:
    """Why a take's outputs are not up to date, in words ([] when they are): what differs
    between the manifest ``record`` and ``made``, and any asked output that is missing or not
    the file the manifest describes."""
    if record is None:
        return ["new" if not any(p.exists() for p in outputs.values())
                else "no manifest beside its outputs (an older or interrupted run)"]
    if not record:
        return ["its manifest is unreadable"]
    why = []

    def get(*keys):
        value = record
        for key in keys:
            value = value.get(key) if isinstance(value, dict) else None
        return value

    if get("puppet") != made.version:
        why.append(f"puppet {get('puppet')} -> {made.version}")
    if get("take", "sha256") != made.take_sha256:
        why.append("the take changed")
    if get("rig", "sha256") != made.rig_sha256:
        old = get("rig", "file")
        why.append(f"the rig changed ({old} -> {made.rig_file})" if old != made.rig_file
                   else f"the rig changed ({made.rig_file})")
    if get("character", "sha256") != made.character:
        why.append("the character changed")
    old_settings = get("settings") if isinstance(get("settings"), dict) else {}
    for key, value in made.settings.items():
        if old_settings.get(key) != value:
            why.append(f"{key} {_show(old_settings.get(key))} -> {_show(value)}")
    written = get("outputs") if isinstance(get("outputs"), dict) else {}
    for fmt, path in outputs.items():
        entry = written.get(fmt)
        if not isinstance(entry, dict) or entry.get("path") != path.name:
            why.append(f"{path.name} not made yet")
        elif not path.exists():
            why.append(f"{path.name} is missing")
        elif path.stat().st_size != entry.get("bytes") or file_sha256(path) != entry.get("sha256"):
            why.append(f"{path.name} changed since it was written")
    return why


def _show(value) -> str:
    if value is None:
        return "(none)"
    if isinstance(value, list):
        return "x".join(map(str, value))
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


def write(path: Path, made: Made, outputs: Mapping[str, Path], *, inputs=(),
          force: bool = False) -> None:
    """Write the manifest for ``outputs`` (in place already) atomically (``puppet.atomic``)."""
    text = json.dumps(made.record(outputs), indent=1, sort_keys=True) + "\n"
    with atomic_output(path, kind="text", inputs=inputs, force=force,
                       what="manifest") as temporary:
        temporary.write_text(text, encoding="utf-8")
