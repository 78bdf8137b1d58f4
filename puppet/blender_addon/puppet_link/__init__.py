"""puppet link: a Blender add-on that poses an armature (and shows the exact mesh) live from
``puppet ... --link`` and records into the timeline. Nothing beyond Blender's own Python (and the
numpy it ships); the protocol is puppet's ``wire`` module, shipped next to this file.

In Blender: View3D > Sidebar > Puppet. Connect (host, port, token beyond loopback), pick the
armature imported from the rig's .glb (and its mesh), check the bone mapping, tick Record to key
the bones at scene frame = start frame + take time x scene fps. Connect keeps trying until
Disconnect: a puppet that stops and starts again is picked up by itself (the panel says so).

Every tick (``tick()``, on a ``bpy.app.timers`` callback; never blocking) reads what arrived,
keys every frame being recorded, applies the newest frame and acks it. A frame's joint keys
are glTF node translations and rotations (Y up) relative to each joint's parent node, as the
exported .glb holds them; the hello's ``above`` places them in the armature node's space (the
node Blender's glTF importer makes the armature object, however it is moved, turned or scaled):
G = G_parent · above · key. The bones get the same rigid motion in Blender's Z-up armature
space, as the importer plays the file's keys: matrix_basis = B⁻¹ Z Δp⁻¹ Δj Z⁻¹ B, with B the
bone's rest matrix, Z the glTF-to-Blender axes, Δ = G·G_rest⁻¹ a joint's motion from its rest
and p the nearest driven bone above.

The exact mesh never touches the user's mesh: it is shown on a copy the add-on owns (an object
"<mesh> (puppet)" with a copy of the mesh data, no modifiers, no shape keys, placed at the
glTF-to-Blender axes so puppet's model-frame vertices go in as they come: one bulk copy into its
position attribute) while the user's mesh object is hidden; unticking "Exact mesh" or
Disconnect deletes the copy and restores the object's visibility, so the user's vertices,
modifiers and shape keys are as imported. (A shape key or a Mesh Cache file would write into
the user's data or need its Armature modifier switched off; an evaluated copy would be re-made
by Blender every frame.)

Recording: a frame puppet flags recording (``puppet live --record``), or any frame while Record
is ticked, is keyed: puppet sends each such frame, none skipped, and they queue while Blender is
busy. Keys go on integer scene frames: a frame at take time t sits at start + t × scene fps;
each integer frame between two streamed frames gets their linear blend (the frame itself where
they coincide, as ``puppet play`` sends the export's frames), so the action has one key per
scene frame, where ``puppet export`` of the take puts its frame. Keys are LINEAR, set on the
keyframe points themselves. Each recording is its own action, named after the take.
"""

from __future__ import annotations

import math
import select
import socket
import struct
import time
from collections import deque

import bpy
import numpy as np  # Blender ships numpy
from mathutils import Matrix, Quaternion, Vector

from . import names, wire

bl_info = {
    "name": "puppet link",
    "author": "puppet",
    "version": (2, 0, 0),
    "blender": (4, 4, 0),
    "location": "View3D > Sidebar > Puppet",
    "description": "Pose an armature live from a puppet (puppet live/demo/play --link), record it",
    "category": "Animation",
}

SOUND_STRIP = "puppet sound"  # the take's sound on the timeline (as docs/blender.md names it)
MAP_PREFIX = "puppet_map:"  # armature data custom property: joint -> bone, where names differ
TICK_S = 0.004
RETRY_S = 1.0  # seconds between attempts to reach puppet
CONNECT_S = 5.0  # an attempt that has not connected by then is given up
STALL_S = 1.0  # connected and no frame for this long: the panel says the link stalled
READ_CAP = 16 << 20  # bytes read in one tick at most (the rest waits for the next)
COSTS = 4096  # per-update costs kept for the panel and the benchmark
Z_UP = Matrix(((1, 0, 0, 0), (0, 0, -1, 0), (0, 1, 0, 0), (0, 0, 0, 1)))  # glTF Y up -> Z up


PC2_HEADER = struct.Struct("<12siiffi")  # signature, version, points, start frame, rate, samples


class PointCache:
    """A PC2 point cache of the recorded mesh (Blender's Mesh Cache modifier reads it): one
    sample per scene frame from ``start``; the header's sample count is patched after every
    write, so the file is whole whenever it is read. Layout: puppet's ``puppet.export.pc2``
    (little endian: "POINTCACHE2\\0", 1, points, start frame, 1.0, samples; then samples x
    points x float32 x, y, z, the mesh's own space)."""

    def __init__(self, path: str, points: int, start: int):
        self.file = open(path, "wb")
        self.points, self.start, self.samples = points, start, 0
        self.file.write(PC2_HEADER.pack(b"POINTCACHE2\0", 1, points, float(start), 1.0, 0))

    def add(self, co: np.ndarray, frame: int) -> None:
        """The mesh ``co`` (points x 3 float32) at scene frame ``frame`` (the next one)."""
        while self.start + self.samples <= frame:  # (a gap repeats; recording leaves none)
            self.file.write(co.tobytes())
            self.samples += 1
        self.file.seek(PC2_HEADER.size - 4)
        self.file.write(struct.pack("<i", self.samples))
        self.file.seek(0, 2)
        self.file.flush()

    def close(self) -> None:
        self.file.close()


def _trs(t, q) -> Matrix:
    """4x4 from a translation (x, y, z) and a glTF quaternion (x, y, z, w)."""
    m = Quaternion((q[3], q[0], q[1], q[2])).to_matrix().to_4x4()
    m.translation = Vector(t)
    return m


def mapping(armature) -> dict:
    """{joint: bone} saved on the armature (names that differ)."""
    data = armature.data
    return {k[len(MAP_PREFIX):]: str(data[k]) for k in data.keys() if k.startswith(MAP_PREFIX)}


class ExactMesh:
    """The exact mesh on a copy the add-on owns (see the module docstring): ``show(user)``
    makes it and hides the user's object, ``write(vertices)`` puts puppet's model-frame
    vertices (n x 3 float32, a buffer) in, ``remove()`` deletes it and restores the user's
    object's visibility. The user's mesh data and modifiers are never written."""

    def __init__(self):
        self.user = None  # the user's mesh object (name)
        self.copy = None  # our object (name)
        self.hidden = None  # the user's object's (hide_viewport, hide_render) before

    def show(self, user) -> bool:
        if self.copy is not None and self.user == user.name and self.copy in bpy.data.objects:
            return True
        self.remove()
        data = user.data.copy()
        data.name = f"{user.data.name} (puppet)"
        copy = bpy.data.objects.new(f"{user.name} (puppet)", data)
        for collection in user.users_collection or (bpy.context.scene.collection,):
            collection.objects.link(copy)
        if data.shape_keys is not None:
            copy.shape_key_clear()
        copy.matrix_world = Z_UP  # puppet's model frame (the file's world) -> Blender's
        self.user, self.copy = user.name, copy.name
        self.hidden = (user.hide_viewport, user.hide_render)
        user.hide_viewport = user.hide_render = True
        return True

    def write(self, vertices) -> None:
        """One bulk copy into the position attribute (``mesh.vertices.foreach_set("co")``
        goes vertex by vertex: 15 ms for the critter's 24 910, against 0.02 ms), then tag the
        mesh for Blender's next evaluation (normals included)."""
        data = bpy.data.objects[self.copy].data
        data.attributes["position"].data.foreach_set(
            "vector", np.frombuffer(vertices, np.float32))
        data.update()

    def remove(self) -> None:
        if self.copy is not None:
            copy = bpy.data.objects.get(self.copy)
            if copy is not None:
                data = copy.data
                bpy.data.objects.remove(copy)
                if data is not None and data.users == 0:
                    bpy.data.meshes.remove(data)
            user = bpy.data.objects.get(self.user)
            if user is not None and self.hidden is not None:
                user.hide_viewport, user.hide_render = self.hidden
        self.user = self.copy = self.hidden = None


class Recording:
    """One recording: its own action (named after the take) on the armature, 7 F-curves per
    bound bone (location x, y, z; rotation w, x, y, z), keys written straight into their
    keyframe points, LINEAR, one per integer scene frame (see the module docstring); and the
    point cache of the exact mesh when asked. ``add(at, values, co)`` per streamed frame: its
    scene frame (float), its bones' values (7 per bone) and its mesh in the mesh's own space
    (or None); ``flush()`` writes the keys gathered (once per tick)."""

    def __init__(self, name: str, armature, bones, cache_path: str | None):
        self.action = bpy.data.actions.new(name)
        animation = armature.animation_data or armature.animation_data_create()
        animation.action = self.action
        self.curves = []
        for pose_bone in bones:
            bone = pose_bone.name
            for path, width in (("location", 3), ("rotation_quaternion", 4)):
                for i in range(width):
                    self.curves.append(self.action.fcurve_ensure_for_datablock(
                        armature, f'pose.bones["{bpy.utils.escape_identifier(bone)}"].{path}',
                        index=i, group_name=bone))
        self.cache_path, self.cache = cache_path, None
        self.previous = None  # (at, values, co) of the frame before
        self.pending = []  # (scene frame, values) not yet in the F-curves
        self.frames = []  # every scene frame keyed, in order (8 bytes a frame)
        self.streamed = []  # the scene frame (float) of every frame puppet sent, in order
        self.keys = 0

    def add(self, at: float, values: np.ndarray, co) -> None:
        self.streamed.append(at)
        if self.previous is None:
            if abs(at - round(at)) < 1e-6:
                self._key(round(at), values, co)
        else:
            before, old, old_co = self.previous
            if at <= before:  # (a frame out of order: nothing puppet sends)
                return
            for f in range(math.floor(before) + 1, math.floor(at + 1e-6) + 1):
                w = (f - before) / (at - before)
                if w >= 1.0 - 1e-9:
                    self._key(f, values, co)
                else:
                    blend = old + w * (values - old)
                    _normalize_quaternions(blend)
                    self._key(f, blend, None if co is None else old_co + w * (co - old_co))
        self.previous = (at, values, co)

    def _key(self, frame: int, values, co) -> None:
        self.pending.append((frame, values))
        self.frames.append(frame)
        if co is not None and self.cache_path:
            if self.cache is None:
                path = self.cache_path.replace("{take}", bpy.path.clean_name(self.action.name))
                self.cache = PointCache(bpy.path.abspath(path), len(co), frame)
            self.cache.add(co.astype(np.float32, copy=False), frame)

    def flush(self) -> None:
        """Write the pending keys into the F-curves (k points added per curve at once)."""
        if not self.pending:
            return
        k = len(self.pending)
        for c, curve in enumerate(self.curves):
            points = curve.keyframe_points
            n = len(points)
            points.add(k)
            for i, (frame, values) in enumerate(self.pending):
                point = points[n + i]
                point.co = (frame, values[c])
                point.interpolation = "LINEAR"
        self.keys += k
        self.pending.clear()

    def close(self) -> None:
        self.flush()
        if self.cache is not None:
            self.cache.close()
            self.cache = None


def _normalize_quaternions(values: np.ndarray) -> None:
    """values: per bone 3 location then 4 quaternion numbers; each quaternion made unit."""
    per_bone = values.reshape(-1, 7)
    q = per_bone[:, 3:]
    q /= np.linalg.norm(q, axis=1, keepdims=True)


class Link:
    """One connection to puppet and the armature it drives (module state; see ``tick``).

    state: off | connecting | connected | waiting (to retry) | refused. status: a line for the
    panel. notes: mapping problems. health: puppet's last health message. Counts:
    frames_applied, frames_received, malformed, skipped (received, not shown: a newer one came
    in the same tick). costs: {"receive", "bones", "mesh", "record"}: Blender-side CPU
    milliseconds per update (reading the socket and decoding; posing the armature; writing the
    exact mesh; keying), the last COSTS of each.
    """

    def __init__(self):
        self.sock = None
        self.reader = None
        self.hello = None
        self.target = None  # (host, port, token) while Connect holds
        self.state = "off"
        self.status = "not connected"
        self.notes: list[str] = []
        self.frames_applied = self.frames_received = self.malformed = self.skipped = 0
        self.last_seq, self.last_take_s = -1, 0.0
        self.bones = []  # (pose bone, joint, parent joint or -1, B⁻¹Z, Z⁻¹B)
        self.keyed_q = {}  # bone name: its last keyed quaternion
        self.recording: Recording | None = None
        self.recordings = 0
        self.exact = ExactMesh()
        self.mesh_on = self.record_on = False
        self.bound_to = None  # the armature bound (name)
        self.health = {}
        self.recent_skips = 0  # frames puppet skipped for us between its last two health messages
        self.retry_at = 0.0
        self.connect_started = 0.0
        self.last_frame_at = None  # time.monotonic() a frame last arrived
        self.last_tick_at = None
        self.stall_note = ""
        self.stall_until = 0.0
        self.costs = {name: deque(maxlen=COSTS) for name in ("receive", "bones", "mesh", "record")}

    # -- connection -----------------------------------------------------------------------

    def connect(self, host: str, port: int, token: str, mesh: bool, record: bool) -> None:
        """Hold a connection to host:port until ``disconnect``: try now, and again every
        RETRY_S whenever it fails or puppet stops."""
        self.close()
        self.target = (host, int(port), token)
        self.mesh_on, self.record_on = bool(mesh), bool(record)
        self.hello, self.bones, self.bound_to = None, [], None
        self.retry_at = 0.0
        self._attempt()

    def _attempt(self) -> None:
        host, port, _ = self.target
        try:
            family, kind, proto, _, address = socket.getaddrinfo(
                host, port, type=socket.SOCK_STREAM)[0]
            self.sock = socket.socket(family, kind, proto)
            self.sock.setblocking(False)
            self.sock.connect_ex(address)
        except OSError as err:
            self._wait(f"cannot reach {host}:{port}: {err.strerror or err}")
            return
        self.state, self.connect_started = "connecting", time.monotonic()
        self.status = f"connecting to {host}:{port}"

    def _connecting(self) -> None:
        """A connection under way: once the socket is writable, say who we are."""
        host, port, token = self.target
        _, ready, _ = select.select([], [self.sock], [], 0)
        if not ready:
            if time.monotonic() - self.connect_started > CONNECT_S:
                self._wait(f"no answer from {host}:{port}")
            return
        error = self.sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
        if error:
            self._wait(f"puppet is not running at {host}:{port} ({errno_text(error)})")
            return
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock.setblocking(True)
        self.sock.settimeout(2.0)
        try:
            self.sock.sendall(wire.encode_json(wire.CONNECT, {
                "protocol": wire.PROTOCOL, "token": token or None, "mesh": self.mesh_on,
                "record": self.record_on, "health": True, "name": "blender"}))
        except OSError as err:
            self._wait(f"lost {host}:{port} ({err})")
            return
        self.sock.setblocking(False)
        self.reader = wire.Reader()
        self.state = "handshake"
        self.status = f"waiting for puppet's hello from {host}:{port}"

    def _wait(self, status: str) -> None:
        """Close the socket and try again in RETRY_S (while Connect holds)."""
        if self.sock is not None:
            self.sock.close()
        self.sock = None
        self.status = status  # (tick ends the recording once this poll's frames are keyed)
        self.state = "waiting" if self.target is not None else "off"
        self.retry_at = time.monotonic() + RETRY_S

    def close(self, status: str = "not connected") -> None:
        """Disconnect: stop trying, end the recording, delete the exact mesh's copy."""
        if self.sock is not None:
            self.sock.close()
        self.sock = None
        self.target = None
        self.state = "off"
        self.status = status
        self.end_recording()
        self.exact.remove()

    def end_recording(self) -> None:
        if self.recording is not None:
            self.recording.close()
            self.recording = None

    def set_options(self, mesh: bool, record: bool) -> None:
        """Tell puppet whether to send the vertices and every frame (Record)."""
        if (mesh, record) == (self.mesh_on, self.record_on) or self.state == "handshake":
            return  # (during the handshake: sent once the hello is in)
        self.mesh_on, self.record_on = bool(mesh), bool(record)  # the next CONNECT's, if none
        if self.sock is not None and self.state == "connected":
            try:
                self.sock.setblocking(True)
                self.sock.sendall(wire.encode_json(wire.MESH, {"mesh": self.mesh_on,
                                                               "record": self.record_on}))
                self.sock.setblocking(False)
            except OSError as err:
                self._wait(f"puppet connection lost ({err}); last pose kept")

    def poll(self) -> list:
        """Read what arrived (never blocks, at most READ_CAP bytes); every frame, in order."""
        frames = []
        taken = 0
        while self.sock is not None and self.state in ("handshake", "connected") \
                and taken < READ_CAP:
            try:
                data = self.sock.recv(1 << 20)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as err:
                self._wait(f"puppet connection lost ({err}); last pose kept")
                break
            if not data:
                self._wait("puppet stopped streaming; last pose kept")
                break
            taken += len(data)
            self.reader.feed(data)
            try:
                for kind, body in self.reader.messages():
                    try:
                        content = wire.decode(kind, body)
                    except ValueError:
                        self.malformed += 1
                        continue
                    if kind == wire.FRAME_KIND:
                        frames.append(content)
                    elif kind == wire.HEALTH:
                        self.recent_skips = (content.get("skipped", 0)
                                             - self.health.get("skipped", 0))
                        self.health = content
                    elif kind == wire.HELLO:
                        self.end_recording()  # a new connection: a new take
                        self.hello, self.bones, self.health = content, [], {}
                        self.state = "connected"
                        self.status = (f"connected: rig {content.get('rig')}, "
                                       f"{len(content.get('joints', []))} joints")
                    elif kind == wire.ERROR:
                        self._wait(f"refused: {content.get('error')}")
                        self.target, self.state = None, "refused"  # the same would be refused
                    elif kind == wire.BYE:
                        self._wait(f"puppet stopped streaming ({content.get('reason')}); "
                                   "last pose kept")
                    else:
                        self.malformed += 1
            except wire.WireError:
                self.malformed += 1
                self._wait("malformed stream from puppet; disconnected, last pose kept")
        self.frames_received += len(frames)
        return frames

    def ack(self, seq: int) -> None:
        if self.sock is None:
            return
        try:
            self.sock.send(wire.encode_ack(seq, time.monotonic()))
        except (BlockingIOError, OSError):
            pass

    # -- the armature ------------------------------------------------------------------------

    def _worlds(self, translations, rotations) -> list:
        """Each joint's transform in the armature node's space (glTF axes) for its keys."""
        worlds = []
        for j, parent in enumerate(self.parents):
            local = self.above[j] @ _trs(translations[3 * j:3 * j + 3],
                                         rotations[4 * j:4 * j + 4])
            worlds.append(local if parent < 0 else worlds[parent] @ local)
        return worlds

    def bind(self, armature) -> None:
        """Match the hello's joints to ``armature``'s bones (saved mapping, else same name)."""
        hello = self.hello
        joints, parents = hello["joints"], hello["parents"]
        saved = mapping(armature)
        self.notes = []
        self.parents = parents
        above = hello.get("above") or [None] * len(joints)
        self.above = [Matrix.Identity(4) if a is None else
                      Matrix([a[0:4], a[4:8], a[8:12], a[12:16]]) for a in above]
        flat_t = [x for t in hello["rest_translation"] for x in t]
        flat_q = [x for q in hello["rest_rotation"] for x in q]
        self.rest_inv = [m.inverted() for m in self._worlds(flat_t, flat_q)]
        joint_of_bone = {}
        self.bones = []
        for j, name in enumerate(joints):
            bone_name = saved.get(name, name)
            pose_bone = armature.pose.bones.get(bone_name)
            if pose_bone is None:
                where = "saved mapping" if name in saved else "same name"
                self.notes.append(f"joint {name}: no bone {bone_name!r} ({where}); not driven")
                continue
            joint_of_bone[bone_name] = j
            pose_bone.rotation_mode = "QUATERNION"
            B = pose_bone.bone.matrix_local.copy()
            self.bones.append([pose_bone, j, -1, B.inverted() @ Z_UP, Z_UP.inverted() @ B])
        for entry in self.bones:  # the nearest driven bone above (undriven ones stay at rest)
            parent = entry[0].parent
            while parent is not None and parent.name not in joint_of_bone:
                parent = parent.parent
            entry[2] = joint_of_bone[parent.name] if parent is not None else -1
        driven = {e[0].name for e in self.bones}
        extra = [b.name for b in armature.pose.bones if b.name not in driven]
        if extra:
            self.notes.append(f"{len(extra)} bones not driven: {', '.join(extra[:8])}"
                              + (" ..." if len(extra) > 8 else ""))
        self.notes.insert(0, f"{len(self.bones)} of {len(joints)} joints drive bones")

    def basis(self, frame) -> list:
        """Each bound bone's matrix_basis for ``frame``."""
        G = self._worlds(frame.translations, frame.rotations)
        delta = [G[j] @ self.rest_inv[j] for j in range(frame.count)]
        return [left @ (delta[j] if p < 0 else delta[p].inverted() @ delta[j]) @ right
                for _pose_bone, j, p, left, right in self.bones]

    def apply(self, frame) -> None:
        """Pose the bound bones with ``frame``."""
        for entry, matrix in zip(self.bones, self.basis(frame)):
            entry[0].matrix_basis = matrix

    def values(self, frame) -> np.ndarray:
        """The bound bones' keyed values for ``frame``: per bone location (3) and quaternion
        (w, x, y, z), each on the hemisphere of the bone's previous key (q and -q are one
        rotation; keys on opposite sides would interpolate through a wrong one)."""
        out = np.empty(7 * len(self.bones))
        for i, (entry, matrix) in enumerate(zip(self.bones, self.basis(frame))):
            location, q, _ = matrix.decompose()
            previous = self.keyed_q.get(entry[0].name)
            if previous is not None and q.dot(previous) < 0:
                q.negate()
            self.keyed_q[entry[0].name] = q
            out[7 * i:7 * i + 3] = location
            out[7 * i + 3:7 * i + 7] = q
        return out

    def mesh_fits(self, frame, mesh_object) -> bool:
        """Whether ``frame``'s vertices fit the mesh (a note when the counts differ)."""
        n = len(frame.vertices) // 3
        if n == len(mesh_object.data.vertices):
            return True
        note = f"mesh {mesh_object.name}: {len(mesh_object.data.vertices)} vertices, puppet sends {n}"
        if note not in self.notes:
            self.notes.append(note)
        return False

    def record(self, frame, armature, settings, mesh_object) -> None:
        """Key ``frame`` (see Recording) at start + take time x scene fps; a new recording
        (its own action) when none is under way."""
        scene = bpy.context.scene
        if self.recording is None:
            hello = self.hello
            name = hello.get("take") or f"{hello.get('rig', 'puppet')} {time.strftime('%H:%M:%S')}"
            self.recording = Recording(name, armature, [e[0] for e in self.bones],
                                       settings.point_cache or None)
            self.place_sound(scene, settings.start_frame)
            self.recordings += 1
            self.keyed_q = {}
        co = None
        if (mesh_object is not None and settings.point_cache and frame.vertices is not None
                and self.mesh_fits(frame, mesh_object)):
            K = np.array(mesh_object.matrix_world.inverted() @ Z_UP)  # model -> mesh's own
            points = np.frombuffer(frame.vertices, np.float32).reshape(-1, 3)
            co = points @ K[:3, :3].T + K[:3, 3]
        fps = scene.render.fps / scene.render.fps_base
        self.recording.add(settings.start_frame + frame.take_s * fps, self.values(frame), co)

    def place_sound(self, scene, start_frame: int) -> None:
        """Put the take's sound (the hello's) on the scene's timeline as the strip SOUND_STRIP,
        its sample 0 at start_frame - offset_s x scene fps, so it plays in sync with the keys;
        the previous take's strip of that name goes (a take without sound leaves none)."""
        editor = scene.sequence_editor or scene.sequence_editor_create()
        strips = editor.strips if hasattr(editor, "strips") else editor.sequences  # Blender 5
        old = strips.get(SOUND_STRIP)
        if old is not None:
            strips.remove(old)
        sound = self.hello.get("sound")
        if not sound:
            return
        fps = scene.render.fps / scene.render.fps_base
        frame = round(start_frame - float(sound["offset_s"]) * fps)
        try:
            strips.new_sound(SOUND_STRIP, sound["path"], 1, frame)
        except RuntimeError as err:  # not readable from this machine
            self.notes.append(f"sound {sound['path']}: {err}; the take is keyed without it")

    # -- health ------------------------------------------------------------------------------

    def health_lines(self) -> list:
        """The panel's lines on the link's health: puppet's reading -> applied (median, p99)
        and applied rate, and what is wrong (a stall, frames dropped or lost)."""
        h, lines = self.health, []
        if self.state == "connected" and h:
            median, p99 = h.get("applied_median_ms"), h.get("applied_p99_ms")
            latency = ("reading->applied: none yet" if median is None else
                       f"reading->applied median {median:.1f} ms, p99 {p99:.1f} ms")
            lines.append(f"{latency}; applied {h.get('acked_per_s', 0):.1f}/s")
            if self.recent_skips > 0:
                lines.append(f"dropping: {self.recent_skips} frames skipped in the last "
                             f"{wire.HEALTH_S:g} s (Blender slower than puppet; live display "
                             "only, recordings queue)")
            if h.get("lost"):
                lines.append(f"LOST {h['lost']} recorded frames (Blender too far behind)")
        now = time.monotonic()
        if (self.state == "connected" and self.last_frame_at is not None
                and now - self.last_frame_at > STALL_S):
            lines.append(f"stalled: no frame from puppet for {now - self.last_frame_at:.1f} s")
        if self.stall_note and now < self.stall_until:
            lines.append(self.stall_note)
        if self.recording is not None:
            lines.append(f"recording {self.recording.action.name}: {len(self.recording.frames)}"
                         " frames keyed")
        return lines


def errno_text(code: int) -> str:
    import os

    return os.strerror(code)


LINK = Link()


def _redraw() -> None:
    screen = getattr(bpy.context, "screen", None)
    for area in (screen.areas if screen is not None else ()):
        if area.type == "VIEW_3D":
            area.tag_redraw()


def tick():
    """The per-tick step: (re)connect, read, key every frame being recorded, apply the newest
    frame (bones; the exact mesh when on), ack it. Returns the seconds to the next tick (a
    ``bpy.app.timers`` callback), None once disconnected."""
    settings = bpy.context.scene.puppet_link
    now = time.monotonic()
    if LINK.last_tick_at is not None and now - LINK.last_tick_at > 0.25:
        LINK.stall_note = f"Blender was busy {now - LINK.last_tick_at:.1f} s: frames queued"
        LINK.stall_until = now + 5.0
    LINK.last_tick_at = now
    if LINK.target is None and LINK.sock is None:
        LINK.end_recording()
        if LINK.state != "refused":
            LINK.exact.remove()
        _redraw()
        return None
    if LINK.sock is None:
        if now >= LINK.retry_at:
            LINK._attempt()
        return TICK_S if LINK.sock is not None else RETRY_S / 4
    if LINK.state == "connecting":
        LINK._connecting()
        return TICK_S
    armature, mesh_object = settings.armature, settings.mesh
    LINK.set_options(settings.use_mesh and mesh_object is not None, settings.record)
    received = time.thread_time()
    frames = LINK.poll()
    received = (time.thread_time() - received) * 1e3
    if not (settings.use_mesh and mesh_object is not None):
        LINK.exact.remove()
    if not frames or LINK.hello is None or armature is None:
        if LINK.state != "connected":
            LINK.end_recording()
        if now - getattr(tick, "drawn", 0.0) > 0.5:
            tick.drawn = now
            _redraw()
        return TICK_S
    LINK.last_frame_at = now
    if not LINK.bones or LINK.bound_to != armature.name:
        LINK.bind(armature)
        LINK.bound_to = armature.name
    LINK.costs["receive"].append(received)
    started = time.thread_time()  # costs: this thread's CPU time (a busy machine inflates none)
    for frame in frames:
        if settings.record or frame.recording:
            LINK.record(frame, armature, settings, mesh_object)
        elif LINK.recording is not None:  # puppet stopped recording
            LINK.end_recording()
    if LINK.recording is not None:
        LINK.recording.flush()
        if (not settings.record and not frames[-1].recording) or LINK.state != "connected":
            LINK.end_recording()
    recorded = time.thread_time()
    newest = frames[-1]
    LINK.skipped += len(frames) - 1
    LINK.apply(newest)
    posed = time.thread_time()
    if settings.use_mesh and mesh_object is not None and newest.vertices is not None:
        if LINK.mesh_fits(newest, mesh_object) and LINK.exact.show(mesh_object):
            LINK.exact.write(newest.vertices)
            LINK.costs["mesh"].append((time.thread_time() - posed) * 1e3)
    if frames[0].recording or settings.record:
        LINK.costs["record"].append((recorded - started) * 1e3)
    LINK.costs["bones"].append((posed - recorded) * 1e3)
    LINK.frames_applied += 1
    LINK.last_seq, LINK.last_take_s = newest.seq, newest.take_s
    LINK.ack(newest.seq)
    if now - getattr(tick, "drawn", 0.0) > 0.5:
        tick.drawn = now
        _redraw()
    return TICK_S


def _is_armature(_self, obj):
    return obj.type == "ARMATURE"


def _is_mesh(_self, obj):
    return obj.type == "MESH"


def bvh_names_back(bvh_armature, spelled) -> dict:
    """Rename the bones of an armature that Blender's BVH importer made to the spelling in
    ``spelled`` (the names of the character's bones or vertex groups, in its joint order) where
    puppet's BVH rule (``names.safe_names(spelled, "bvh")``: whitespace -> "_", accents dropped,
    made unique) gave the bone its name; Blender renames the action's F-curve paths with them.
    Returns {BVH name: name now} for every bone renamed."""
    written, _changed = names.safe_names(list(spelled), "bvh")
    back = {new: old for old, new in zip(spelled, written) if new != old}
    renamed = {}
    for bone in bvh_armature.data.bones:
        original = back.get(bone.name)
        if original is not None and original not in bvh_armature.data.bones:
            renamed[bone.name] = original
    for written_name, original in renamed.items():
        bvh_armature.data.bones[written_name].name = original
    return renamed


class PuppetLinkSettings(bpy.types.PropertyGroup):
    host: bpy.props.StringProperty(name="Host", default="127.0.0.1")
    port: bpy.props.IntProperty(name="Port", default=9100, min=1, max=65535)
    token: bpy.props.StringProperty(name="Token", default="", subtype="PASSWORD",
                                    description="Printed by puppet when it listens beyond loopback")
    armature: bpy.props.PointerProperty(name="Armature", type=bpy.types.Object, poll=_is_armature)
    mesh: bpy.props.PointerProperty(name="Mesh", type=bpy.types.Object, poll=_is_mesh)
    use_mesh: bpy.props.BoolProperty(
        name="Exact mesh", default=False,
        description="Show puppet's FAST vertices on a copy of the mesh (the mesh itself is "
                    "never written; it is hidden meanwhile and shown again when this is off)")
    record: bpy.props.BoolProperty(name="Record", default=False,
                                   description="Key the bones at start + take time x scene fps")
    start_frame: bpy.props.IntProperty(name="Start frame", default=1)
    point_cache: bpy.props.StringProperty(
        name="Point cache", default="", subtype="FILE_PATH",
        description="While recording the exact mesh, also write it to this PC2 file (empty: "
                    "no); {take} in the path becomes the recording's name (one file per take)")


class PUPPETLINK_OT_connect(bpy.types.Operator):
    """Connect to a running puppet (puppet live/demo/play --link)"""

    bl_idname = "puppet_link.connect"
    bl_label = "Connect"

    def execute(self, context):
        s = context.scene.puppet_link
        LINK.connect(s.host, s.port, s.token, s.use_mesh and s.mesh is not None, s.record)
        if not bpy.app.timers.is_registered(tick):
            bpy.app.timers.register(tick, first_interval=0.0)
        return {"FINISHED"}


class PUPPETLINK_OT_disconnect(bpy.types.Operator):
    """Stop receiving and stop reconnecting (the last pose stays; the exact mesh's copy goes and
    the mesh is shown as it was)"""

    bl_idname = "puppet_link.disconnect"
    bl_label = "Disconnect"

    def execute(self, context):
        LINK.close()
        return {"FINISHED"}


class PUPPETLINK_OT_map(bpy.types.Operator):
    """Save a bone for a joint whose name differs (kept on the armature)"""

    bl_idname = "puppet_link.map"
    bl_label = "Map joint"

    joint: bpy.props.StringProperty(name="Joint")
    bone: bpy.props.StringProperty(name="Bone")

    def execute(self, context):
        armature = context.scene.puppet_link.armature
        if armature is None:
            return {"CANCELLED"}
        armature.data[MAP_PREFIX + self.joint] = self.bone
        LINK.bones = []  # bind again on the next frame
        return {"FINISHED"}

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)


class PUPPETLINK_OT_bvh_names(bpy.types.Operator):
    """Give the active armature (a BVH that puppet exported, as Blender imported it) the
    character's bone names where puppet's BVH rule changed them (a space became "_"), so its
    bones drive the character's vertex groups"""

    bl_idname = "puppet_link.bvh_names"
    bl_label = "BVH names back"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        bvh = context.active_object
        others = [o for o in context.selected_objects if o is not bvh]
        if bvh is None or bvh.type != "ARMATURE" or len(others) != 1:
            self.report({"ERROR"}, "select the character (armature or mesh), then the BVH's "
                                   "armature last (active)")
            return {"CANCELLED"}
        other = others[0]
        spelled = ([b.name for b in other.data.bones] if other.type == "ARMATURE" else
                   [g.name for g in other.vertex_groups])
        renamed = bvh_names_back(bvh, spelled)
        self.report({"INFO"}, f"{len(renamed)} bones renamed")
        return {"FINISHED"}


class PUPPETLINK_PT_panel(bpy.types.Panel):
    bl_label = "puppet link"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Puppet"

    def draw(self, context):
        s, layout = context.scene.puppet_link, self.layout
        layout.prop(s, "host")
        layout.prop(s, "port")
        layout.prop(s, "token")
        row = layout.row()
        row.operator("puppet_link.connect")
        row.operator("puppet_link.disconnect")
        layout.label(text=f"[{LINK.state}] {LINK.status}")
        if LINK.state == "waiting":
            layout.label(text=f"reconnecting every {RETRY_S:g} s (Disconnect stops)")
        for line in LINK.health_lines():
            layout.label(text=line)
        layout.label(text=f"frames applied {LINK.frames_applied}, skipped {LINK.skipped}, "
                          f"malformed {LINK.malformed}")
        layout.prop(s, "armature")
        layout.prop(s, "mesh")
        layout.prop(s, "use_mesh")
        row = layout.row()
        row.prop(s, "record")
        row.prop(s, "start_frame")
        layout.prop(s, "point_cache")
        for note in LINK.notes:
            layout.label(text=note)
        if s.armature is not None:
            box = layout.box()
            box.label(text="Saved mapping (joint -> bone):")
            for key in s.armature.data.keys():
                if key.startswith(MAP_PREFIX):
                    box.prop(s.armature.data, f'["{key}"]', text=key[len(MAP_PREFIX):])
            box.operator("puppet_link.map")
        layout.operator("puppet_link.bvh_names")


CLASSES = (PuppetLinkSettings, PUPPETLINK_OT_connect, PUPPETLINK_OT_disconnect, PUPPETLINK_OT_map,
           PUPPETLINK_OT_bvh_names, PUPPETLINK_PT_panel)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.puppet_link = bpy.props.PointerProperty(type=PuppetLinkSettings)


def unregister():
    LINK.close()
    if bpy.app.timers.is_registered(tick):
        bpy.app.timers.unregister(tick)
    del bpy.types.Scene.puppet_link
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
