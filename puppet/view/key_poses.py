"""Key poses on the page (``puppet keys --view``): the shot's keys as a timeline, Space and the
Key button, key edits and retimes sent to the KeyDesk, and the previous and next key drawn as
onion skins around the playhead."""

from __future__ import annotations

from puppet.errors import PuppetError
from puppet.view.server import KEY_EDITS


class KeyPoses:
    """keys: a ``puppet.keys.capture.KeyDesk``, or None (every key input is refused).

    ``onion``: ghosts shown; ``playhead``: the onion skins' frame (None: where the next key
    lands); ``version``: counts changes of what the onion skins show.
    """

    def __init__(self, keys, *, ghosts: bool = False):
        self.keys = keys
        self.onion = keys is not None
        self.ghosts = ghosts or keys is not None  # onion skins drawn (keys, or the studio's compare)
        self.compare_pose = None  # a Reading shown as the compared take's ghost (studio)
        self.playhead: int | None = None
        self.version = 0
        self._said = None         # the last key command's outcome: (taken, words)
        self._skins = None
        self._ghosts = (-1, None, [])  # (onion version, what they show, [(T, rgb)])
        self._server = None

    def attach(self, rig, width: int, height: int, renderer, picker, server) -> None:
        """Start drawing for a view of width x height [px] frames of ``renderer``."""
        self._server = server
        self._renderer = renderer
        self._picker = picker
        if self.ghosts:
            from puppet.view.onion import OnionSkins

            self._skins = OnionSkins(rig, width, height)

    @property
    def shown(self) -> bool:
        """True when the frames get onion skins."""
        return self._skins is not None and (self.compare_pose is not None
                                            or (self.onion and self.keys is not None))

    def compare(self, reading) -> None:
        """Show ``reading`` (another take at the reviewed take's play position) as a ghost over
        the frames; None: no compare ghost (loop thread)."""
        if reading is None and self.compare_pose is None:
            return
        self.compare_pose = reading
        self.version += 1
        if self._skins is not None and reading is not None:
            self._skins.forget([reading])

    def state(self) -> dict | None:
        """The shot's keys for the page's timeline and its key controls (None: no keys)."""
        if self.keys is None:
            return None
        session = self.keys.session
        keys = session.keys.keys
        next_frame = keys[-1].frame + session.step if keys else 1
        said = self._said
        return {"fps": session.keys.fps, "step": session.step, "next_frame": next_frame,
                "interpolation": session.interpolation,
                "keys": [{"index": k.id, "frame": k.frame, "interpolation": k.interpolation}
                         for k in keys],
                "playhead": self.playhead if self.playhead is not None else next_frame,
                "onion": self.onion, "path": str(session.path),
                "said": said[1] if said else None, "taken": said[0] if said else None}

    def _send(self) -> None:
        self.version += 1
        self._server.send_to(None, {"type": "keys", **self.state()})

    def input(self, client: str, kind: str, msg: dict) -> None:
        """Page input for the keys: a key (Space, Key button), a key edit (replace, delete,
        insert, interpolation: ``server.KEY_EDITS``) or a retime (a dragged tick) go to the
        KeyDesk as the terminal's command lines; onion skins and their frame stay in the view."""
        if self.keys is None:
            raise PuppetError("keys need 'puppet keys ... --view'")
        if kind == "key":
            self.keys.press("", client)
        elif kind == "key_edit":
            self.keys.press(KEY_EDITS[msg["action"]].format(**msg), client)
        elif kind == "retime":
            self.keys.press(f"t {msg['index']} {msg['frame']}", client)
        elif kind == "onion":
            self.onion = msg["on"]
            self._send()
        else:
            self.playhead = msg["frame"]
            self._send()

    def feed(self, batch) -> None:
        """The loop's readings to the KeyDesk, and the outcome of the commands it applied told
        to every page (a refusal also as a notice to the page that asked)."""
        desk = self.keys
        if desk is None:
            return
        desk.feed(batch)
        version = desk.version
        outcomes = desk.step()
        if not outcomes:
            return
        for origin, taken, words in outcomes:
            self._said = (taken, words)
            if not taken and isinstance(origin, str):
                self._server.warn(words, origin, "key refused")
        if desk.version != version and self._skins is not None:
            self._skins.forget(desk.session.keys.keys)
        self._send()

    def drop_camera(self, camera_id: int) -> None:
        if self._skins is not None:
            self._skins.drop_camera(camera_id)

    def draw_over(self, buffer, camera_id: int, orbit, camera) -> None:
        """Draw the previous and next key's ghosts (around the playhead) over ``buffer``."""
        from puppet.view.onion import NEXT_RGB, PREVIOUS_RGB, neighbours, pose_id

        onion = self._skins
        if self._ghosts[0] != self.version and self.compare_pose is not None:
            from puppet.view.onion import COMPARE_RGB

            pose = self.compare_pose
            self._ghosts = (self.version, (pose_id(pose), COMPARE_RGB),
                            [(onion.ghost_T(pose), COMPARE_RGB)])
        elif self._ghosts[0] != self.version:  # once per change: solved, cached by pose
            state = self.state()
            previous, following = neighbours(self.keys.session.keys.keys, state["playhead"])
            chosen = [(key, rgb) for key, rgb in ((previous, PREVIOUS_RGB), (following, NEXT_RGB))
                      if key is not None]
            self._ghosts = (self.version, tuple((pose_id(k), rgb) for k, rgb in chosen),
                            [(onion.ghost_T(k), rgb) for k, rgb in chosen])
        _, shown, ghosts = self._ghosts
        if not ghosts:
            return
        renderer = self._renderer

        def draw(T):
            own = renderer.camera
            if camera is not own:
                renderer.camera = camera
            try:
                renderer.draw(T, out=onion.shade)
            finally:
                if camera is not own:
                    renderer.camera = own
            return onion.shade, self._picker.coverage(T, camera, onion.cover)

        layer = onion.layer(camera_id, (orbit.version, shown), ghosts, draw)
        onion.apply(buffer, layer)

    def close(self) -> None:
        if self._skins is not None:
            self._skins.close()
