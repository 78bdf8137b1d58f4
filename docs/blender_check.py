"""Do every step of docs/blender.md in Blender and show what each step gives (needs ``bpy``).

    puppet export take.mcap --fps 24 --gltf anim.glb --usd anim.usdc --bvh skeleton.bvh \\
        --pc2 mesh.pc2 --up z
    python docs/blender_check.py --fps 24 --frames N --glb anim.glb --pc2 mesh.pc2 \\
        --bvh skeleton.bvh --usd anim.usdc [--character creature.glb] [--save shown.npz]

N is the frame count that ``puppet export`` printed; ``--character`` is the glTF file the rig
was made from (the PC2 and the BVH then go on its mesh, as on the user's own character).
Run it with the ``bpy`` module (``pip install bpy``, Python 3.11) or with
``blender --background --python docs/blender_check.py -- ARGS``. Each step is done as the
document says, through the operators that the File > Import menus call, in a fresh scene:

  gltf       glTF import of anim.glb (scene rate and range set as the document says);
  pc2_glb    a Mesh Cache with the PC2 on the mesh of that import;
  pc2_source a Mesh Cache with the PC2 on the mesh of the character file (with --character);
  bvh        the BVH imported, and the character's mesh (else the glTF's) driven by it through
             its Armature modifier and its own vertex groups;
  usd        USD import of anim.usdc.

It prints one line per step: the mesh's vertex count, the scene's rate and range, and how far
the mesh is from the PC2 step's (the exact FAST mesh) over every frame, in % of the diagonal of
the character's rest bounding box (as ``puppet export`` prints its figures). ``--save`` writes
what each step showed (world-space vertices of every frame, the scene's rate and range, bone and
vertex group names, UV maps, materials, images, object placement) to an .npz file, which the
tests (tests/export/blender) read.
"""

import argparse
import json
import sys

import bpy
import numpy as np


def fresh_scene(fps=None):
    """An empty scene (Blender's defaults: 24 fps, frames 1..250), at ``fps`` when given (docs:
    "Set the scene's frame rate to the export's")."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if fps is not None:  # fps / fps_base is the rate: any rate, 23.976 or 0.5 alike
        bpy.context.scene.render.fps = max(1, round(fps))
        bpy.context.scene.render.fps_base = max(1, round(fps)) / fps


def skinned_mesh():
    """The mesh object that an Armature modifier deforms (not a bone's display shape)."""
    found = [o for o in bpy.data.objects
             if o.type == "MESH" and any(m.type == "ARMATURE" for m in o.modifiers)]
    if len(found) != 1:
        raise SystemExit(f"expected one skinned mesh, found {[o.name for o in found]}")
    return found[0]


def rest_vertices(obj) -> np.ndarray:
    """(n, 3) the mesh's own vertices (no modifier: its rest pose) in world space."""
    co = np.empty(3 * len(obj.data.vertices))
    obj.data.vertices.foreach_get("co", co)
    M = np.array(obj.matrix_world)
    return co.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]


def world_vertices(obj) -> np.ndarray:
    """(n, 3) the evaluated mesh (every modifier applied) in world space."""
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = evaluated.data
    co = np.empty(3 * len(mesh.vertices))
    mesh.vertices.foreach_get("co", co)
    M = np.array(evaluated.matrix_world)
    return co.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]


def scene_state(frames_of=None) -> dict:
    scene = bpy.context.scene
    state = {"fps": scene.render.fps / scene.render.fps_base,
             "frame_start": scene.frame_start, "frame_end": scene.frame_end}
    if frames_of is not None and frames_of.animation_data and frames_of.animation_data.action:
        state["action_range"] = tuple(frames_of.animation_data.action.frame_range)
    return state


def fcurves(action) -> list:
    """Every F-curve of an action: in its layers' channel bags (Blender 4.4 and later), else
    the action's own list."""
    if not hasattr(action, "layers"):
        return list(action.fcurves)
    return [c for layer in action.layers for strip in layer.strips for bag in strip.channelbags
            for c in bag.fcurves]


def look(mesh) -> dict:
    """The mesh's UV maps, colour attributes and materials, and the images loaded (with pixels)."""
    return {"uv_layers": [uv.name for uv in mesh.data.uv_layers],
            "color_attributes": [c.name for c in mesh.data.color_attributes],
            "materials": [m.name for m in mesh.data.materials if m],
            "images": sorted(i.name for i in bpy.data.images if i.has_data or i.size[0])}


def placement(mesh) -> dict:
    """(4, 4) world matrices of a mesh object and of the armature object of its Armature modifier."""
    armature = next((m.object for m in mesh.modifiers if m.type == "ARMATURE"), None)
    out = {"mesh_world": np.array(mesh.matrix_world)}
    if armature is not None:
        out["armature_world"] = np.array(armature.matrix_world)
    return out


def play(obj) -> dict:
    """{"vertices": (frames, n, 3) world vertices of ``obj`` on every frame of the scene's range}."""
    scene = bpy.context.scene
    vertices = []
    for frame in range(scene.frame_start, scene.frame_end + 1):
        scene.frame_set(frame)
        vertices.append(world_vertices(obj))
    return {"vertices": np.array(vertices)}


def import_gltf(path, fps=None, frames=None):
    """docs, glTF: rate first, File > Import > glTF 2.0 with the defaults, then Start and End
    from the scene's custom properties puppet_frame_start/end that the import made from the
    file (a character file has none: 1 and ``frames``). Without fps and frames: a plain import
    into Blender's default scene."""
    fresh_scene(fps)
    bpy.ops.import_scene.gltf(filepath=path)
    scene = bpy.context.scene
    if frames is not None:
        scene.frame_start = scene.get("puppet_frame_start", 1)
        scene.frame_end = scene.get("puppet_frame_end", frames)
    return skinned_mesh()


def add_mesh_cache(obj, pc2):
    """docs, PC2: Add Modifier > Edit > Mesh Cache, Format PC2, the file, Frame Start 1."""
    cache = obj.modifiers.new("puppet", "MESH_CACHE")
    cache.cache_format = "PC2"
    cache.filepath = pc2
    cache.frame_start = 1.0
    return cache


def import_bvh(path):
    """docs, BVH: File > Import > Motion Capture, Update Scene FPS and Duration ticked."""
    before = set(bpy.data.objects)
    bpy.ops.import_anim.bvh(filepath=path, update_scene_fps=True, update_scene_duration=True)
    return next(o for o in bpy.data.objects if o not in before and o.type == "ARMATURE")


def drive_with(mesh, armature):
    """docs, BVH on your mesh: the mesh's Armature modifier's Object set to the BVH armature."""
    modifier = next(m for m in mesh.modifiers if m.type == "ARMATURE")
    modifier.object = armature


def import_usd(path, fps):
    """docs, USD: rate first, File > Import > Universal Scene Description with the defaults."""
    fresh_scene(fps)
    bpy.ops.wm.usd_import(filepath=path)
    found = [o for o in bpy.data.objects
             if o.type == "MESH" and any(m.type == "MESH_SEQUENCE_CACHE" for m in o.modifiers)]
    if len(found) != 1:
        raise SystemExit(f"expected one mesh with a Mesh Sequence Cache, found {[o.name for o in found]}")
    return found[0]


def run_steps(fps, frames, glb, pc2, bvh, usd, character=None) -> dict:
    """{step: {"vertices": (frames, n, 3), scene state, names...}} for each step given."""
    shown = {}
    if glb:
        body = import_gltf(glb, fps, frames)
        armature = next(m.object for m in body.modifiers if m.type == "ARMATURE")
        action = armature.animation_data.action
        shown["gltf"] = {**scene_state(armature), **play(body), "rest": rest_vertices(body),
                         "keys": sum(len(c.keyframe_points) for c in fcurves(action)),
                         "scene_properties": {k: v for k, v in bpy.context.scene.items()
                                              if k.startswith("puppet_")},
                         "bones": [b.name for b in armature.data.bones],
                         **look(body), **placement(body)}
        if pc2:
            add_mesh_cache(body, pc2)
            shown["pc2_glb"] = {**scene_state(), **play(body)}
    if pc2 and character:
        body = import_gltf(character, fps, frames)
        rest = rest_vertices(body)
        add_mesh_cache(body, pc2)
        shown["pc2_source"] = {**scene_state(), **play(body), "rest": rest, **placement(body)}
    if bvh and (character or glb):
        body = import_gltf(character or glb)  # the BVH import sets the scene's rate and range
        armature = import_bvh(bvh)
        bpy.context.scene.frame_end = frames  # the importer only lengthens the range, to N + 1
        drive_with(body, armature)
        shown["bvh"] = {**scene_state(armature), **play(body),
                        "bones": [b.name for b in armature.data.bones],
                        "vertex_groups": [g.name for g in body.vertex_groups]}
    if usd:
        body = import_usd(usd, fps)
        shown["usd"] = {**scene_state(), **play(body), **look(body), **placement(body)}
    return shown


def report(shown) -> str:
    """One line per step; distances from the PC2 step's mesh (the exact FAST mesh), % of the
    diagonal of the character's rest bounding box (as ``puppet export`` prints them)."""
    reference = next((shown[k]["vertices"] for k in ("pc2_source", "pc2_glb") if k in shown), None)
    rest = next((shown[k]["rest"] for k in ("pc2_source", "gltf") if k in shown), None)
    lines = []
    for step, s in shown.items():
        V = s["vertices"]
        line = (f"{step:10s} {V.shape[1]} vertices, {s['fps']:g} fps, frames "
                f"{s['frame_start']}..{s['frame_end']}")
        if "action_range" in s:
            line += f", keys on {s['action_range'][0]:g}..{s['action_range'][1]:g}"
        if "keys" in s:
            line += f" ({s['keys']} key values)"
        if reference is not None and V.shape == reference.shape:
            diagonal = np.linalg.norm(rest.max(0) - rest.min(0))
            d = np.linalg.norm(V - reference, axis=2) / diagonal * 100
            line += f"; from the PC2 mesh: max {d.max():.3g} %, RMS {np.sqrt((d ** 2).mean()):.3g} %"
        elif reference is not None:
            line += f"; cannot compare with the PC2 mesh: shape {V.shape} vs {reference.shape}"
        lines.append(line)
    return "\n".join(lines)


def save(path, shown) -> None:
    arrays = {f"{step}.{k}": v for step, s in shown.items() for k, v in s.items()
              if isinstance(v, np.ndarray)}
    meta = {step: {k: v for k, v in s.items() if not isinstance(v, np.ndarray)}
            for step, s in shown.items()}
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)


def main(argv) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fps", type=float, required=True)
    parser.add_argument("--frames", type=int, required=True)
    for name in ("glb", "pc2", "bvh", "usd", "character", "save"):
        parser.add_argument(f"--{name}")
    args = parser.parse_args(argv)
    shown = run_steps(args.fps, args.frames, args.glb, args.pc2, args.bvh, args.usd, args.character)
    print(report(shown))
    if args.save:
        save(args.save, shown)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]))
