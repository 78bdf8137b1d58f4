"""The shot format (a take with a keys channel) and its in-betweens: keys read back exactly,
Playback plays a shot at its key frames (frame count = last key frame), joint rotations are
the keys' on key frames and slerped / splined / held between, a damaged key loses only itself,
edits refuse reordering naming both keys, and FAST in-betweens keep energy and volume better
than a per-vertex blend of the key meshes."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from puppet.keys import insert_key, read_shot, remove_key, replace_key, retime, write_shot
from puppet.keys.example import critter_keys
from puppet.keys.measure import compare_inbetweens
from puppet.rig import builtin
from puppet.take import Playback, TakeError, TakeReader
from puppet.take.keys import KEY_TOPIC, Key, Keys


@pytest.fixture(scope="module")
def critter():
    return builtin()


def header_of(rig):
    from puppet.rig.calibration import Calibration

    return {"ids": [int(i) for i in rig.servo_map.ids], "models": dict(rig.servo_map.models),
            "rig_map_text": "", "calibration_text":
                Calibration.capture(rig.servo_map.ids, rig.servo_map.zero).to_record(),
            "rig_name": rig.name}


def fk_rotations(rig, ticks):
    return rig.skeleton.joint_rotations(rig.servo_map.angles(np.asarray(ticks, np.int32)))


def test_a_shot_reads_back_its_keys_exactly(tmp_path, critter):
    keys = critter_keys(critter, step=12, fps=24)
    keys.keys[2].interpolation = "step"
    shot = tmp_path / "shot.mcap"
    write_shot(shot, header_of(critter), keys)
    header, back, reader = read_shot(shot)
    assert back.fps == 24.0 and back.skipped == []
    assert [k.frame for k in back.keys] == [1, 13, 25, 37]
    assert [k.interpolation for k in back.keys] == ["linear", "linear", "step", "linear"]
    for a, b in zip(keys.keys, back.keys):
        assert a.ticks.tolist() == b.ticks.tolist() and b.ok.all()
    # the readings channel holds the same keys at their times: a take reader sees four readings
    t, ticks, ok = reader.arrays()
    assert (t - t[0]).tolist() == [0, 500_000_000, 1_000_000_000, 1_500_000_000]
    assert ticks.tolist() == [k.ticks.tolist() for k in keys.keys]
    assert KEY_TOPIC in reader.topics and reader.recovery is None


def test_playback_of_a_shot_hits_every_key_and_interpolates_rotations(tmp_path, critter):
    keys = critter_keys(critter, step=40, fps=24)  # 40 frames apart: 1.67 s, more than MAX_GAP_S
    keys.keys[1].interpolation = "step"
    keys.keys[2].interpolation = "smooth"
    shot = tmp_path / "shot.mcap"
    write_shot(shot, header_of(critter), keys)
    frames = Playback.of_take(TakeReader(shot), critter.servo_map.ids, fps=24, rig=critter)
    assert len(frames) == 121 and frames.cuts == []  # the last key's frame; no gap cut
    got = list(frames)
    key_rot = [fk_rotations(critter, k.ticks) for k in keys.keys]
    for k, f in zip(keys.keys, (0, 40, 80, 120)):
        assert got[f].ticks.tolist() == k.ticks.tolist()  # key poses exact at their frames
        np.testing.assert_allclose(got[f].rotations, key_rot[keys.keys.index(k)], atol=1e-12)
    # linear: the slerp halfway between key 0 and key 1, per joint
    for bone in range(critter.skeleton.bone_count):
        r0, r1 = Rotation.from_matrix(key_rot[0][bone]), Rotation.from_matrix(key_rot[1][bone])
        half = r0 * Rotation.from_rotvec((r0.inv() * r1).as_rotvec() * 0.5)
        np.testing.assert_allclose(got[20].rotations[bone], half.as_matrix(), atol=1e-9)
    # step: key 1 held until key 2
    for f in range(40, 80):
        np.testing.assert_allclose(got[f].rotations, key_rot[1], atol=1e-12)
        assert got[f].ticks.tolist() == keys.keys[1].ticks.tolist()
    # smooth: a spline through the keys, not the slerp (it differs mid-segment) but continuous
    slerp_mid = [Rotation.from_matrix(key_rot[2][b]) * Rotation.from_rotvec(
        (Rotation.from_matrix(key_rot[2][b]).inv() * Rotation.from_matrix(key_rot[3][b])).as_rotvec()
        * 0.5) for b in range(critter.skeleton.bone_count)]
    off = max(np.abs(got[100].rotations[b] - slerp_mid[b].as_matrix()).max()
              for b in range(critter.skeleton.bone_count))
    assert off > 1e-3
    steps = [np.abs(got[f + 1].rotations - got[f].rotations).max() for f in range(80, 120)]
    assert max(steps) < 0.2
    # seeking (the view) gives the frame's rotations too
    np.testing.assert_allclose(frames.at(20 / 24).rotations, got[20].rotations, atol=1e-9)


def test_fast_fills_the_free_bones_of_the_inbetweens(tmp_path, critter):
    """Every in-between solved by FAST from the rotations: the free bones (spine, ears, tail)
    move in every in-between, and the rig's ARAP energy and the volume change are lower than
    the per-vertex blend of the key meshes (the comparison bench/keys.py prints)."""
    keys = critter_keys(critter, step=12, fps=24)
    shot = tmp_path / "shot.mcap"
    write_shot(shot, header_of(critter), keys)
    frames = Playback.of_take(TakeReader(shot), critter.servo_map.ids, fps=24, rig=critter)
    report = compare_inbetweens(critter, frames, [k.frame - 1 for k in keys.keys])
    assert report["inbetweens"] == 33
    assert report["free_bones_moving"] == 1.0
    assert report["fast"]["energy_mean"] < report["blend"]["energy_mean"]
    assert report["fast"]["volume_change_mean"] < report["blend"]["volume_change_mean"]


def test_a_damaged_key_loses_only_itself(tmp_path, critter):
    keys = critter_keys(critter)
    shot = tmp_path / "shot.mcap"
    write_shot(shot, header_of(critter), keys)
    data = bytearray(shot.read_bytes())
    marker = json.dumps({"index": 2}).encode()[1:-1]  # '"index": 2'
    at = data.find(marker)
    assert at > 0
    data[at + len(marker) - 1] = ord("7")  # key 2 now claims index 7: its crc no longer fits
    shot.write_bytes(bytes(data))
    reader = TakeReader(shot)
    back = reader.keys()
    assert [k.frame for k in back.keys] == [1, 13, 37]
    assert len(back.skipped) == 1 and "key message 2" in back.skipped[0]
    assert "key message 2" in reader.recovery  # said wherever the take's recovery is printed
    frames = Playback.of_take(reader, critter.servo_map.ids, fps=24, rig=critter)
    assert len(frames) == 37


def test_edits_keep_keys_in_order_and_name_both_keys(critter):
    keys = critter_keys(critter, step=12)
    moved = retime(keys, {2: 40, 3: 52})
    assert [k.frame for k in moved.keys] == [1, 13, 40, 52]
    with pytest.raises(TakeError) as err:
        retime(keys, {2: 13})
    assert "key 2 (frame 13) would land on the same frame as key 1 (frame 13)" in str(err.value)
    with pytest.raises(TakeError) as err:
        retime(keys, {1: 30})
    assert "key 2 (frame 25) would land before key 1 (frame 30)" in str(err.value)
    fewer = remove_key(keys, 1)
    assert [k.frame for k in fewer.keys] == [1, 25, 37]
    assert [k.id for k in fewer.keys] == [0, 2, 3]  # ids are stable: the others keep theirs
    new = Key(19, keys.keys[0].ticks + 5, keys.keys[0].ok)
    more = insert_key(keys, new)
    assert [k.frame for k in more.keys] == [1, 13, 19, 25, 37]
    assert [k.id for k in more.keys] == [0, 1, 4, 2, 3]  # a new key takes the next unused id
    with pytest.raises(TakeError) as err:
        insert_key(keys, Key(25, new.ticks, new.ok))
    assert "key 4 (frame 25) would land on the same frame as key 2 (frame 25)" in str(err.value)
    again = replace_key(keys, 3, new)
    assert again.keys[3].frame == 37 and again.keys[3].ticks.tolist() == new.ticks.tolist()
    with pytest.raises(TakeError) as err:
        remove_key(keys, 9)
    assert "no key 9: the shot's keys are 0, 1, 2, 3" in str(err.value)


def test_a_take_without_keys_is_not_a_shot(tmp_path, critter):
    from puppet.reading import Reading
    from puppet.take import TakeWriter

    path = tmp_path / "take.mcap"
    h = header_of(critter)
    with TakeWriter(path, **h) as w:
        w.write(Reading(0, np.asarray(h["ids"]), np.full(15, 2048, np.int32), np.ones(15, bool)))
    assert TakeReader(path).keys() is None
    with pytest.raises(TakeError) as err:
        read_shot(path)
    assert "not a shot" in str(err.value) and "take.mcap" in str(err.value)


def test_frames_before_the_first_key_hold_it(tmp_path, critter):
    keys = retime(critter_keys(critter, step=12), {0: 5})
    shot = tmp_path / "shot.mcap"
    write_shot(shot, header_of(critter), keys)
    frames = Playback.of_take(TakeReader(shot), critter.servo_map.ids, fps=24, rig=critter)
    assert len(frames) == 37  # frame 1 .. the last key's frame
    first = fk_rotations(critter, keys.keys[0].ticks)
    for f in range(5):
        np.testing.assert_allclose(frames.reading(f).rotations, first, atol=1e-12)
        assert frames.reading(f).ticks.tolist() == keys.keys[0].ticks.tolist()
    assert frames.reading(5).ticks.tolist() != keys.keys[0].ticks.tolist()


def test_long_shots_are_interpolated_in_bounded_blocks(tmp_path, critter):
    """Frames past ROTATION_BLOCK, in any order, give the rotations of one whole evaluation."""
    from puppet.take.inbetween import Inbetweens
    from puppet.take.playback import ROTATION_BLOCK

    keys = critter_keys(critter, step=100, fps=24)
    keys.keys[1].interpolation = "smooth"
    shot = tmp_path / "shot.mcap"
    write_shot(shot, header_of(critter), keys)
    frames = Playback.of_take(TakeReader(shot), critter.servo_map.ids, fps=24, rig=critter)
    assert len(frames) == 301 > ROTATION_BLOCK
    whole = Inbetweens(keys.times_ns(), [fk_rotations(critter, k.ticks) for k in keys.keys],
                       [k.interpolation for k in keys.keys]).at(frames.frame_times_ns())
    for f in (300, 0, 255, 256, 150, 299):
        np.testing.assert_allclose(frames.reading(f).rotations, whole[f], atol=1e-12)


def test_a_key_is_the_median_of_the_good_readings_in_the_hold_window():
    from puppet.keys.capture import HOLD_NS, KeyRefused, held_pose
    from puppet.reading import Reading

    ids = np.array([1, 2, 3])
    press = 10_000_000_000

    def reading(dt_ns, ticks, ok=(True, True, True)):
        return Reading(press + dt_ns, ids, np.array(ticks, np.int32), np.array(ok))

    readings = [reading(-50_000_000, [0, 0, 0]),                    # before the press: not used
                reading(0, [100, 200, 300]), reading(50_000_000, [102, 199, 301]),
                reading(100_000_000, [101, 5000, 299], (True, False, True)),  # one late reply
                reading(150_000_000, [999, 201, 300]),               # a jolt: the median drops it
                reading(HOLD_NS, [101, 200, 300]),
                reading(HOLD_NS + 1, [7, 7, 7])]                     # after the window
    ticks, ok, used = held_pose(readings, press, ids)
    assert ticks.tolist() == [101, 200, 300] and ok.all() and used == 5
    silent = [reading(t, [1, 2, 3], (True, True, False)) for t in (0, 60_000_000, 120_000_000)]
    with pytest.raises(KeyRefused) as err:
        held_pose(silent, press, ids)
    assert "servo(s) [3] flagged" in str(err.value)
    late = [Reading(press + t, ids, np.array([1, 2, 3], np.int32), np.array([True, True, False]),
                    late=np.array([False, False, True])) for t in (0, 60_000_000, 120_000_000)]
    with pytest.raises(KeyRefused) as err:  # late replies on a busy host: not a fault
        held_pose(late, press, ids)
    assert "servo(s) [3]: their replies came late" in str(err.value)
    assert "flagged" not in str(err.value)
    with pytest.raises(KeyRefused) as err:
        held_pose(readings[:1], press, ids)
    assert "no reading in the hold window" in str(err.value)


def test_the_view_shows_a_shot_with_its_rotations(tmp_path, critter):
    """play --view's source (TakeSource over the shot's Playback) hands on the joint rotations
    of the position shown: paused at a seek, the in-between's rotations."""
    from puppet.view import TakeSource

    keys = critter_keys(critter, step=12, fps=24)
    shot = tmp_path / "shot.mcap"
    write_shot(shot, header_of(critter), keys)
    frames = Playback.of_take(TakeReader(shot), critter.servo_map.ids, fps=24, rig=critter)
    source = TakeSource(frames)
    source.pause()
    source.seek(18 / 24)
    shown = source.latest(timeout=5.0)
    np.testing.assert_allclose(shown.rotations, frames.reading(18).rotations, atol=1e-9)
