"""Run with bpy: record what ``puppet live --record TAKE --link`` streams, then compare the keys
with the take's ``puppet export --gltf``. argv: ZIP GLB PORT SPAN REFERENCE SENSED.

Installs and enables the add-on from its zip, imports GLB (the character, at 30 fps) and lets
the add-on drive its armature with Record off: puppet's frames are flagged recording, so the
add-on keys them (calling its own tick: module mode has no event loop). Once its keys span SPAN
scene frames it disconnects, prints RECORDED and waits for the REFERENCE .glb (the test exports
the take meanwhile), imports it, and for every keyed scene frame before the export's last
measures, between the recorded action and the export: the largest distance of bone heads and
tails (world), and the largest angle (degrees) between the local rotations (relative to the
parent bone) of the SENSED bones (comma-separated: the joints servos read); and the export's
own largest change of each from that frame to the next. Which frames the two can agree on is
the test's to say (it knows the take's readings): the scene frame of every frame puppet
streamed is in "streamed". Prints RESULT {json}.
"""

import json
import math
import os
import sys
import time

import bpy

zip_path, glb, port, span, reference_glb, sensed = sys.argv[-6:]
port, span, sensed = int(port), float(span), sensed.split(",")
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path, overwrite=True)
bpy.ops.preferences.addon_enable(module="puppet_link")
import puppet_link  # noqa: E402  (installed just now)

scene = bpy.context.scene
scene.render.fps, scene.render.fps_base = 30, 1.0
bpy.ops.import_scene.gltf(filepath=glb)
target = next(o for o in scene.objects if o.type == "ARMATURE")
target.animation_data_clear()
settings = scene.puppet_link
settings.port, settings.armature, settings.record, settings.start_frame = port, target, False, 1
assert bpy.ops.puppet_link.connect() == {"FINISHED"}
link = puppet_link.LINK
keyed = []
deadline = time.monotonic() + 600
while (link.state != "waiting" and (len(keyed) < 2 or keyed[-1] - keyed[0] < span)
       and time.monotonic() < deadline):
    puppet_link.tick()
    if link.recording is not None:
        keyed, streamed = list(link.recording.frames), list(link.recording.streamed)
        action = link.recording.action
    time.sleep(0.002)
status, lost = link.status, link.health.get("lost", 0)
link.close()
recorded = len(keyed)
print("RECORDED", flush=True)
while not os.path.exists(reference_glb) and time.monotonic() < deadline:
    time.sleep(0.1)
before = set(scene.objects)
bpy.ops.import_scene.gltf(filepath=reference_glb)
reference = next(o for o in scene.objects if o not in before and o.type == "ARMATURE")


def points(armature):
    out = []
    for bone in armature.pose.bones:
        out += [armature.matrix_world @ bone.head, armature.matrix_world @ bone.tail]
    return out


def turns(armature):
    out = []
    for name in sensed:
        bone = armature.pose.bones[name]
        local = bone.matrix if bone.parent is None else bone.parent.matrix.inverted() @ bone.matrix
        out.append(local.to_quaternion())
    return out


def degrees(a, b):
    """The largest angle between two lists of rotations (q and -q are one rotation), and the
    bone it is on."""
    angles = [math.degrees(p.rotation_difference(q).angle) for p, q in zip(a, b)]
    return max((min(x, 360.0 - x), name) for x, name in zip(angles, sensed))


fcurves = [c for layer in action.layers for strip in layer.strips
           for bag in strip.channelbags for c in bag.fcurves]
frames = []
last = int(reference.animation_data.action.frame_range[1])  # the export's last frame
for f in range(keyed[0], min(keyed[-1], last - 1) + 1):
    scene.frame_set(f)
    shown, expected = points(target), points(reference)
    shown_turns, expected_turns = turns(target), turns(reference)
    scene.frame_set(f + 1)
    following, following_turns = points(reference), turns(reference)
    worst_deg, worst_bone = degrees(shown_turns, expected_turns)
    frames.append({"frame": f,
                   "worst": max((a - b).length for a, b in zip(shown, expected)),
                   "step": max((a - b).length for a, b in zip(expected, following)),
                   "worst_deg": worst_deg, "worst_bone": worst_bone,
                   "step_deg": degrees(expected_turns, following_turns)[0]})
editor = scene.sequence_editor
sound_strips = [{"name": x.name, "frame_start": x.frame_start, "path": x.sound.filepath}
                for x in (editor.strips if editor is not None else []) if x.type == "SOUND"]
print("RESULT " + json.dumps({"status": status, "sound_strips": sound_strips, "keyed": keyed,
                              "frames": frames, "streamed": streamed, "lost": lost,
                              "recorded": recorded, "action": action.name,
                              "interpolation": sorted({p.interpolation for c in fcurves
                                                       for p in c.keyframe_points})}))
