"""PNG and MP4 sinks: files written, read back with the right count, size and content."""

import imageio.v3 as iio
import imageio_ffmpeg
import numpy as np
import pytest

from puppet.render import PngSink, Renderer, SinkError, VideoSink


def bending_frames(gl_context, bar, helpers, count: int, width: int, height: int) -> list[np.ndarray]:
    V, F, W = bar
    frames = []
    with Renderer(V, F, W, width=width, height=height, context=gl_context) as renderer:
        for k in range(count):
            bend = helpers.rotation_about(helpers.rotation_z(np.pi / 2 * k / max(count - 1, 1)), [1, 0, 0])
            frames.append(renderer.draw(helpers.handle_T([helpers.IDENTITY, bend])).copy())
    return frames


def test_mp4_has_the_written_frame_count_size_and_content(gl_context, bar, helpers, tmp_path):
    frames = bending_frames(gl_context, bar, helpers, count=12, width=160, height=120)
    path = tmp_path / "take.mp4"
    with VideoSink(path, fps=24) as video:
        for frame in frames:
            video.write(frame)
    assert video.count == 12
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = reader.__next__()
    decoded = [np.frombuffer(raw, np.uint8).reshape(120, 160, 3) for raw in reader]
    assert meta["size"] == (160, 120)
    assert meta["fps"] == pytest.approx(24)
    assert len(decoded) == 12
    for original, back in zip(frames, decoded):  # lossy codec: compare with a tolerance
        assert np.abs(original.astype(float) - back.astype(float)).mean() < 4.0
    # The frames differ from each other (the bone bends), and the video kept that order.
    assert np.abs(decoded[0].astype(float) - decoded[-1].astype(float)).mean() > 2.0


def test_png_sink_writes_numbered_frames(gl_context, bar, helpers, tmp_path):
    frames = bending_frames(gl_context, bar, helpers, count=3, width=64, height=48)
    with PngSink(tmp_path / "frames") as sink:
        paths = [sink.write(frame) for frame in frames]
    assert [p.name for p in paths] == ["frame_000000.png", "frame_000001.png", "frame_000002.png"]
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == [p.name for p in paths]
    for frame, path in zip(frames, paths):
        back = iio.imread(path)
        assert back.shape == (48, 64, 3)
        assert np.abs(back.astype(int) - frame.astype(int)).max() <= 1  # PNG is lossless


def test_sinks_refuse_bad_frames_and_sizes(tmp_path):
    with pytest.raises(SinkError, match="must be even"):
        VideoSink(tmp_path / "odd.mp4", fps=30, size=(161, 120))
    with pytest.raises(SinkError, match="fps must be positive"):
        VideoSink(tmp_path / "still.mp4", fps=0)
    with pytest.raises(SinkError, match="does not exist"):
        VideoSink(tmp_path / "missing" / "take.mp4", fps=30)
    with VideoSink(tmp_path / "take.mp4", fps=30) as video:
        video.write(np.zeros((48, 64, 3), np.uint8))
        with pytest.raises(SinkError, match="frame is 32x48, the sink was opened at 64x48"):
            video.write(np.zeros((48, 32, 3), np.uint8))
    with pytest.raises(SinkError, match="closed"):
        video.write(np.zeros((48, 64, 3), np.uint8))
    with PngSink(tmp_path / "frames") as sink:
        with pytest.raises(SinkError, match=r"expected a \(height, width, 3\) uint8 RGB image, got float64"):
            sink.write(np.zeros((48, 64, 3)))


def test_video_appears_only_when_finished_and_a_dead_encoder_is_an_error(tmp_path):
    frame = np.full((48, 64, 3), 90, np.uint8)
    path = tmp_path / "take.mp4"
    video = VideoSink(path, fps=30)
    video.write(frame)
    assert not path.exists()  # written to a temporary sibling until close
    video.close()
    assert imageio_ffmpeg.count_frames_and_secs(str(path))[0] == 1

    broken = tmp_path / "broken.mp4"
    video = VideoSink(broken, fps=30)
    video.write(frame)
    video._process.kill()  # the encoder dies (killed, disk full) while frames still come
    video._process.wait()
    with pytest.raises(SinkError, match=r"broken\.mp4: the video encoder"):
        for _ in range(100):  # the failure surfaces on a following write at the latest
            video.write(frame)
    video.close()  # reported once; close cleans up without raising again
    assert not broken.exists()
    assert [p.name for p in tmp_path.iterdir() if "partial" in p.name] == []


@pytest.mark.parametrize("encoder", ["thread", "inline"])
def test_both_encoder_modes_write_the_same_frames(tmp_path, encoder):
    rng = np.random.default_rng(1)
    frames = [np.repeat(np.repeat(rng.integers(0, 255, (6, 8, 3), np.uint8), 8, 0), 8, 1) for _ in range(5)]
    path = tmp_path / f"{encoder}.mp4"
    with VideoSink(path, fps=10, encoder=encoder) as video:
        for f in frames:
            video.write(f)
    decoded = [np.frombuffer(raw, np.uint8).reshape(48, 64, 3) for raw in list(imageio_ffmpeg.read_frames(str(path)))[1:]]
    assert len(decoded) == 5
    for original, back in zip(frames, decoded):
        assert np.abs(original.astype(float) - back.astype(float)).mean() < 6.0


def _ffmpeg_in_session(session: int) -> int | None:
    """The pid of the ffmpeg process in session ``session`` (the encoder's), or None yet."""
    from pathlib import Path

    for entry in Path("/proc").iterdir():
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            command = (entry / "cmdline").read_bytes().split(b"\0")[0]
        except (OSError, IndexError):
            continue
        if int(fields[3]) == session and b"ffmpeg" in command:
            return int(entry.name)
    return None


def test_the_encoder_yields_the_cpu_to_the_loop(tmp_path, wait_until):
    """ffmpeg runs niced (the live loop's frames come first), or as this process with nice=0."""
    import os

    own = os.getpriority(os.PRIO_PROCESS, 0)
    for nice, expected in ((10, min(19, own + 10)), (0, own)):
        with VideoSink(tmp_path / f"nice{nice}.mp4", fps=24, size=(32, 32), nice=nice) as video:
            video.write(np.zeros((32, 32, 3), np.uint8))
            session = video._process.pid  # `nice` sets its niceness, then its shell runs ffmpeg
            pid = wait_until(lambda: _ffmpeg_in_session(session), what="ffmpeg in its session")
            wait_until(lambda: os.getpriority(os.PRIO_PROCESS, pid) == expected,
                       what=f"ffmpeg at niceness {expected}")
        assert (tmp_path / f"nice{nice}.mp4").exists()
