"""puppet link: a Blender add-on that poses an armature (and its mesh) live from ``puppet ...
--link`` and records into the timeline. Nothing beyond Blender's own Python; the protocol is
puppet's ``wire`` module, shipped next to this file.

In Blender: View3D > Sidebar > Puppet. Connect (host, port, token beyond loopback), pick the
armature imported from the rig's .glb (and its mesh), check the bone mapping, tick Record to key
the bones at scene frame = start frame + take time x scene fps.

Every tick (``tick()``, on a ``bpy.app.timers`` callback; never blocking) reads what arrived,
applies the newest frame and acks it. A frame's joint keys are glTF node translations and
rotations (Y up) relative to each joint's parent node, as the exported .glb holds them; the
hello's ``above`` places them in the armature node's space (the node Blender's glTF importer
makes the armature object, however it is moved, turned or scaled): G = G_parent · above · key.
The bones get the same rigid motion in Blender's Z-up armature space, as the importer plays the
file's keys: matrix_basis = B⁻¹ Z Δp⁻¹ Δj Z⁻¹ B, with B the bone's rest matrix, Z the
glTF-to-Blender axes, Δ = G·G_rest⁻¹ a joint's motion from its rest and p the nearest driven
bone above. Vertices (model frame, the file's world) go into the mesh through its object's
world: co = mesh world⁻¹ Z v.

Recording: a frame puppet flags recording (``puppet live --record``), or any frame while Record
is ticked, keys the bones at scene frame start + take time × scene fps (take time: the reading's
time on the take's time line), where ``puppet export`` of the take puts it.
"""

from __future__ import annotations

import socket
import struct
import time

import bpy
from mathutils import Matrix, Quaternion, Vector

from . import wire

bl_info = {
    "name": "puppet link",
    "author": "puppet",
    "version": (1, 0, 0),
    "blender": (4, 2, 0),
    "location": "View3D > Sidebar > Puppet",
    "description": "Pose an armature live from a puppet (puppet live/demo/play --link), record it",
    "category": "Animation",
}

MAP_PREFIX = "puppet_map:"  # armature data custom property: joint -> bone, where names differ
TICK_S = 0.004
Z_UP = Matrix(((1, 0, 0, 0), (0, 0, -1, 0), (0, 1, 0, 0), (0, 0, 0, 1)))  # glTF Y up -> Z up


PC2_HEADER = struct.Struct("<12siiffi")  # signature, version, points, start frame, rate, samples


class PointCache:
    """A PC2 point cache of the recorded mesh (Blender's Mesh Cache modifier reads it): one
    sample per scene frame from ``start``, each the newest recorded mesh at or before it (a
    frame that came late repeats the one before); the header's sample count is patched after
    every write, so the file is whole whenever it is read. Layout: puppet's
    ``puppet.export.pc2`` (little endian: "POINTCACHE2\\0", 1, points, start frame, 1.0,
    samples; then samples x points x float32 x, y, z, the mesh's own space)."""

    def __init__(self, path: str, points: int, start: int):
        self.file = open(path, "wb")
        self.points, self.start, self.samples = points, start, 0
        self.file.write(PC2_HEADER.pack(b"POINTCACHE2\0", 1, points, float(start), 1.0, 0))

    def add(self, co: bytes, at: float) -> None:
        """The mesh ``co`` (points x 3 float32) recorded at scene frame ``at``."""
        while self.start + self.samples <= round(at):
            self.file.write(co)
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


class Link:
    """One connection to puppet and the armature it drives (module state; see ``tick``).

    status: a line for the panel. notes: mapping problems. frames_applied, malformed, skipped.
    """

    def __init__(self):
        self.sock = None
        self.reader = None
        self.hello = None
        self.status = "not connected"
        self.notes: list[str] = []
        self.frames_applied = self.malformed = self.skipped = 0
        self.last_seq, self.last_take_s = -1, 0.0
        self.bones = []  # (pose bone, joint, parent joint or -1, B⁻¹Z, Z⁻¹B)
        self.recorded = 0
        self.last_frame = None  # the scene frame keyed last
        self.keyed_q = {}  # bone name: its last keyed quaternion
        self.mesh_co = None  # the mesh's coordinates last written (points x 3 float32)
        self.cache = None  # the PointCache being written
        self.mesh_on = False
        self.bound_to = None  # the armature bound (name)

    # -- connection -----------------------------------------------------------------------

    def connect(self, host: str, port: int, token: str, mesh: bool) -> None:
        self.close()
        self.end_cache()
        self.sock = socket.create_connection((host, port), timeout=5.0)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock.sendall(wire.encode_json(wire.CONNECT, {
            "protocol": wire.PROTOCOL, "token": token or None, "mesh": bool(mesh),
            "name": "blender"}))
        self.sock.setblocking(False)
        self.reader = wire.Reader()
        self.mesh_on = bool(mesh)
        self.status = f"connecting to {host}:{port}"

    def close(self, status: str = "not connected") -> None:
        if self.sock is not None:
            self.sock.close()
        self.sock = None
        self.status = status

    def end_cache(self) -> None:
        """Close the point cache (the next recording starts a new one)."""
        if self.cache is not None:
            self.cache.close()
            self.cache = None

    def cache_mesh(self, path: str, at: float) -> None:
        """Add the mesh just written to the point cache at ``path`` (opened at the first one)."""
        if self.cache is None:
            self.cache = PointCache(bpy.path.abspath(path), len(self.mesh_co), round(at))
        self.cache.add(self.mesh_co.tobytes(), at)

    def set_mesh(self, on: bool) -> None:
        if self.sock is not None and self.hello is not None and on != self.mesh_on:
            self.sock.setblocking(True)
            self.sock.sendall(wire.encode_json(wire.MESH, {"mesh": bool(on)}))
            self.sock.setblocking(False)
        self.mesh_on = bool(on)

    def poll(self):
        """Read what arrived (never blocks); the newest frame, or None."""
        newest = None
        while self.sock is not None:
            try:
                data = self.sock.recv(1 << 20)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as err:
                self.close(f"puppet connection lost ({err}); last pose kept")
                break
            if not data:
                self.close("puppet stopped streaming; last pose kept")
                break
            self.reader.feed(data)
            try:
                for kind, body in self.reader.messages():
                    try:
                        content = wire.decode(kind, body)
                    except ValueError:
                        self.malformed += 1
                        continue
                    if kind == wire.FRAME_KIND:
                        if newest is not None:
                            self.skipped += 1
                        newest = content
                    elif kind == wire.HELLO:
                        self.hello = content
                        self.status = (f"connected: rig {content.get('rig')}, "
                                       f"{len(content.get('joints', []))} joints")
                    elif kind == wire.ERROR:
                        self.close(f"refused: {content.get('error')}")
                    elif kind == wire.BYE:
                        self.close(f"puppet stopped streaming ({content.get('reason')}); "
                                   "last pose kept")
                    else:
                        self.malformed += 1
            except wire.WireError:
                self.malformed += 1
                self.close("malformed stream from puppet; disconnected, last pose kept")
        return newest

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

    def apply(self, frame, armature) -> None:
        """Pose the bound bones with ``frame``."""
        G = self._worlds(frame.translations, frame.rotations)
        delta = [G[j] @ self.rest_inv[j] for j in range(frame.count)]
        for pose_bone, j, p, left, right in self.bones:
            motion = delta[j] if p < 0 else delta[p].inverted() @ delta[j]
            pose_bone.matrix_basis = left @ motion @ right

    def apply_mesh(self, frame, armature, mesh_object) -> bool:
        """Write the frame's vertices into the mesh (its armature modifier off); False with a
        note when the counts differ."""
        mesh = mesh_object.data
        n = len(frame.vertices) // 3
        if n != len(mesh.vertices):
            note = f"mesh {mesh_object.name}: {len(mesh.vertices)} vertices, puppet sends {n}"
            if note not in self.notes:
                self.notes.append(note)
            return False
        for modifier in mesh_object.modifiers:
            if modifier.type == "ARMATURE":
                modifier.show_viewport = False
        import numpy as np  # Blender ships numpy; the wire itself needs none

        K = mesh_object.matrix_world.inverted() @ Z_UP  # model frame -> the mesh's own
        points = np.frombuffer(frame.vertices, np.float32).reshape(-1, 3).astype(np.float64)
        A = np.array(K, np.float64)
        out = points @ A[:3, :3].T + A[:3, 3]
        self.mesh_co = out.astype(np.float32)
        mesh.vertices.foreach_set("co", self.mesh_co.ravel())
        mesh.update()
        return True

    def record(self, frame, armature, scene, start_frame: int) -> float:
        """Key the bound bones at start + take time x scene fps (linear keys, as the glTF
        export's); the scene frame keyed. Each bone's quaternion stays on the hemisphere of its
        previous key (q and -q are one rotation; keys on opposite sides would interpolate
        through a wrong one)."""
        fps = scene.render.fps / scene.render.fps_base
        at = start_frame + frame.take_s * fps
        if abs(at - round(at)) < 1e-6:
            at = float(round(at))
        edit = bpy.context.preferences.edit
        interpolation = edit.keyframe_new_interpolation_type
        edit.keyframe_new_interpolation_type = "LINEAR"  # as the glTF export's keys play
        try:
            for pose_bone, *_ in self.bones:
                q, previous = pose_bone.rotation_quaternion, self.keyed_q.get(pose_bone.name)
                if previous is not None and q.dot(previous) < 0:
                    pose_bone.rotation_quaternion = -q
                self.keyed_q[pose_bone.name] = pose_bone.rotation_quaternion.copy()
                pose_bone.keyframe_insert("location", frame=at, group=pose_bone.name)
                pose_bone.keyframe_insert("rotation_quaternion", frame=at, group=pose_bone.name)
        finally:
            edit.keyframe_new_interpolation_type = interpolation
        self.recorded += 1
        self.last_frame = at
        return at


LINK = Link()


def tick():
    """The per-tick step: read, apply the newest frame (bones; mesh when on), record, ack.
    Returns the seconds to the next tick (a ``bpy.app.timers`` callback), None once closed."""
    settings = bpy.context.scene.puppet_link
    armature = settings.armature
    if LINK.sock is None:
        LINK.end_cache()
        return None
    frame = LINK.poll()
    if frame is None or LINK.hello is None or armature is None:
        return TICK_S
    if not LINK.bones or LINK.bound_to != armature.name:
        LINK.bind(armature)
        LINK.bound_to = armature.name
    LINK.set_mesh(settings.use_mesh)
    LINK.apply(frame, armature)
    meshed = False
    if settings.use_mesh and settings.mesh is not None and frame.vertices is not None:
        meshed = LINK.apply_mesh(frame, armature, settings.mesh)
    elif not settings.use_mesh and settings.mesh is not None:
        for modifier in settings.mesh.modifiers:
            if modifier.type == "ARMATURE":
                modifier.show_viewport = True
    if settings.record or frame.recording:
        at = LINK.record(frame, armature, bpy.context.scene, settings.start_frame)
        if meshed and settings.point_cache:
            LINK.cache_mesh(settings.point_cache, at)
    LINK.frames_applied += 1
    LINK.last_seq, LINK.last_take_s = frame.seq, frame.take_s
    LINK.ack(frame.seq)
    if LINK.sock is None:  # puppet stopped with this frame
        LINK.end_cache()
    return TICK_S


def _is_armature(_self, obj):
    return obj.type == "ARMATURE"


def _is_mesh(_self, obj):
    return obj.type == "MESH"


class PuppetLinkSettings(bpy.types.PropertyGroup):
    host: bpy.props.StringProperty(name="Host", default="127.0.0.1")
    port: bpy.props.IntProperty(name="Port", default=9100, min=1, max=65535)
    token: bpy.props.StringProperty(name="Token", default="", subtype="PASSWORD",
                                    description="Printed by puppet when it listens beyond loopback")
    armature: bpy.props.PointerProperty(name="Armature", type=bpy.types.Object, poll=_is_armature)
    mesh: bpy.props.PointerProperty(name="Mesh", type=bpy.types.Object, poll=_is_mesh)
    use_mesh: bpy.props.BoolProperty(name="Exact mesh", default=False,
                                     description="Write puppet's FAST vertices into the mesh")
    record: bpy.props.BoolProperty(name="Record", default=False,
                                   description="Key the bones at start + take time x scene fps")
    start_frame: bpy.props.IntProperty(name="Start frame", default=1)
    point_cache: bpy.props.StringProperty(
        name="Point cache", default="", subtype="FILE_PATH",
        description="While recording the exact mesh, also write it to this PC2 file (empty: no)")


class PUPPETLINK_OT_connect(bpy.types.Operator):
    """Connect to a running puppet (puppet live/demo/play --link)"""

    bl_idname = "puppet_link.connect"
    bl_label = "Connect"

    def execute(self, context):
        s = context.scene.puppet_link
        try:
            LINK.connect(s.host, s.port, s.token, s.use_mesh)
        except OSError as err:
            LINK.status = f"cannot connect to {s.host}:{s.port}: {err.strerror or err}"
            self.report({"ERROR"}, LINK.status)
            return {"CANCELLED"}
        LINK.bones, LINK.bound_to, LINK.hello = [], None, None
        if not bpy.app.timers.is_registered(tick):
            bpy.app.timers.register(tick, first_interval=0.0)
        return {"FINISHED"}


class PUPPETLINK_OT_disconnect(bpy.types.Operator):
    """Stop receiving (the last pose stays)"""

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
        layout.label(text=LINK.status)
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


CLASSES = (PuppetLinkSettings, PUPPETLINK_OT_connect, PUPPETLINK_OT_disconnect, PUPPETLINK_OT_map,
           PUPPETLINK_PT_panel)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.puppet_link = bpy.props.PointerProperty(type=PuppetLinkSettings)


def unregister():
    LINK.close()
    LINK.end_cache()
    if bpy.app.timers.is_registered(tick):
        bpy.app.timers.unregister(tick)
    del bpy.types.Scene.puppet_link
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
