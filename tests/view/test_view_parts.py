"""The live view's parts without a browser: address and access rules, the frame header, page
input checks, the orbit camera, drag geometry, exact picking, handles on top of the servo
constraints, marks in a take."""

from __future__ import annotations

import math
import socket

import numpy as np
import pytest

from puppet.bus import Reading
from puppet.loop import Pipeline
from puppet.render import Camera
from puppet.rig import builtin
from puppet.net.address import AddressError, Access, bind, is_loopback, parse_address
from puppet.view.protocol import DEFAULT_PORT
from puppet.view.handles import drag_target, pixel_ray, project, surface_point
from puppet.view.orbit import OrbitCamera
from puppet.view.protocol import FLAG_DRAFT, FRAME_HEADER, FRAME_JPEG, frame_header
from puppet.view.server import check_input


def test_addresses_parse():
    def parse_address_view(text):
        return parse_address(text, option="--view", default_port=DEFAULT_PORT)

    assert parse_address_view(None) == ("127.0.0.1", DEFAULT_PORT)
    assert parse_address_view("") == ("127.0.0.1", DEFAULT_PORT)
    assert parse_address_view("9000") == ("127.0.0.1", 9000)
    assert parse_address_view("0.0.0.0:9001") == ("0.0.0.0", 9001)
    assert parse_address_view("[::1]:9002") == ("::1", 9002)
    assert parse_address_view("myhost") == ("myhost", DEFAULT_PORT)
    with pytest.raises(AddressError, match="--view 'localhost:http': port 'http' is not a number"):
        parse_address_view("localhost:http")
    with pytest.raises(AddressError, match="port 70000 is not in 0..65535"):
        parse_address_view("70000")
    # The Blender link's addresses: its own option named, its own default port.
    assert parse_address("myhost", option="--link", default_port=9100) == ("myhost", 9100)
    with pytest.raises(AddressError, match="--link '70000': port 70000"):
        parse_address("70000", option="--link", default_port=9100)


def test_loopback_needs_no_token_and_beyond_it_a_constant_time_token():
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.4")
    local = Access.for_host("127.0.0.1", 8765)
    assert local.token is None and local.token_ok(None)
    assert local.url() == "http://127.0.0.1:8765/"
    assert local.host_ok("127.0.0.1:8765") and local.host_ok("localhost:8765")
    assert not local.host_ok("evil.example:8765")  # DNS rebinding onto loopback
    wide = Access.for_host("0.0.0.0", 8765)
    assert wide.token is not None and len(wide.token) >= 20
    assert wide.url().endswith(f"?token={wide.token}")
    assert wide.token_ok(wide.token)
    assert not wide.token_ok(None) and not wide.token_ok(wide.token[:-1]) and not wide.token_ok("")
    assert Access.for_host("0.0.0.0", 8765).token != wide.token  # random per run


def test_a_taken_port_is_a_clear_error():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(AddressError) as err:
            bind("127.0.0.1", port, option="--view")
    assert str(err.value) == (f"--view: address 127.0.0.1:{port} is already in use (port {port}); "
                              f"stop the other program or pick another port, e.g. --view {port + 1}")


def test_frame_header_is_fixed_little_endian():
    data = frame_header(FLAG_DRAFT, 3, 2**32 + 5, 123456789012, 987654321098)
    assert len(data) == FRAME_HEADER.size == 24
    assert FRAME_HEADER.unpack(data) == (FRAME_JPEG, FLAG_DRAFT, 3, 5, 123456789012, 987654321098)


@pytest.mark.parametrize("message, problem", [
    (None, "not a JSON object"),
    ({"type": "launch"}, "unknown message type 'launch'"),
    ({"type": "drag", "key": 1, "x": "3", "y": 4}, "drag: field 'x' missing or invalid"),
    ({"type": "drag", "key": 1, "x": float("nan"), "y": 4}, "drag: field 'x' missing or invalid"),
    ({"type": "zoom", "factor": 1e300}, "zoom: field 'factor' missing or invalid"),
    ({"type": "marker", "name": "x" * 81}, "marker: field 'name' missing or invalid"),
    ({"type": "pick", "key": True, "seq": 1, "x": 0, "y": 0}, None),  # bool is an int in JSON terms
    ({"type": "orbit", "dx": 3.5, "dy": -2}, None),
])
def test_page_input_is_checked(message, problem):
    assert check_input(message) == problem


def test_orbit_camera_keeps_distance_and_target():
    start = Camera.framing(np.array([[-1.0, 0, -1], [1, 2, 1]]))
    orbit = OrbitCamera(start)
    assert orbit.pristine and orbit.camera() is start
    distance = np.linalg.norm(start.eye - start.target)
    orbit.orbit(math.pi / 2, 0.0)
    moved = orbit.camera()
    assert not orbit.pristine
    assert np.linalg.norm(moved.eye - moved.target) == pytest.approx(distance)
    assert np.allclose(moved.target, start.target)
    orbit.orbit(0.0, 10.0)  # pitch is clamped short of the pole
    assert orbit.pitch < math.pi / 2
    orbit.zoom(0.5)
    assert np.linalg.norm(orbit.camera().eye - orbit.camera().target) == pytest.approx(distance / 2)
    orbit.reset()
    assert orbit.pristine and np.allclose(orbit.camera().eye, start.eye)


def test_drag_ray_hits_the_point_it_projects_from():
    camera = Camera.framing(np.array([[-1.0, 0, -1], [1, 2, 1]]))
    flip = np.diag([1.0, -1.0, 1.0, 1.0])
    view_proj = flip @ camera.projection_matrix(640 / 480, 2.0) @ camera.view_matrix()
    point = np.array([0.3, 1.1, -0.2])
    (x, y), = project(view_proj, 640, 480, point[None])
    origin, direction = pixel_ray(view_proj, 640, 480, x, y)
    closest = origin + direction * ((point - origin) @ direction)
    assert np.linalg.norm(closest - point) < 1e-6
    back = camera.basis()[2]
    target = drag_target(view_proj, 640, 480, x + 50, y, point, back)
    assert abs((target - point) @ back) < 1e-9  # stays in the plane facing the camera
    assert np.allclose(project(view_proj, 640, 480, target[None])[0], [x + 50, y], atol=1e-6)


@pytest.fixture(scope="module")
def critter_pipeline():
    with Pipeline(builtin(), overlay=True) as pipeline:
        yield pipeline


def rest_reading(rig) -> Reading:
    ids = rig.servo_map.ids
    return Reading(0, ids, np.round(rig.servo_map.zero).astype(np.int32), np.ones(len(ids), bool))


def test_picking_is_exact(critter_pipeline):
    from puppet.render.passes.picking import Picker

    pipeline = critter_pipeline
    pipeline.solve(rest_reading(pipeline.rig))
    renderer = pipeline.renderer
    with Picker(renderer) as picker:
        view_proj = picker.view_proj(renderer.camera)
        hits = 0
        for x, y in [(320, 240), (300, 150), (330, 300), (280, 200)]:
            pick = picker.pick(pipeline.T, renderer.camera, x, y)
            if pick is None:
                continue
            hits += 1
            point, _ = surface_point(pipeline.model, np.asarray(pipeline.rig.F, np.int64), pipeline.T,
                                     pick.triangle, pick.bary)
            # The picked surface point projects back onto the pixel's center.
            assert np.allclose(project(view_proj, renderer.width, renderer.height, point[None])[0],
                               [x + 0.5, y + 0.5], atol=0.02)
        assert hits >= 3
        assert picker.pick(pipeline.T, renderer.camera, 3, 3) is None  # the background
        assert picker.pick(pipeline.T, renderer.camera, -1, 10) is None  # off the image


def test_a_picked_handle_holds_its_exact_surface_point(critter_pipeline):
    # The page's pick and drag through the View: the handle is the picked (triangle, barycentric)
    # point itself (not a nearby vertex), it starts where that point is, and the solve puts it
    # where it is dragged while the sensed legs stay where the servos put them.
    from puppet.view import View

    pipeline = critter_pipeline
    rig = pipeline.rig
    F = np.asarray(rig.F, np.int64)
    reading = rest_reading(rig)
    reading.ticks[:] += 200  # a pose away from rest
    pipeline.solve(reading)
    tail = rig.skeleton.names.index("tail3")
    tip = int(np.argmax(rig.W[:, tail] * np.linalg.norm(rig.V - rig.skeleton.heads[tail], axis=1)))
    diag = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0)))
    view = View("127.0.0.1:0")
    try:
        view.attach(pipeline)
        view_proj = view._picker.view_proj(view.cameras.get(0).camera())
        (x, y), = project(view_proj, view.width, view.height, pipeline.deformed()[tip][None])
        view.command("page", {"type": "pick", "key": 1, "seq": 10**6, "x": x, "y": y, "camera": 0})
        view.apply(pipeline)
        assert len(view.handle_desk.handles) == 1
        handle = view.handle_desk.handles[0]
        assert handle.corners == tuple(int(v) for v in F[handle.triangle])
        assert abs(sum(handle.bary) - 1.0) < 1e-12 and min(handle.bary) >= 0.0
        assert pipeline.pattern.positional == tuple(int(v) for v in rig.pins) + (handle.point,)
        assert set(handle.as_dict()) == {"id", "triangle", "bary"}
        # The handle starts exactly where its point is (nothing jumps) and projects onto the click.
        b = np.array(handle.bary)
        start = b @ pipeline.deformed()[list(handle.corners)]
        assert np.linalg.norm(pipeline.handle_targets[0] - start) < 1e-6 * diag
        np.testing.assert_allclose(project(view_proj, view.width, view.height, start[None])[0],
                                   [np.floor(x) + 0.5, np.floor(y) + 0.5], atol=0.05)
        view.command("page", {"type": "drag", "key": 1, "x": x + 40.0, "y": y - 30.0, "camera": 0})
        view.apply(pipeline)
        target = pipeline.handle_targets[0].astype(np.float64)
        np.testing.assert_allclose(target, handle.target, atol=1e-6 * diag)
        np.testing.assert_allclose(project(view_proj, view.width, view.height, target[None])[0],
                                   [x + 40.0, y - 30.0], atol=0.05)
        for _ in range(20):
            pipeline.solve(reading)
        point = b @ pipeline.deformed()[list(handle.corners)]
        assert np.linalg.norm(point - target) < 1e-4 * diag  # the dragged point is where it was put
        blocks = pipeline.T.reshape(-1, 4, 3)
        for q, bone in enumerate(rig.full_bones):  # sensed legs stay where the servos put them
            assert np.abs(blocks[bone] - pipeline.values.full[q]).max() < 1e-5
        view.command("page", {"type": "remove", "handle": handle.id})
        view.apply(pipeline)
        assert view.handle_desk.handles == []
    finally:
        view.close()
        pipeline.set_handles([])
    assert pipeline.pattern.positional == tuple(int(v) for v in rig.pins)


def test_marks_go_in_the_take_and_old_readers_skip_them(tmp_path):
    from puppet.take import BackgroundTakeWriter, TakeReader, TakeWriter
    from puppet.take.markers import read_markers

    ids = np.array([1, 2])
    path = tmp_path / "marked.mcap"
    writer = BackgroundTakeWriter(TakeWriter(path, ids=ids, models={1: "XL330-M288", 2: "XL330-M288"},
                                             rig_map_text="", calibration_text="", rig_name="two"))
    for i in range(20):
        writer.write(Reading(1000 + i, ids, np.array([i, -i], np.int32), np.ones(2, bool)))
        if i in (5, 12):
            writer.mark(1000 + i, f"mark {i}")
    writer.close()
    assert read_markers(path) == [(1005, "mark 5"), (1012, "mark 12")]
    reader = TakeReader(path)
    assert len(reader) == 20 and not reader.truncated
    assert reader.arrays()[1][:, 0].tolist() == list(range(20))


def test_nothing_is_rendered_or_encoded_without_a_viewer():
    from puppet.demo import run_demo
    from puppet.view import View

    view = View("127.0.0.1:0")
    try:
        summary, _ = run_demo(seconds=1.0, sinks_for=lambda _p: [], view=view, width=160, height=120)
        stats = view.stats()
    finally:
        view.close()
    assert summary.frames > 5
    assert (stats["frames_rendered"], stats["frames_reused"], stats["frames_sent"]) == (0, 0, 0)
    assert view.frames.encoder.encoded == 0


def test_camera_moves_are_merged_into_one_change_per_frame(critter_pipeline):
    from puppet.view import View

    view = View("127.0.0.1:0")
    try:
        view.attach(critter_pipeline)
        camera = view.cameras.get(0)
        version = camera.version
        for dx in (5.0, 7.0, -2.0):
            view.command("page", {"type": "orbit", "dx": dx, "dy": 1.0, "camera": 0})
        view.command("page", {"type": "zoom", "factor": 0.5, "camera": 0})
        yaw = camera.yaw
        view.apply(critter_pipeline)
        assert camera.version == version + 2  # one orbit (three events merged) and one zoom
        assert camera.yaw == pytest.approx((yaw - 10.0 * 0.01) % (2 * math.pi))
        view.apply(critter_pipeline)  # nothing new: nothing changes
        assert camera.version == version + 2
    finally:
        view.close()


def test_take_source_shows_the_take_by_its_one_rule():
    """``play --view``'s source asks the take's Playback for the reading at its play position:
    interpolated ticks, the gap cut (its duration and seeks are on the cut time line)."""
    from puppet.take import Playback
    from puppet.view import TakeSource

    t = np.array([0, 100_000_000, 5_100_000_000], np.int64)  # a 5 s gap, cut to 1 s
    ticks = np.array([[0, 4000], [100, 4090], [300, 10]], np.int32)
    frames = Playback(t, ticks, np.ones((3, 2), bool), np.array([1, 2]), fps=30)
    source = TakeSource(frames, rate_hz=1000.0, markers=[(frames.play_s(5_100_000_000), "end")])
    assert source.duration_s == pytest.approx(1.1)
    assert source.state()["markers"] == [{"t_s": 1.1, "name": "end"}]
    source.pause()
    for position in (0.05, 0.6, 1.1):
        source.seek(position)
        got = source.latest(timeout=1.0)
        assert got is not None and source.position_s == position
        assert got.ticks.tolist() == frames.at(position).ticks.tolist()
    source.seek(0.6)  # half way through the cut gap: half way from 100 to 300, 4090 to 10 (wrap)
    assert source.latest(timeout=1.0).ticks.tolist() == [200, 4096 + 2]


def test_page_messages_parse_bounded_and_notices_merge_per_kind():
    from puppet.net.guard import RateLimit, Throttle, parse_message

    assert parse_message("[" * 2000 + "]" * 2000) is None  # no RecursionError: refused unparsed
    assert parse_message('{"type": "orbit", "dx": 1, "dy": 2}') == {"type": "orbit", "dx": 1, "dy": 2}
    assert parse_message("[1, 2]") is None
    limit = RateLimit(rate_per_s=10, burst=3)
    assert [limit.take(0.0) for _ in range(4)] == [True, True, True, False]
    assert limit.take(0.1) is True and limit.refused == 1  # 0.1 s at 10 per second: one more
    notes = Throttle(every_s=2.0)
    assert notes.offer("bad", "bad 1", 0.0) == "bad 1"
    assert notes.offer("bad", "bad 2", 0.5) is None
    assert notes.offer("bad", "bad 3", 1.0) is None
    assert notes.offer("other", "other 1", 1.0) == "other 1"
    assert notes.due(1.5) == []
    assert notes.due(2.0) == ["bad 3 (and 1 more like it)"]
    assert notes.due(5.0) == []


def test_the_stall_before_a_viewer_is_dropped_is_the_default_unless_the_environment_says(
        monkeypatch):
    import pytest

    from puppet.view.errors import ViewError
    from puppet.view.protocol import STALL_DROP_ENV, STALL_DROP_S, stall_drop_s

    monkeypatch.delenv(STALL_DROP_ENV, raising=False)
    assert stall_drop_s() == STALL_DROP_S == 10.0
    monkeypatch.setenv(STALL_DROP_ENV, "2.5")
    assert stall_drop_s() == 2.5
    for bad in ("soon", "0", "-1", "inf", "nan"):
        monkeypatch.setenv(STALL_DROP_ENV, bad)
        with pytest.raises(ViewError, match=f"^{STALL_DROP_ENV}='{bad}': must be a number "):
            stall_drop_s()
