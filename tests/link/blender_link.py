"""Run with bpy: install and enable the add-on from its zip, import the exported .glb twice
(a reference playing the file's animation, and a target the add-on drives), connect to a
running ``puppet play --link``, apply and record frames by calling the add-on's own tick
(module mode has no event loop), then print RESULT {json}: per recorded frame the largest
difference of bone heads and tails (world) between target and reference, the mesh mode's
vertices (world, on the add-on's copy of the mesh), and the add-on's status lines.

argv: ZIP GLB PORT MESH(0/1)
"""

import json
import sys
import time

import bpy

zip_path, glb, port, use_mesh = sys.argv[-4:]
port, use_mesh = int(port), use_mesh == "1"
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path, overwrite=True)
bpy.ops.preferences.addon_enable(module="puppet_link")
import puppet_link  # noqa: E402  (installed just now)

scene = bpy.context.scene
scene.render.fps, scene.render.fps_base = 30, 1.0  # the take's rate, before the import
bpy.ops.import_scene.gltf(filepath=glb)
reference = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
before = set(bpy.context.scene.objects)
bpy.ops.import_scene.gltf(filepath=glb)
new = [o for o in bpy.context.scene.objects if o not in before]
target = next(o for o in new if o.type == "ARMATURE")
target_mesh = next(o for o in new if o.type == "MESH")
target.animation_data_clear()
settings = scene.puppet_link
settings.port, settings.armature, settings.mesh = port, target, target_mesh
settings.use_mesh, settings.record, settings.start_frame = use_mesh, not use_mesh, 1
assert bpy.ops.puppet_link.connect() == {"FINISHED"}
link = puppet_link.LINK
keyed, meshes = [], []
deadline = time.monotonic() + 600
while link.sock is not None and time.monotonic() < deadline:
    applied = link.frames_applied
    puppet_link.tick()
    if link.frames_applied > applied:
        keyed.append(settings.start_frame + round(link.last_take_s * 30))
        if use_mesh and len(meshes) < 3:
            shown = bpy.data.objects[link.exact.copy]
            co = [0.0] * (3 * len(shown.data.vertices))
            shown.data.vertices.foreach_get("co", co)
            mw = shown.matrix_world
            meshes.append({"take_s": link.last_take_s,
                           "world": [list(mw @ __import__("mathutils").Vector(co[3 * i:3 * i + 3]))
                                     for i in range(len(co) // 3)]})
    time.sleep(0.002)
result = {"status": link.status, "notes": link.notes, "applied": link.frames_applied,
          "malformed": link.malformed, "frames": [], "meshes": meshes, "keyed": keyed}
if not use_mesh:
    for f in sorted(set(keyed)):
        scene.frame_set(f)
        worst = moved = 0.0
        for bone in target.pose.bones:
            ref = reference.pose.bones[bone.name]
            for a, b, rest in ((target.matrix_world @ bone.head, reference.matrix_world @ ref.head,
                                target.matrix_world @ bone.bone.head_local),
                               (target.matrix_world @ bone.tail, reference.matrix_world @ ref.tail,
                                target.matrix_world @ bone.bone.tail_local)):
                worst = max(worst, (a - b).length)
                moved = max(moved, (a - rest).length)
        result["frames"].append({"frame": f, "worst": worst, "moved": moved})
print("RESULT " + json.dumps(result))
