"""A starting rig file for a character: ``puppet rig init CHARACTER.glb``.

The file lists every joint (parents first) with its parent, where its rest axes point in the
character's own words, and what a positive turn about each does; suggests a fixed root (and
fixes bones that no vertex follows: the solve could not place them) and solver options sized
to the mesh; and holds one commented ``[[servo]]`` block per joint for the user to uncomment
and fill (``puppet rig axes`` and ``puppet calibrate --guided`` help).
The text parses as it is (``puppet rig info`` loads it: a rig with no servos yet).

Joint names are written as TOML strings with every non-printable character (controls, line and
paragraph separators, format characters) as a ``\\uXXXX`` escape, which TOML reads back to the
same name; comments show Python's repr (which escapes them too). Names glTF cannot hold as
Unicode text (a lone surrogate) are refused when the file is read (puppet.rig.gltf, with its
joint and vertex bounds).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from puppet.atomic import atomic_output, check_output
from puppet.rig.directions import bone_axes
from puppet.rig.errors import RigError

#: Suggested servo model in the commented blocks (the user sets their own).
SUGGESTED_MODEL = "XL330-M288"
MAX_CLUSTERS = 200
#: One extra weight per this many vertices, at most MAX_EXTRA_WEIGHTS.
VERTICES_PER_EXTRA_WEIGHT = 1000
MAX_EXTRA_WEIGHTS = 8


def suggested_solver(vertices: int, bones: int) -> tuple[int, int]:
    """(clusters, extra_weights) for a mesh of ``vertices`` welded vertices and ``bones`` bones.

    Clusters grow as the square root of the vertex count (FAST's figures: 50-200 for 10k-50k
    vertices), at least one per bone, at most MAX_CLUSTERS and a third of the vertices; extra
    weights (free handles for secondary motion) only on meshes large enough to carry them.
    """
    clusters = int(np.clip(round(np.sqrt(vertices)), max(bones, 8), MAX_CLUSTERS))
    clusters = max(1, min(clusters, vertices // 3))
    extra = min(MAX_EXTRA_WEIGHTS, vertices // VERTICES_PER_EXTRA_WEIGHT)
    return clusters, extra


def suggested_root(parents: np.ndarray, unused: set[int]) -> int:
    """The bone to hold fixed: the root with the most descendants, moved down past bones that
    influence no vertex while they have exactly one child (an exporter's 'root' bone)."""
    parents = np.asarray(parents)  # parents first: parents[i] < i
    children: dict[int, list[int]] = {i: [] for i in range(len(parents))}
    size = np.ones(len(parents), np.int64)  # bones in each subtree, summed up without recursion
    for i in range(len(parents) - 1, -1, -1):
        if parents[i] >= 0:
            children[int(parents[i])].insert(0, i)
            size[parents[i]] += size[i]
    roots = [int(i) for i in np.flatnonzero(parents < 0)]
    bone = max(roots, key=lambda i: size[i])
    while bone in unused and len(children[bone]) == 1:
        bone = children[bone][0]
    return bone


COMMENT_COLUMN = 32


def _line(code: str, comment: str) -> str:
    """``code`` with ``# comment`` aligned at COMMENT_COLUMN."""
    return f"{code:<{COMMENT_COLUMN - 1}} # {comment}"


def _toml_string(text: str) -> str:
    """A TOML basic string: quotes and backslashes escaped, every non-printable character as
    \\uXXXX (or \\UXXXXXXXX), so the text reads back to ``text`` and holds no control
    character (TOML refuses them, DEL included, in strings and comments)."""
    out = []
    for ch in text:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ch.isprintable():
            out.append(ch)
        else:
            out.append(f"\\u{ord(ch):04X}" if ord(ch) <= 0xFFFF else f"\\U{ord(ch):08X}")
    return '"' + "".join(out) + '"'


def rig_init_text(character_path: Path, rig_path: Path, character, skin: int | None) -> str:
    """The rig file's text for ``character`` (a GltfCharacter) read from ``character_path``,
    to be written at ``rig_path`` (the mesh path is written relative to it)."""
    sk = character.skeleton
    names = sk.names
    unused_names = set(character.unused_joints)
    unused = {i for i, n in enumerate(names) if n in unused_names}
    root = suggested_root(sk.parents, unused)
    fixed = [root] + sorted(unused - {root})
    n = len(character.V)
    clusters, extra = suggested_solver(n, sk.bone_count)
    try:
        mesh = os.path.relpath(character_path.resolve(), rig_path.resolve().parent)
    except ValueError:  # another drive (Windows)
        mesh = str(character_path.resolve())
    try:
        mesh.encode("utf-8")
    except UnicodeEncodeError:  # undecodable bytes in the file's name
        raise RigError("its path is not UTF-8 text: a rig file cannot name it; rename the file",
                       path=character_path) from None
    lines = [
        f"# Rig for {character_path.name}, written by `puppet rig init`.",
        "# Directions are the character's own: glTF's +Y is up and +Z forward, so +X is the",
        "# character's left. Turns are right-handed about the axis (thumb along it).",
        "# Next: uncomment a [[servo]] block for each servo in your puppet and set its axis",
        f"# (`puppet rig axes {rig_path.name}` shows each turn); then",
        f"# `puppet calibrate --rig {rig_path.name} --port PORT --guided` finds each servo's id,",
        "# sign and zero ticks and writes them here (or set them by hand).",
        "",
        f"name = {_toml_string(character_path.stem.encode('utf-8', 'replace').decode())}",
        f"mesh = {_toml_string(mesh.replace(os.sep, '/'))}",
    ]
    if skin is not None:
        lines.append(_line(f"skin = {int(skin)}", "the file has several skins: this one"))
    lines += [
    ]
    if len(fixed) > 1:
        lines.append(f"# no vertex follows {', '.join(repr(names[b]) for b in fixed[1:])}: held fixed "
                     "(the solve cannot place a bone that moves nothing)")
    lines += [
        _line("fixed = [" + ", ".join(_toml_string(names[b]) for b in fixed) + "]",
              "suggested: the root, held still by the puppet's stand"),
        "",
        f"[solver]  # sized to the mesh: {n} vertices ({character.file_vertices} in the file before "
        f"welding seams), {sk.bone_count} bones",
        _line(f"clusters = {clusters}", "rotation clusters: more follow the surface better, cost more"),
        _line(f"extra_weights = {extra}", "free handles for secondary motion (0 on small meshes)"),
        _line('energy = "spokes_and_rims"', "spokes | spokes_and_rims | elements"),
        "",
        "# ---- joints, parents first -----------------------------------------------------------",
    ]
    for i, name in enumerate(names):
        parent = ("root, no parent" if sk.parents[i] < 0
                  else f"parent {names[sk.parents[i]]!r}")
        where, turns = bone_axes(sk.frames[i], sk.heads[i], sk.tails[i])
        lines += ["", f"# joint {name!r} ({parent})"
                  + (": no vertex follows it (held fixed)" if name in unused_names else "")
                  + (": suggested fixed root" if i == root else ""),
                  f"#   rest axes: {where}",
                  f"#   {turns}"]
        if i in fixed:  # a servo there contradicts 'fixed' (refused, naming the line)
            lines.append(f"#   a servo here: take {name!r} out of 'fixed' above first (a fixed "
                         "bone has no joint to read)")
        lines += ["# [[servo]]",
                  _line(f"# id = {i + 1}", "bus id (`puppet scan`), or let calibrate --guided find it"),
                  _line(f'# model = "{SUGGESTED_MODEL}"', "your servo's model"),
                  f"# joint = {_toml_string(name)}",
                  _line('# axis = "x"', "x | y | z | -x | -y | -z | [ax, ay, az]"),
                  "# sign = 1",
                  "# zero_ticks = 2048",
                  "# limits_deg = [-90, 90]"]
    return "\n".join(lines) + "\n"


def write_rig_init(character_path, out=None, *, skin: int | None = None, force: bool = False):
    """Write a starting rig file for a .glb/.gltf character; returns (rig path, GltfCharacter).

    out: the rig file (default: the character's path with .toml). Refuses to overwrite an
    existing file unless ``force``; written atomically.
    """
    from puppet.rig.gltf import external_files, read_gltf

    character_path = Path(character_path)
    if character_path.suffix.lower() not in (".glb", ".gltf"):
        raise RigError(f"rig init reads a glTF character (.glb or .gltf), not {character_path.suffix!r}",
                       path=character_path)
    rig_path = Path(out) if out is not None else character_path.with_suffix(".toml")
    inputs = [character_path, *external_files(character_path)]
    rule = dict(kind="rig file", inputs=inputs, force=force, keep_existing=True, what="rig file")
    check_output(rig_path, **rule)
    if rig_path.suffix.lower() != ".toml":
        raise RigError("a rig file ends in .toml", path=rig_path)
    character = read_gltf(character_path, skin=skin)
    text = rig_init_text(character_path, rig_path, character, skin)
    with atomic_output(rig_path, **rule) as temporary:
        temporary.write_text(text, encoding="utf-8")
    return rig_path, character
