"""Check the steps of docs/blender.md in Blender itself (run with Blender's Python: ``bpy``).

    puppet export take.mcap --fps 24 --gltf anim.glb --usd anim.usdc --bvh skeleton.bvh \\
        --pc2 mesh_z.pc2 --up z
    python docs/blender_check.py anim.glb mesh_z.pc2 skeleton.bvh anim.usdc

Needs the ``bpy`` module (``pip install bpy`` in its own environment, Python 3.11) or
``blender --background --python docs/blender_check.py -- FILES``. Each step is done the way the
document says, through the same operators the File > Import menus call, and its result is
compared with the point cache, which holds the FAST mesh exactly. Prints one line per check.
"""

import struct
import sys

import bpy
import numpy as np


def fresh(fps):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.context.scene.render.fps = fps
    bpy.context.scene.render.fps_base = 1.0


def world_vertices(obj):
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    return np.array([(evaluated.matrix_world @ v.co)[:] for v in evaluated.data.vertices])


def read_pc2(path):
    with open(path, "rb") as f:
        _, _, n, start, _, samples = struct.unpack("<12siiffi", f.read(32))
        return start, np.frombuffer(f.read(), np.float32).reshape(samples, n, 3)


def main(glb, pc2_z, bvh, usd, fps=24):
    start, mesh = read_pc2(pc2_z)  # written with --up z: Blender's own axes
    frames = len(mesh)
    checks = []

    def check(name, ok, detail=""):
        checks.append(ok)
        print(f"{'PASS' if ok else 'FAIL'}  {name} {detail}")

    # glTF: File > Import > glTF 2.0, scene at the export's fps first.
    fresh(fps)
    bpy.ops.import_scene.gltf(filepath=glb)
    arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    body = next(o for o in bpy.data.objects if o.type == "MESH")
    action = arm.animation_data.action
    check("glTF: one armature, every joint a bone", len(arm.data.bones) > 0,
          f"({len(arm.data.bones)} bones)")
    check("glTF: keys on frames 1..N", tuple(action.frame_range) == (1.0, float(frames)),
          f"({tuple(action.frame_range)})")
    diagonal = np.linalg.norm(mesh[0].max(0) - mesh[0].min(0))
    worst = 0.0
    for frame in (1, frames // 2, frames):
        bpy.context.scene.frame_set(frame)
        worst = max(worst, np.linalg.norm(world_vertices(body) - mesh[frame - 1], axis=1).max())
    check("glTF: skinned mesh near the FAST mesh", worst < 0.05 * diagonal,
          f"(max {100 * worst / diagonal:.2f} % of the diagonal)")

    # PC2: on the mesh imported from the glTF, a Mesh Cache added below its Armature modifier.
    cache = body.modifiers.new("puppet", "MESH_CACHE")
    check("PC2: Mesh Cache below the Armature, overwriting",
          [m.type for m in body.modifiers] == ["ARMATURE", "MESH_CACHE"]
          and cache.deform_mode == "OVERWRITE")
    cache.cache_format = "PC2"
    cache.filepath = pc2_z
    cache.frame_start = 1.0
    worst = 0.0
    for frame in (1, 2, frames // 2, frames):
        bpy.context.scene.frame_set(frame)
        worst = max(worst, np.linalg.norm(world_vertices(body) - mesh[frame - 1], axis=1).max())
    check("PC2 --up z, Frame Start 1, default axes: exact", worst < 1e-5, f"(max {worst:.1e})")
    check("PC2 header start frame", start == 1.0, f"({start})")

    # BVH: File > Import > Motion Capture (.bvh), Update Scene FPS and Duration on.
    fresh(fps)
    bpy.ops.import_anim.bvh(filepath=bvh, update_scene_fps=True, update_scene_duration=True)
    arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    scene = bpy.context.scene
    check("BVH: scene fps from the file", scene.render.fps == fps, f"({scene.render.fps})")
    check("BVH: first frame on scene frame 1",
          tuple(arm.animation_data.action.frame_range) == (1.0, float(frames)),
          f"({tuple(arm.animation_data.action.frame_range)})")

    # USD: File > Import > Universal Scene Description.
    fresh(fps)
    bpy.ops.wm.usd_import(filepath=usd)
    scene = bpy.context.scene
    body = next(o for o in bpy.data.objects if o.type == "MESH")
    arms = [o for o in bpy.data.objects if o.type == "ARMATURE"]
    check("USD: frame range 1..N set from the stage", (scene.frame_start, scene.frame_end) ==
          (1, frames), f"({scene.frame_start}..{scene.frame_end})")
    check("USD: skeleton imported as an armature", len(arms) == 1)
    worst = 0.0
    for frame in (1, frames // 2, frames):
        scene.frame_set(frame)
        worst = max(worst, np.linalg.norm(world_vertices(body) - mesh[frame - 1], axis=1).max())
    check("USD: mesh points are the FAST mesh", worst < 1e-5, f"(max {worst:.1e})")
    print(f"{sum(checks)} passed, {len(checks) - sum(checks)} failed")
    return all(checks)


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    sys.exit(0 if main(*args[:4], fps=int(args[4]) if len(args) > 4 else 24) else 1)
