"""Joint names as each file format can hold them: one rule per format, the rig's spelling kept
wherever the format's reader keeps it.

- ``"bvh"``: a BVH file separates its words by whitespace, so every whitespace character (and
  every control character) becomes ``_``, which is also what Blender's BVH importer does to a
  name it finds split in two (it joins the words with ``_``: no spelling of a space survives
  it). To drive a character whose bones or vertex groups have spaces ("Neck Base.001"), the
  live link's add-on maps the names back by this same rule (its "BVH names back" operator;
  this file ships inside the add-on for it: standard library only). Non-ASCII letters lose their accents (``é`` -> ``e``; others -> ``_``):
  Blender's importer reads the file in the system's text encoding, which is UTF-8 only on some
  systems. Everything else is kept as written: dots, ``.L``/``.R`` (Blender's mirroring),
  brackets, ``#``, ``/``, quotes; checked by importing every kept name into Blender 5.0
  (``bpy.ops.import_anim.bvh``: the bone is named exactly as the joint).
- ``"usd"``: USD joint paths are made of identifiers: ``[A-Za-z0-9_]``, not starting with a digit
  (a leading ``_`` is added); every other character becomes ``_``. (The Skeleton's
  ``jointNames`` keep the rig's spelling.)

Names are made unique after the rule by a suffix ``_2``, ``_3``...; a name the rule leaves alone
keeps its spelling. Blender cuts bone and vertex-group names at 63 bytes on every import alike.
"""

from __future__ import annotations

import re
import unicodedata

RULES = ("bvh", "usd")
_NOT_IDENTIFIER = re.compile(r"[^A-Za-z0-9_]")


def _ascii(name: str) -> str:
    """name with accents dropped (NFKD); other non-ASCII characters -> '_'."""
    decomposed = unicodedata.normalize("NFKD", name)
    kept = "".join(ch for ch in decomposed if not unicodedata.combining(ch))
    return "".join(ch if ch.isascii() else "_" for ch in kept)


def safe_name(name: str, rule: str = "usd") -> str:
    """One name under a format's rule (uniqueness aside); rule: one of RULES."""
    out = _ascii(str(name))
    if rule == "bvh":
        out = "".join("_" if ch.isspace() or not ch.isprintable() else ch for ch in out)
        return out or "_"
    if rule != "usd":
        raise ValueError(f"naming rule must be one of {RULES}, got {rule!r}")
    out = _NOT_IDENTIFIER.sub("_", out)
    if not out or out[0].isdigit():
        out = "_" + out
    return out


def safe_names(names, rule: str = "usd") -> tuple[list[str], dict[str, str]]:
    """(names under ``rule``, same order, unique; {original: new} for every name that changed)."""
    taken: set[str] = set()
    originals = [str(n) for n in names]
    reserved = {n for n in originals if safe_name(n, rule) == n}  # unchanged names keep their spelling
    out, changed = [], {}
    for name in originals:
        base = safe_name(name, rule)
        candidate, k = base, 2
        while candidate in taken or (candidate != name and candidate in reserved):
            candidate, k = f"{base}_{k}", k + 1
        taken.add(candidate)
        out.append(candidate)
        if candidate != name:
            changed[name] = candidate
    return out, changed
