"""Page input applied by the loop: the checked messages that arrived since the last frame, each
to the part of the view it concerns (cameras, handles, recording, playback, keys, overlay)."""

from __future__ import annotations

from collections import deque

from puppet.errors import PuppetError


class PageInput:
    """commands: the deque of (client, message) the server thread appends to; the parts:
    cameras (Cameras), handle_desk (HandleDesk), recording (Recording), playback (Playback),
    key_poses (KeyPoses), frames (ViewFrames: the overlay), server (the ViewServer), studio
    (StudioDesk, or None: studio input is refused)."""

    def __init__(self, commands: deque, *, cameras, handle_desk, recording, playback, key_poses, frames,
                 server, studio=None):
        self._commands = commands
        self._cameras = cameras
        self._handles = handle_desk
        self._recording = recording
        self._playback = playback
        self._key_poses = key_poses
        self._frames = frames
        self._server = server
        self._studio = studio

    def apply(self, pipeline) -> None:
        """Apply the page input that arrived since the last frame (loop thread, before solving).

        Orbit, pan and zoom are merged into one camera change per camera; drags into one target
        per handle; picks and removals refactor the solver (a pattern switch). A refused input
        is told to the page that asked.
        """
        if not self._commands:
            return
        moves: dict[int, list] = {}
        drags: dict[int, tuple] = {}
        while self._commands:
            client, msg = self._commands.popleft()
            kind = msg["type"]
            try:
                if kind in ("orbit", "pan", "zoom"):
                    move = moves.setdefault(msg["camera"], [0.0, 0.0, 0.0, 0.0, 1.0])
                    if kind == "orbit":
                        move[0] += msg["dx"]
                        move[1] += msg["dy"]
                    elif kind == "pan":
                        move[2] += msg["dx"]
                        move[3] += msg["dy"]
                    else:
                        move[4] *= msg["factor"]
                elif kind == "drag":
                    handle = self._handles.held(client, msg["key"])
                    if handle is not None:
                        drags[handle] = (msg["camera"], msg["x"], msg["y"])
                    # else: a drag that started on the background (warned at its pick)
                else:
                    self._one(pipeline, client, kind, msg)
            except PuppetError as err:  # told to the page that asked
                self._server.warn(f"{kind}: {err}", client, f"{kind} refused")
                if kind == "pick":  # the page's pending drag becomes an orbit
                    self._server.send_to(client, {"type": "pick_miss", "key": msg["key"]})
        for camera_id, (dx, dy, px, py, zoom) in moves.items():
            self._cameras.move(camera_id, dx, dy, px, py, zoom)
        for handle_id, (camera_id, x, y) in drags.items():
            self._handles.drag(pipeline, handle_id, camera_id, x, y)

    def _one(self, pipeline, client: str, kind: str, msg: dict) -> None:
        if kind == "pick":
            self._handles.pick(pipeline, client, msg)
        elif kind == "grab":
            self._handles.grab(client, msg["key"], msg["handle"])
        elif kind == "remove":
            self._handles.remove(pipeline, msg["handle"])
        elif kind == "preset":
            self._cameras.preset(msg["camera"], msg["name"])
        elif kind == "reset":
            self._cameras.reset(msg["camera"])
        elif kind == "camera_mode":
            if msg["own"]:
                self._cameras.own(msg["camera"])
        elif kind == "left":
            if msg["camera"] != 0:
                self._cameras.drop(msg["camera"])
                self._key_poses.drop_camera(msg["camera"])
            self._handles.left(client)
        elif kind == "overlay":
            self._frames.overlay = msg["on"]
            self._server.send_to(None, {"type": "overlay", "on": self._frames.overlay})
        elif kind == "record":
            self._recording.set(msg["on"])
        elif kind == "marker":
            self._recording.mark(msg["name"])
        elif kind == "playback":
            self._playback.control(msg["action"], msg["value"])
        elif kind == "studio":
            if self._studio is None:
                raise PuppetError("the studio's controls need `puppet studio SESSION`")
            if msg.get("action") == "pick_joint":  # the bone under the click, for the desk
                msg = {**msg, "bone": self._handles.bone_at(pipeline, msg)
                       if self._studio.check_pick(msg) else None}
            self._studio.input(client, msg)
        elif kind in ("key", "key_edit", "retime", "onion", "playhead"):
            self._key_poses.input(client, kind, msg)
