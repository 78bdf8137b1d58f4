"""Joint names that every file format accepts: ASCII letters, digits and underscores.

BVH splits on whitespace and many importers choke on punctuation; USD joint paths need valid
identifiers. ``safe_names`` maps each name to one that is non-empty, starts with a letter or an
underscore, holds only ``[A-Za-z0-9_]``, and is unique (a suffix ``_2``, ``_3``... where two
names would collide). The mapping is reported to the user for every name it changes.
"""

from __future__ import annotations

import re
import unicodedata

_BAD = re.compile(r"[^A-Za-z0-9_]")


def safe_name(name: str) -> str:
    """One name made safe (uniqueness aside): accents dropped, other characters -> '_'."""
    ascii_name = unicodedata.normalize("NFKD", str(name)).encode("ascii", "ignore").decode()
    out = _BAD.sub("_", ascii_name)
    if not out or out[0].isdigit():
        out = "_" + out
    return out


def safe_names(names) -> tuple[list[str], dict[str, str]]:
    """(safe names in the same order, {original: safe} for every name that changed)."""
    taken: set[str] = set()
    originals = [str(n) for n in names]
    reserved = {n for n in originals if safe_name(n) == n}  # unchanged names keep their spelling
    out, changed = [], {}
    for name in originals:
        base = safe_name(name)
        candidate, k = base, 2
        while candidate in taken or (candidate != name and candidate in reserved):
            candidate, k = f"{base}_{k}", k + 1
        taken.add(candidate)
        out.append(candidate)
        if candidate != name:
            changed[name] = candidate
    return out, changed
