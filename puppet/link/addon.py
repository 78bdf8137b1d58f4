"""The Blender add-on's zip: ``puppet/blender_addon/puppet_link/`` plus this package's ``wire``
module and ``puppet.export.names``, copied verbatim (both ends of the link speak the same
protocol file; the add-on maps BVH names back by puppet's own rule)."""

from __future__ import annotations

import zipfile
from pathlib import Path

from puppet.atomic import OutputError, atomic_output, check_output

ADDON = Path(__file__).resolve().parents[1] / "blender_addon" / "puppet_link"
WIRE = Path(__file__).resolve().with_name("wire.py")
NAMES = Path(__file__).resolve().parents[1] / "export" / "names.py"
NAME = "puppet_link"


def addon_files() -> dict[str, bytes]:
    """{path in the zip: bytes}: the add-on's files, wire.py and names.py, under puppet_link/."""
    files = {f"{NAME}/{p.relative_to(ADDON).as_posix()}": p.read_bytes()
             for p in sorted(ADDON.rglob("*")) if p.is_file() and "__pycache__" not in p.parts}
    files[f"{NAME}/wire.py"] = WIRE.read_bytes()
    files[f"{NAME}/names.py"] = NAMES.read_bytes()
    return files


def write_addon(out, *, force: bool = False) -> Path:
    """Write the add-on's zip at ``out`` (the one rule for outputs: ``puppet.atomic``)."""
    if Path(out).suffix.lower() != ".zip":
        raise OutputError(f"{out}: the add-on is a zip archive that Blender installs: name it "
                          "*.zip (e.g. puppet_link.zip)")
    target = check_output(out, kind="npz", inputs=[], force=force, what="add-on")
    with atomic_output(target, kind="npz", inputs=[], force=force, what="add-on") as temporary:
        with zipfile.ZipFile(temporary, "w", zipfile.ZIP_DEFLATED) as archive:
            for name, data in addon_files().items():
                archive.writestr(name, data)
    return Path(out)
