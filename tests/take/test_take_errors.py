"""Bad takes and bad use get typed errors that name the file and what is wrong."""

import numpy as np
import pytest
from mcap.writer import CompressionType, Writer

from puppet.reading import Reading
from puppet.take import TakeError, TakeReader, TakeRigMismatch, TakeWriter, check_take_rig
from puppet.take import format as fmt


def open_error(path) -> str:
    with pytest.raises(TakeError) as e:
        TakeReader(path)
    assert e.value.path == str(path)
    assert str(path) in str(e.value)
    return e.value.reason


def test_missing_file(tmp_path):
    assert "no such take file" in open_error(tmp_path / "nope.mcap")


def test_directory(tmp_path):
    assert "directory" in open_error(tmp_path)


def test_a_fifo_or_a_device_is_refused_unopened(tmp_path):
    import os

    fifo = tmp_path / "fifo.mcap"
    os.mkfifo(fifo)  # opened, it would block until a writer came: for ever
    assert open_error(fifo) == "is a FIFO (named pipe), not a take file (only regular files are read)"
    assert open_error("/dev/zero").startswith("is a character device, not a take file")


def test_empty_file(tmp_path):
    p = tmp_path / "empty.mcap"
    p.write_bytes(b"")
    assert "empty file" in open_error(p)


def test_not_an_mcap(tmp_path):
    p = tmp_path / "notes.mcap"
    p.write_text("[rig]\nname = 'this is a rig map, not a take'\n")
    assert "not an MCAP file" in open_error(p)


def write_foreign_mcap(path, *, puppet_info=None, schema_name="other/Msg", encoding="cdr"):
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.NONE)
        w.start(profile="", library="some-robot-logger")
        if puppet_info is not None:
            w.add_metadata(fmt.TAKE_METADATA, puppet_info)
            w.add_metadata(fmt.RIG_MAP_METADATA, {"text": ""})
            w.add_metadata(fmt.CALIBRATION_METADATA, {"text": ""})
        sid = w.register_schema(schema_name, "ros2msg", b"int32 x\n")
        ch = w.register_channel(fmt.TOPIC if puppet_info else "/imu", encoding, sid)
        w.add_message(ch, log_time=1, data=b"\x00\x01\x00\x00\x07\x00\x00\x00", publish_time=1)
        w.finish()


GOOD_INFO = {"format_version": "1", "rig_name": "r", "ids": "[1]", "models": '{"1": "XL430"}',
             "servo_count": "1"}


def test_mcap_from_another_tool(tmp_path):
    p = tmp_path / "robot.mcap"
    write_foreign_mcap(p)
    reason = open_error(p)
    assert "not a puppet take" in reason and "some-robot-logger" in reason


def test_wrong_schema(tmp_path):
    p = tmp_path / "schema.mcap"
    write_foreign_mcap(p, puppet_info=GOOD_INFO)
    reason = open_error(p)
    assert "other/Msg" in reason and fmt.SCHEMA_NAME in reason


def test_newer_format_version(tmp_path):
    p = tmp_path / "future.mcap"
    write_foreign_mcap(p, puppet_info={**GOOD_INFO, "format_version": "4"})
    reason = open_error(p)
    assert "version 4 (newer)" in reason and "reads versions 1, 2 and 3" in reason


def test_malformed_take_metadata(tmp_path):
    p = tmp_path / "meta.mcap"
    write_foreign_mcap(p, puppet_info={**GOOD_INFO, "ids": "[1, 2]"})
    assert "2 ids but servo_count 1" in open_error(p)
    write_foreign_mcap(p, puppet_info={k: v for k, v in GOOD_INFO.items() if k != "models"})
    assert "lacks field 'models'" in open_error(p)


def test_take_from_another_rig(take_path, kit):
    r = TakeReader(take_path)
    r.check_rig(kit.IDS, kit.MODELS)  # its own rig
    r.check_rig(kit.IDS[::-1].copy())  # order does not matter
    with pytest.raises(TakeRigMismatch) as e:
        r.check_rig([3, 7, 11, 99], rig_name="dragon")
    msg = str(e.value)
    assert "take from another rig" in msg and str(take_path) in msg
    assert "servos [99] of the rig are not in the take" in msg
    assert "servos [12] of the take are not in the rig" in msg
    assert "'dragon'" in msg and "'bench'" in msg
    assert e.value.take_ids == [3, 7, 11, 12] and e.value.rig_ids == [3, 7, 11, 99]
    with pytest.raises(TakeRigMismatch) as e:
        check_take_rig(r.metadata, ids=kit.IDS, models={**kit.MODELS, 11: "XL430-W250"})
    assert "servo 11 is a XM430-W350 in the take but a XL430-W250 in the rig" in str(e.value)
    with pytest.raises(TakeRigMismatch):
        next(r.readings(ids=[3, 7, 11]))


def test_writer_refuses_bad_setup(tmp_path, kit):
    p = tmp_path / "w.mcap"
    common = dict(rig_map_text="", calibration_text="", rig_name="r")
    with pytest.raises(TakeError, match="duplicate servo ids"):
        TakeWriter(p, ids=[1, 1], models={1: "a"}, **common)
    with pytest.raises(TakeError, match=r"models name servos \[1\], ids are \[1, 2\]"):
        TakeWriter(p, ids=[1, 2], models={1: "a"}, **common)
    with pytest.raises(TakeError, match="non-empty 1-D array of integers"):
        TakeWriter(p, ids=[], models={}, **common)
    assert not p.exists()
    kit.open_writer(p).close()
    before = p.read_bytes()
    with pytest.raises(TakeError, match="file exists"):
        kit.open_writer(p)
    assert p.read_bytes() == before  # nothing lost
    kit.open_writer(p, overwrite=True).close()
    with pytest.raises(TakeError, match="cannot create take file"):
        kit.open_writer(tmp_path / "no" / "such" / "dir.mcap")


def test_writer_refuses_bad_readings(tmp_path, kit):
    p = tmp_path / "w.mcap"
    w = kit.open_writer(p)
    w.write(kit.reading_at(0, 5_000))
    bad_ids = Reading(t_ns=6_000, ids=np.array([3, 7, 11, 13]), ticks=np.zeros(4, np.int32),
                      ok=np.ones(4, bool))
    with pytest.raises(TakeError, match=r"reading has servo ids \[3, 7, 11, 13\]"):
        w.write(bad_ids)
    with pytest.raises(TakeError, match="earlier than the previous 5000"):
        w.write(kit.reading_at(1, 4_000))
    w.write(kit.reading_at(1, 5_000))  # equal timestamps are allowed
    w.close()
    w.close()
    with pytest.raises(TakeError, match="after close"):
        w.write(kit.reading_at(2, 7_000))
    r = TakeReader(p)
    assert len(r) == 2 and r.truncated is False
    assert r.metadata.models == kit.MODELS
