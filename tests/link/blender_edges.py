"""Run with bpy: the add-on's answers to what goes wrong. argv: ZIP GLB REFUSING_PORT FAKE_PORT.

1. A puppet listening beyond loopback, connected with a wrong token: the panel's status says
   refused.
2. A puppet (the test's fake server) whose rig has one joint more than the armature, with a
   saved mapping naming a bone the armature lacks, that sends a malformed frame, a good one,
   then a health message and nothing for a while (a stalled link), and stops without a word
   once Record is ticked: notes name both joints, the malformed frame is counted and skipped,
   the good one applied, the panel's health lines (once one says the link stalled) give
   puppet's figures, the status says puppet stopped, the last pose stays.
Prints RESULT {json}.
"""

import json
import sys
import time

import bpy

zip_path, glb, refusing, fake = sys.argv[-4], sys.argv[-3], int(sys.argv[-2]), int(sys.argv[-1])
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path, overwrite=True)
bpy.ops.preferences.addon_enable(module="puppet_link")
import puppet_link  # noqa: E402

bpy.ops.import_scene.gltf(filepath=glb)
scene = bpy.context.scene
armature = next(o for o in scene.objects if o.type == "ARMATURE")
settings = scene.puppet_link
settings.armature = armature
link = puppet_link.LINK
result = {}


def run_until_closed():
    deadline = time.monotonic() + 300
    while link.sock is not None and time.monotonic() < deadline:
        puppet_link.tick()
        time.sleep(0.002)


settings.port, settings.token = refusing, "wrong"
assert bpy.ops.puppet_link.connect() == {"FINISHED"}
run_until_closed()
result["refused_status"] = link.status

first_bone = armature.pose.bones[0].name
armature.data[puppet_link.MAP_PREFIX + first_bone] = "no_such_bone"
settings.port, settings.token = fake, ""
assert bpy.ops.puppet_link.connect() == {"FINISHED"}
deadline = time.monotonic() + 60  # the link stalls after STALL_S (1 s)
while (link.sock is not None and time.monotonic() < deadline
       and not any(line.startswith("stalled:") for line in link.health_lines())):
    puppet_link.tick()
    time.sleep(0.002)
result["health_lines"] = link.health_lines()
settings.record = True  # the fake puppet stops when it hears this
run_until_closed()
second = armature.pose.bones[1]
kept = [list(r) for r in second.matrix_basis]
for _ in range(5):
    puppet_link.tick()
result.update(status=link.status, notes=link.notes, malformed=link.malformed,
              applied=link.frames_applied, first_bone=first_bone, second_bone=second.name,
              posed=[list(r) for r in second.matrix_basis], kept=kept)
print("RESULT " + json.dumps(result))
