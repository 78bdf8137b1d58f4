"""The page's panel: servo angles and their last faults, the loop's rate and the view's figures
(PANEL_HZ), the bus events as they come, and each camera's view of the bones and handles."""

from __future__ import annotations

from collections import deque

import numpy as np

from puppet.events import EVENT_KINDS
from puppet.view.handles import project
from puppet.view.protocol import PANEL_HZ

FAULTS_KEPT = 200         # bus events a late viewer still gets
LOOP_TIMES_KEPT = 240     # loop frame times for the rate (about 1 s at 240 fps)


def bone_legend() -> list[dict]:
    """The overlay's bone colours for the page: [{state, color ('#rrggbb', sRGB), words}]."""
    from puppet.render.overlay import BONE_STATE_COLORS, BONE_STATE_WORDS

    def srgb(c: float) -> int:
        c = 12.92 * c if c <= 0.0031308 else 1.055 * c ** (1 / 2.4) - 0.055
        return round(min(max(c, 0.0), 1.0) * 255)

    return [{"state": state, "color": "#" + "".join(f"{srgb(c):02x}" for c in rgb),
             "words": BONE_STATE_WORDS[state]}
            for state, rgb in BONE_STATE_COLORS.items() if state is not None]


SERVO_STATES = {
    "ok": "read this time",
    "late": "reply came late (busy computer): its last angle held, not a fault",
    "fault": "at fault (its last fault says why): its last angle held",
}
"""A servo's state on the page's servo table, and what it means; ``fault`` is also its bone's
state (puppet.render.overlay), a late servo's bone keeps its colour."""


def servo_state(ok: bool, fault: bool) -> str:
    """The key of SERVO_STATES for a servo read ``ok`` and at ``fault`` (Pipeline.fault)."""
    return "ok" if ok else "fault" if fault else "late"


def posed_bones(pipeline) -> np.ndarray:
    """(b, 2, 3) bone heads and tails moved by their handles."""
    seg = pipeline.bone_segments
    b = len(seg)
    blocks = pipeline.T.reshape(-1, 4, 3)[:b].astype(np.float64)
    homo = np.concatenate([seg, np.ones((b, 2, 1))], axis=2)
    return np.matmul(homo, blocks)


class Panel:
    """servo_ids, bone_names: the rig's; width, height: the frames [px]; view_proj: Camera ->
    (4, 4) world to clip as drawn; server: the ViewServer; lock: guards ``faults`` and the panel
    (read by snapshots); t0: monotonic time [s] the panel's times count from."""

    def __init__(self, servo_ids, bone_names, width: int, height: int, view_proj, server, lock, t0: float):
        self._servo_ids = list(servo_ids)
        self._bone_names = list(bone_names)
        self._width, self._height = width, height
        self._view_proj = view_proj
        self._server = server
        self._lock = lock
        self._t0 = t0
        self.faults: deque = deque(maxlen=FAULTS_KEPT)
        self._last_fault: dict[int, str] = {}
        self._events_seen = 0
        self._loop_times: deque = deque(maxlen=LOOP_TIMES_KEPT)
        self._next_panel = 0.0
        self.latest: dict = {"type": "panel"}
        self._camera_panels: dict[int, dict] = {}
        self._angles_deg = np.zeros(len(self._servo_ids))

    def tick(self, now: float) -> None:
        """One loop frame at monotonic time ``now`` [s] (the loop's rate)."""
        self._loop_times.append(now)

    def due(self, now: float) -> bool:
        """True when a panel is due (PANEL_HZ) and someone watches; then the next is scheduled."""
        if now >= self._next_panel and self._server.viewers:
            self._next_panel = now + 1.0 / PANEL_HZ
            return True
        return False

    def for_camera(self, camera: int) -> dict:
        """The newest panel, with the handles and bones as seen by ``camera``."""
        with self._lock:  # both from one update: its bones with its own figures
            latest, cams = self.latest, self._camera_panels
        return {**latest, **cams.get(camera, cams.get(0, {}))}

    def take_events(self, source_log) -> None:
        """The source's new bus events to every page (faults also as each servo's last fault)."""
        total = sum(source_log.counts.values())
        new = total - self._events_seen
        if new <= 0:
            return
        try:
            events = tuple(source_log.events)[-new:] if new <= len(source_log.events) else tuple(source_log.events)
        except RuntimeError:  # appended to while copying: next frame
            return
        self._events_seen = total
        for event in events:
            kind = EVENT_KINDS.get(event.kind)
            fault = kind is None or kind.fault
            item = {"t_s": round(event.t_ns / 1e9 - self._t0, 3), "kind": event.kind,
                    "ids": list(event.ids), "detail": event.detail[:200], "fault": fault,
                    "words": kind.words if kind is not None else event.kind}
            with self._lock:
                self.faults.append(item)
            if fault:  # "last fault" names faults only, in the puppeteer's words
                for servo in event.ids:
                    self._last_fault[int(servo)] = item["words"]
            self._server.send_to(None, {"type": "fault", **item})

    def update(self, pipeline, reading, now: float, *, frames: int, drops: int, recording: dict,
               playback: dict | None, refactor_ms: list[float], handles, cameras) -> None:
        """A new panel from the pipeline's pose and ``reading``, with the view's figures, and each
        camera's (``cameras``: {id: OrbitCamera}) projection of the bones and ``handles``."""
        np.degrees(pipeline.angles, out=self._angles_deg)
        times = self._loop_times
        recent = [t for t in times if now - t <= 1.0]
        loop_fps = (len(recent) - 1) / max(recent[-1] - recent[0], 1e-6) if len(recent) > 1 else 0.0
        servos = [{"id": sid, "deg": round(float(deg), 1), "ok": bool(ok),
                   "state": servo_state(ok, fault), "fault": self._last_fault.get(sid, "")}
                  for sid, deg, ok, fault in zip(self._servo_ids, self._angles_deg, reading.ok,
                                                 pipeline.fault)]
        panel = {"type": "panel", "t_s": round(now - self._t0, 2), "servos": servos,
                 "loop_fps": round(loop_fps, 1), "frames": frames, "drops": drops,
                 "recording": recording, "playback": playback,
                 "refactor_ms": round(refactor_ms[-1], 3) if refactor_ms else None}
        cams = {}
        posed = posed_bones(pipeline)
        targets = np.array([h.target for h in handles]).reshape(-1, 3)
        w, h = self._width, self._height
        for camera_id, orbit in list(cameras.items()):
            view_proj = self._view_proj(orbit.camera())
            ends = project(view_proj, w, h, posed.reshape(-1, 3)).reshape(-1, 2, 2)
            spots = project(view_proj, w, h, targets) if len(targets) else np.zeros((0, 2))
            cams[camera_id] = {
                "bones": [{"name": n, "state": s, "a": [round(float(a), 1) for a in e[0]],
                           "b": [round(float(b), 1) for b in e[1]]}
                          for n, s, e in zip(self._bone_names, pipeline.bone_states, ends)],
                "handles": [{"id": handle.id, "x": round(float(p[0]), 1), "y": round(float(p[1]), 1)}
                            for handle, p in zip(handles, spots)],
            }
        with self._lock:
            self.latest, self._camera_panels = panel, cams
