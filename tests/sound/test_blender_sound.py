"""The sound in Blender from an exported file (docs/blender.md, "The take's sound"): the glTF's
scene extras name the sound and the frame its sample 0 plays on; the sound strip lands there."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys

import numpy as np
import pytest
import soundfile as sf

from puppet.export import Outputs, export_take
from puppet.reading import Reading
from puppet.sound import load_sound, sound_ref
from puppet.take import TakeReader, TakeWriter
from puppet.timecode import StartTimecode

# What docs/blender.md says to run in Blender's Python console after importing the .glb.
PLACE_STRIP = """
import bpy, json, sys
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.fps, scene.render.fps_base = 25, 1.0
bpy.ops.import_scene.gltf(filepath=sys.argv[1])
scene = bpy.context.scene
editor = scene.sequence_editor_create()
strips = editor.strips if hasattr(editor, "strips") else editor.sequences  # Blender 5: strips
strip = strips.new_sound("puppet sound", scene["puppet_sound_path"], 1,
                         round(scene["puppet_sound_frame"]))
print("RESULT " + json.dumps({"frame_start": strip.frame_start, "path": strip.sound.filepath,
                              "fps": scene.render.fps, "timecode": scene["puppet_timecode_start"],
                              "action_frames": list(bpy.data.actions[0].frame_range)}))
"""


def test_the_sound_strip_lands_where_the_take_starts(tmp_path, clicks):
    if importlib.util.find_spec("bpy") is None:
        pytest.skip("bpy (Blender as a Python module) is not installed: pip install '.[test]'")
    from puppet.rig import builtin

    rig = builtin()
    sound_path = tmp_path / "line.wav"
    sf.write(sound_path, clicks.click_track(48000, seconds=2.0), 48000)
    ref = sound_ref(load_sound(sound_path), offset_s=0.4)  # 10 frames at 25 fps before time 0
    take = tmp_path / "take.mcap"
    k = len(rig.servo_map)
    with TakeWriter(take, ids=[int(i) for i in rig.servo_map.ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name, sound=ref,
                    timecode=StartTimecode("00:00:10:00", "25")) as writer:
        for i in range(13):
            ticks = (rig.servo_map.zero + 200 * np.sin(0.3 * i + np.arange(k))).astype(np.int32)
            writer.write(Reading(i * 40_000_000, rig.servo_map.ids, ticks, np.ones(k, bool)))
    glb = tmp_path / "anim.glb"
    export_take(rig, TakeReader(take), Outputs(gltf=glb), fps=25.0)
    done = subprocess.run([sys.executable, "-c", PLACE_STRIP, str(glb)], capture_output=True,
                          text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    shown = json.loads(next(x for x in done.stdout.splitlines()
                            if x.startswith("RESULT "))[len("RESULT "):])
    # frame 1 is the take's time 0; the sound's sample 0 is 0.4 s (10 frames) before it
    assert shown["frame_start"] == 1 - 10
    assert shown["path"] == str(sound_path.absolute())
    assert shown["timecode"] == "00:00:10:00"
    assert shown["action_frames"][0] == pytest.approx(1.0)
