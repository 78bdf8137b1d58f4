"""Run with bpy: one Blender session of the add-on across two takes, with the user's mesh checked
before and after. argv: ZIP CHARACTER GLB PORT CACHE STALL_AFTER.

1. Installs and enables the add-on from its zip, imports CHARACTER (``puppet blender
   character``'s .glb of the critter, at rest) as the user's character, and snapshots its mesh: the vertex coordinates' bytes and every property of every
   modifier, and the object's visibility.
2. Connect with Record, Exact mesh and a point cache (CACHE) on, before puppet runs: the add-on
   waits and retries by itself. The test starts ``puppet play TAKE --link PORT``; the add-on
   connects, keys every frame; after STALL_AFTER frames applied, Blender stalls 1.5 s (a sleep
   in the tick loop). When puppet says bye, prints TAKE1 (and the panel's lines seen) and goes
   on ticking: the test starts a second ``puppet play`` on the same port, the add-on reconnects
   by itself and records it into a second action, with Exact mesh turned off and on again while
   it streams, then Record off and a 1 s stall (live frames are skipped: the panel says so).
   The scene's strips are listed at TAKE1 and at the end: a strip named "puppet sound" made
   before Connect stands for an earlier take's sound; the second take has a sound.
3. Disconnect, snapshot the user's mesh again; import the first take's reference (GLB: the
   export of that take, scene at 30 fps) and measure, at every keyed frame of the first action, the largest
   distance of bone heads and tails (world) from it. Prints RESULT {json}.
"""

import json
import sys
import time

import bpy

zip_path, character, glb, port, cache, stall_after = sys.argv[-6:]
port, stall_after = int(port), int(stall_after)
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path, overwrite=True)
bpy.ops.preferences.addon_enable(module="puppet_link")
import puppet_link  # noqa: E402  (installed just now)

scene = bpy.context.scene
scene.render.fps, scene.render.fps_base = 30, 1.0  # the take's rate, before the import
bpy.ops.import_scene.gltf(filepath=character)
target = next(o for o in scene.objects if o.type == "ARMATURE")
mesh_object = next(o for o in scene.objects if o.type == "MESH")


def snapshot():
    co = [0.0] * (3 * len(mesh_object.data.vertices))
    mesh_object.data.vertices.foreach_get("co", co)
    modifiers = []
    for modifier in mesh_object.modifiers:
        props = {}
        for prop in modifier.bl_rna.properties:
            if prop.identifier == "rna_type":
                continue
            value = getattr(modifier, prop.identifier)
            props[prop.identifier] = (value.name if hasattr(value, "name") else
                                      list(value) if hasattr(value, "__len__")
                                      and not isinstance(value, str) else value)
        modifiers.append(props)
    return {"co": __import__("hashlib").sha256(
                __import__("array").array("f", co).tobytes()).hexdigest(),
            "vertices": len(co) // 3, "modifiers": modifiers,
            "shape_keys": mesh_object.data.shape_keys is not None,
            "hidden": [mesh_object.hide_viewport, mesh_object.hide_render],
            "objects": sorted(o.name for o in bpy.data.objects),
            "meshes": sorted(m.name for m in bpy.data.meshes)}


before = snapshot()
settings = scene.puppet_link
settings.port, settings.armature, settings.mesh = port, target, mesh_object
settings.use_mesh, settings.record, settings.start_frame = True, True, 1
settings.point_cache = cache
assert bpy.ops.puppet_link.connect() == {"FINISHED"}
link = puppet_link.LINK
states, panel, during = [link.state], set(), {}
deadline = time.monotonic() + 600


def run(until):
    while not until() and time.monotonic() < deadline:
        puppet_link.tick()
        if not states or states[-1] != link.state:
            states.append(link.state)
        panel.update(line.split(":")[0].split(" ")[0] for line in link.health_lines())
        time.sleep(0.002)


run(lambda: link.state == "waiting")  # no puppet yet: it retries
editor = scene.sequence_editor_create()  # an earlier take's strip: the next take's replaces it
strips = editor.strips if hasattr(editor, "strips") else editor.sequences


def strip_list():
    return [{"name": x.name, "frame_start": x.frame_start,
             "path": x.sound.filepath if x.type == "SOUND" else x.type} for x in strips]


strips.new_effect("puppet sound", "COLOR", 2, 1, length=10)  # standing for an earlier take's
print("WAITING", flush=True)  # the test starts puppet now
run(lambda: link.state == "connected")
stalled = False
while link.state != "waiting" and time.monotonic() < deadline:
    puppet_link.tick()
    if link.exact.copy is not None and "copy" not in during:
        during.update(copy=link.exact.copy, hidden=[mesh_object.hide_viewport,
                                                    mesh_object.hide_render])
    panel.update(line.split(":")[0].split(" ")[0] for line in link.health_lines())
    if link.recording is not None:
        during["first_action"] = link.recording.action.name
    if not stalled and link.frames_applied >= stall_after:
        stalled = True
        time.sleep(1.5)  # Blender busy: puppet's frames queue
        puppet_link.tick()
        during["stall_lines"] = link.health_lines()
    time.sleep(0.002)
first = bpy.data.actions[during["first_action"]]
first_name, first_keys = first.name, len(first.layers[0].strips[0].channelbags[0].fcurves[0]
                                         .keyframe_points)
strips_at_take1 = strip_list()
print("TAKE1", flush=True)
states.append("TAKE1")
run(lambda: link.state == "connected")  # reconnected by itself to the second puppet
toggled = 0
while link.state != "waiting" and time.monotonic() < deadline:
    applied = link.frames_applied
    puppet_link.tick()
    if link.frames_applied > applied:
        toggled += 1
        if toggled == 3:
            settings.use_mesh = False
        elif toggled == 6:
            settings.use_mesh = True
        elif toggled == 10:  # Record off, then a stall: live display skips to the newest
            # (early in the take: a loaded host applies few of its frames, and a take that ends
            # within the stall ends the link, and the panel's line, in the same tick)
            settings.record = False
            time.sleep(1.0)
    panel.update(line.split(":")[0].split(" ")[0] for line in link.health_lines())
    time.sleep(0.002)
bpy.ops.puppet_link.disconnect()
puppet_link.tick()
after = snapshot()


def curves(action):
    bags = [bag for layer in action.layers for strip in layer.strips for bag in strip.channelbags]
    return [c for bag in bags for c in bag.fcurves]


actions = {}
for action in bpy.data.actions:
    fc = curves(action)
    actions[action.name] = {
        "curves": len(fc),
        "frames": [sorted({p.co[0] for p in c.keyframe_points}) for c in fc[:1]][0],
        "keys": sorted({len(c.keyframe_points) for c in fc}),
        "interpolation": sorted({p.interpolation for c in fc for p in c.keyframe_points}),
        "paths": sorted({c.data_path.split('"]')[-1] for c in fc})}

# The first action against the reference export, frame by frame.
target.animation_data.action = first
before_import = set(scene.objects)
bpy.ops.import_scene.gltf(filepath=glb)
reference = next(o for o in scene.objects if o not in before_import and o.type == "ARMATURE")
frames = []
for f in actions[first_name]["frames"]:
    scene.frame_set(int(f))
    worst = 0.0
    for bone in target.pose.bones:
        ref = reference.pose.bones[bone.name]
        for a, b in ((target.matrix_world @ bone.head, reference.matrix_world @ ref.head),
                     (target.matrix_world @ bone.tail, reference.matrix_world @ ref.tail)):
            worst = max(worst, (a - b).length)
    frames.append({"frame": f, "worst": worst})
print("RESULT " + json.dumps({
    "before": before, "after": after, "during": during, "states": states,
    "panel": sorted(panel), "first": first_name, "first_keys_at_take1": first_keys,
    "actions": actions, "frames": frames, "status": link.status, "malformed": link.malformed,
    "notes": link.notes, "strips_at_take1": strips_at_take1, "strips": strip_list()}))
