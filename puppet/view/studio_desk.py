"""The studio on the page (``puppet studio``): the session folder's shots and numbered takes,
the page's studio commands (shots, record with a count-in, circle, note, lock, trash, review,
segments, export) applied through the one writer (``puppet.studio.SessionWriter``), and the
session's listing sent to every page after each change.

Recording goes through the view's Recording part: ``new_take_path`` gives the path, the take is
written by the session's take recorder (``puppet.session.outputs._TakeFromZero``: readings from
the count-in's end, the sound's reference, the start timecode) and ``recorded`` lists it as
take N of the current shot the moment it is closed. "Record a layer" (``record_layer``: a take
of the shot as its base, the layer's joints) is the same recording with the parts of ``puppet
live --over``: the base checked and held by ``puppet.session.layers.LayerPlan``, the live
readings shown over it (``SwitchedReadings.over``: the base from the same count-in, on the
page), the take written by ``layer_recorder`` (raw readings, the layer record): the next take
of the shot is a layer over its base. The studio's bus reader drives nothing (no cycle hook):
on a rig that can drive, the bus is handed to the layer's source for the
take (``Switchable.layer``: the base's servos driven, torque on, as ``live --over`` drives them;
torque off, read back, when the take ends); elsewhere the base plays on the page, said. Review switches the session's source
(``puppet.session.sources.SwitchedReadings``) between the bus and a take on the wall clock.
"""

from __future__ import annotations

import logging
import math
import subprocess
import sys
import threading
import time
from pathlib import Path

from puppet import limits
from puppet.errors import PuppetError

log = logging.getLogger("puppet.view")

#: A clip's file suffix per format (``puppet export``'s options).
CLIP_SUFFIX = {"gltf": ".glb", "usd": ".usdc", "pc2": ".pc2", "bvh": ".bvh"}
#: The page's studio actions: action -> {field: check}.
EXPORT_FORMATS = ("gltf", "usd", "pc2", "bvh", "mp4")
MAX_COUNT_IN_S = 10.0
COMPARE_STEP_S = 1.0 / 15.0
"""The compared take's ghost follows the play position in steps this long (s): a ghost is a
cold solve and two renders, so a playing review re-solves it at most this often."""
SOUNDS = "sounds"
"""The session's folder of sounds to choose from on the page (put there by a person)."""
KEY_FPS = 24.0
"""A keyed shot's frame rate (``puppet keys``' default)."""
KEY_STEP = 12
"""Frames from one key to the next (``puppet keys``' default)."""
WAVEFORM_BARS = 2000
"""The sound's waveform on the page: this many (min, max) pairs over its length."""
REFRESH_S = 1.0
"""How often the take files are looked at (s): one removed behind the studio's back is listed
as missing within this long."""


def _text(v) -> bool:
    return isinstance(v, str) and len(v) <= 200


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _take(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 100_000


ACTIONS = {
    "new_shot": {"name": _text},
    "rename_shot": {"shot": _text, "name": _text},
    "use_shot": {"shot": _text},
    "record": {"count_in": lambda v: _number(v) and 0 <= v <= MAX_COUNT_IN_S},
    "record_layer": {"count_in": lambda v: _number(v) and 0 <= v <= MAX_COUNT_IN_S,
                     "shot": _text, "take": _take,
                     "joints": lambda v: isinstance(v, list) and 0 < len(v) <= 200
                     and all(_text(j) for j in v)},
    "pick_joint": {"x": _number, "y": _number, "seq": lambda v: isinstance(v, int),
                   "bone": lambda v: v is None or isinstance(v, int)},
    "stop": {},
    "note": {"shot": _text, "take": _take, "text": lambda v: isinstance(v, str)},
    "circle": {"shot": _text, "take": _take, "on": lambda v: isinstance(v, bool)},
    "lock": {"shot": _text, "take": _take, "on": lambda v: isinstance(v, bool)},
    "delete": {"shot": _text, "take": _take},
    "restore": {"shot": _text, "take": _take},
    "review": {"shot": _text, "take": _take},
    "live": {},
    "compare": {"shot": _text, "take": _take},
    "compare_off": {},
    "sound": {"name": _text},
    "keys_start": {},
    "keys_done": {},
    "segment": {"shot": _text, "take": _take, "name": _text, "in_s": _number,
                "out_s": _number, "loop": lambda v: isinstance(v, bool)},
    "export": {"scope": lambda v: v in ("take", "circled"),
               "formats": lambda v: isinstance(v, list) and 0 < len(v) <= len(EXPORT_FORMATS)
               and all(f in EXPORT_FORMATS for f in v),
               "fps": lambda v: v is None or (_number(v) and limits.FPS.problem(v) is None),
               "keys": lambda v: v is None or (_number(v) and limits.KEYS_DEG.problem(v) is None)},
}


def check_action(message: dict) -> str | None:
    """None when a ``studio`` message is well formed, else what is wrong with it."""
    action = message.get("action")
    fields = ACTIONS.get(action)
    if fields is None:
        return f"studio: unknown action {action!r}"
    for name, ok in fields.items():
        if name not in message or not ok(message[name]):
            return f"studio {action}: field {name!r} missing or invalid"
    return None


def _stored_sound(path):
    """The take's stored sound reference (puppet.take.sync.SoundRef), or None."""
    from puppet.take import TakeReader

    return TakeReader(path).metadata.sound


def _file_part(name: str) -> str:
    """A clip's name as part of a file name (letters, digits, - and _ kept)."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)[:60] or "clip"


class StudioDesk:
    """writer: the open SessionWriter (its lock held for the session's life); rig: the
    session's rig; open_take(path, zero_ns): the take recorder of the session (count-in end at
    ``zero_ns``); tell: where notes are said (stderr)."""

    def __init__(self, writer, rig, *, open_take, tell=print):
        self.writer = writer
        self.rig = rig
        self._open_take = open_take
        self.tell = tell
        self.said = None            # the newest outcome: {"ok": bool, "text": str}
        self.reviewing = None       # {"shot": key, "take": n} while a take is shown
        self.export = None          # {"running", "done", "total", "text", "outputs"}
        self._server = None
        self._source = None
        self._recording = None
        self._export_thread: threading.Thread | None = None
        self.comparing = None       # {"shot": key, "take": n}: its ghost over the reviewed take
        self.sound = None           # the shot's sound for the page (``use_sound``)
        self.performed_to = (None, 0.0)  # (puppet.sound Sound, offset_s) the takes store
        self.sound_path: Path | None = None  # served to the page (Web Audio)
        self.keying: Path | None = None  # the take being key-posed (a shot of keys), or None
        self._compare = None        # its Playback
        self._compare_at = None     # the play position its ghost shows (s)
        self._shown = None          # the listing the pages were last sent
        self.layering = None        # {"shot", "take", "joints"}: the layer being recorded
        self._layer = None          # its puppet.session.layers.LayerPlan
        self._client = None         # the page whose input is being applied
        self.switch = None          # the session's Switchable source (its bus for a layer)
        self._looked = 0.0          # when the take files were last looked at (monotonic s)

    def attach(self, server, source, recording, key_poses) -> None:
        """server: the ViewServer; source: the loop's reading source (SwitchedReadings);
        recording: the view's Recording part; key_poses: its KeyPoses (the compare ghost)."""
        self._server = server
        self._source = source
        self._recording = recording
        self._key_poses = key_poses

    def use_sound(self, sound, offset_s: float) -> None:
        """The sound takes are performed to (a puppet.sound Sound, its time at each take's
        time 0): its waveform (WAVEFORM_BARS min/max pairs of the channels' mean) and the file,
        played by the page from the take's time 0 (after the count-in), in review and scrubbing."""
        import numpy as np

        self.performed_to = (sound, float(offset_s))
        mono = sound.samples.mean(axis=1) if sound.samples.ndim == 2 else sound.samples
        bars = max(1, min(WAVEFORM_BARS, len(mono)))
        edges = np.linspace(0, len(mono), bars + 1).astype(np.int64)
        lows = np.minimum.reduceat(mono, edges[:-1])
        highs = np.maximum.reduceat(mono, edges[:-1])
        self.sound_path = Path(sound.path)
        self.sound = {"name": sound.name, "offset_s": float(offset_s),
                      "duration_s": sound.frames / sound.rate, "rate": sound.rate,
                      "sha256": sound.sha256,
                      "peaks": [[round(float(a), 3), round(float(b), 3)]
                                for a, b in zip(lows, highs)]}

    def _sound_files(self) -> list[str]:
        """The sound files a person put in the session's sounds/ folder (to choose on the page)."""
        from puppet.sound import SUFFIXES

        folder = self.writer.folder / SOUNDS
        try:
            return sorted(p.name for p in folder.iterdir()
                          if p.is_file() and p.suffix.lower() in SUFFIXES)
        except OSError:
            return []

    def _sound(self, m) -> None:
        """The shot's sound: a file of the session's sounds/ ("": none); the takes recorded
        from now on store its reference."""
        from puppet.sound import load_sound

        if self._recording.state()["on"]:
            raise PuppetError("stop recording first to change the sound")
        if m["name"] == "":
            self.sound, self.sound_path, self.performed_to = None, None, (None, 0.0)
            self._say("no sound: the next takes are silent")
            return
        if m["name"] not in self._sound_files():
            raise PuppetError(f"{self.writer.folder / SOUNDS}: no sound file {m['name']!r} "
                              "(put WAV, FLAC, OGG or MP3 files there)")
        sound = load_sound(self.writer.folder / SOUNDS / m["name"])  # refused naming the file
        self.use_sound(sound, 0.0)
        self._say(f"sound {sound.name}: heard from each take's time 0; its waveform under "
                  "the timeline")

    # ---- what the page shows ----
    def state(self) -> dict:
        listing = self.writer.listing()
        return {**listing, "said": self.said, "reviewing": self.reviewing,
                "comparing": self.comparing, "sound": self.sound,
                "sounds": self._sound_files(), "keying": self.keying is not None,
                "export": self.export, "rig": self.rig.name, "layering": self.layering,
                "joints": self._joints()}

    def _joints(self) -> list[str]:
        """The rig's joints with a sensor servo: what a layer can hold (rig order)."""
        names: list[str] = []
        for servo in self.rig.servo_map.servos:
            if servo.role == "sensor" and servo.joint not in names:
                names.append(servo.joint)
        return names

    def _send(self) -> None:
        if self._server is not None:
            state = self.state()
            self._shown = (state["shots"], state["sounds"])
            self._server.send_to(None, {"type": "studio", **state})

    def follow(self) -> None:
        """Each frame (the loop thread): the compared take's ghost at the reviewed take's play
        position (in COMPARE_STEP_S steps)."""
        if self._compare is None:
            return
        position = self._source.position_s
        if position is None:
            return
        at = round(position / COMPARE_STEP_S) * COMPARE_STEP_S
        if at != self._compare_at:
            self._compare_at = at
            self._key_poses.compare(self._compare.at(min(at, self._compare.duration_s)))

    def refresh(self, now: float) -> None:
        """Every REFRESH_S (the loop thread): the pages are sent the listing again when a take
        file changed behind the studio's back (removed: listed as missing) or a sound file
        came into sounds/."""
        if now - self._looked < REFRESH_S or self._server is None:
            return
        self._looked = now
        if (self.writer.listing()["shots"], self._sound_files()) != self._shown:
            self._send()

    def _say(self, text: str, ok: bool = True) -> None:
        self.said = {"ok": ok, "text": text}
        log.info("studio: %s", text)

    # ---- recording (the Recording part calls these) ----
    def new_take(self, count_in_s: float):
        """(path, recorder) of the current shot's next take, its time 0 after ``count_in_s``."""
        if self.writer.current_shot is None:
            self.writer.new_shot(self.writer._first_shot_name())
        path = self.writer.new_take_path()  # a read-only or full disk fails here, naming it
        plan = self._layer
        if plan is None:
            zero_ns = time.monotonic_ns() + int(count_in_s * 1e9)
            return path, self._open_take(path, zero_ns)
        from puppet.session.layers import layer_recorder

        self.switch.layer(plan, tell=self.tell)  # a base driven: the bus handed over (waits)
        zero_ns = time.monotonic_ns() + int(count_in_s * 1e9)
        plan.from_ns = zero_ns  # the base starts where the take does
        return path, layer_recorder(plan, path, zero_ns=zero_ns, from_ns=zero_ns)

    def recorded(self, path: Path) -> None:
        """The take at ``path`` was closed: listed as take N of its shot (nothing recorded:
        no file, said)."""
        layer, self.layering, self._layer = self.layering, None, None
        if layer is not None:
            self.switch.unlayer(tell=self.tell)  # a driven base: torque off, read back, said
        if not Path(path).is_file():
            self._say(f"nothing recorded (stopped during the count-in): no take", ok=False)
        else:
            take = self.writer.add_take(path)
            shot = self.writer.index.shot(Path(path).parent.name)
            over = "" if layer is None else \
                f": a layer of {', '.join(layer['joints'])} over take {layer['take']}"
            self._say(f"recorded {shot.name} take {take.number} ({take.duration_s or 0:.1f} s)"
                      + over)
        self._send()

    def failed(self, path: Path, err) -> None:
        """The take at ``path`` failed while recording (the Recording part dropped it): a
        layer's base stops (torque off, read back, said), the failure said."""
        layer, self.layering, self._layer = self.layering, None, None
        if layer is not None:
            self.switch.unlayer(tell=self.tell)
        self._say(f"recording stopped: {err}", ok=False)
        self._send()

    # ---- page input (the loop thread) ----
    def check_pick(self, message: dict) -> bool:
        """A ``pick_joint`` message's click is well formed (``PageInput`` then finds its bone)."""
        return check_action({**message, "bone": None}) is None

    def input(self, client: str, message: dict) -> None:
        problem = check_action(message)
        if problem is not None:
            raise PuppetError(problem)
        action = message["action"]
        self._client = client
        try:
            getattr(self, "_compare_take" if action == "compare" else f"_{action}")(message)
        except PuppetError as err:
            self._say(str(err), ok=False)
            self._send()
            raise
        self._send()

    def _new_shot(self, m) -> None:
        shot = self.writer.new_shot(m["name"])
        self._say(f"new shot {shot.name!r}: the next take goes there")

    def _rename_shot(self, m) -> None:
        old = self.writer.shot(m["shot"]).name
        shot = self.writer.rename_shot(m["shot"], m["name"])
        self._say(f"shot {old!r} is now {shot.name!r}")

    def _use_shot(self, m) -> None:
        shot = self.writer.use_shot(m["shot"])
        self._say(f"shot {shot.name!r}: the next take goes there")

    def _keys_start(self, m) -> None:
        """Key poses (``puppet keys --view``'s mode, on this page): the current shot's next take
        is a shot of keys (Space or the key button takes the held pose), written after each
        key; ``keys_done`` lists it."""
        from puppet.keys.capture import KeyDesk, KeySession
        from puppet.take.header import take_header

        if self._recording.state()["on"]:
            raise PuppetError("stop recording first to take key poses")
        if self.keying is not None:
            raise PuppetError("key poses are being taken already: press done first")
        self._live(m)
        if self.writer.current_shot is None:
            self.writer.new_shot(self.writer._first_shot_name())
        path = self.writer.new_take_path()
        header = take_header(self.rig)
        sound, offset_s = self.performed_to
        if sound is not None:
            from puppet.sound import sound_ref

            header["sound"] = sound_ref(sound, offset_s)
        self._key_poses.keys = KeyDesk(KeySession(path, header, fps=KEY_FPS, step=KEY_STEP))
        self._key_poses.onion = True
        self.keying = path
        self._key_poses._send()
        self._say(f"key poses for {self.writer.current_shot.name!r}: hold a pose, press Space "
                  "(or key); done lists them as a take")

    def _keys_done(self, m) -> None:
        if self.keying is None:
            raise PuppetError("no key poses are being taken")
        path, self.keying = self.keying, None
        desk, self._key_poses.keys = self._key_poses.keys, None
        self._key_poses.onion = False
        self._key_poses.version += 1
        if not path.is_file():
            self._say("no key taken: no take", ok=False)
            return
        take = self.writer.add_take(path)
        keys = len(desk.session.keys.keys)
        self._say(f"keyed {self.writer.current_shot.name} take {take.number} ({keys} keys)")

    def _record(self, m) -> None:
        if self.keying is not None:
            raise PuppetError("key poses are being taken: press done first, then record")
        self._live(m)
        self._recording.set(True, count_in_s=float(m["count_in"]))
        self._say(f"recording into {self.writer.current_shot.name!r} after a count-in of "
                  f"{m['count_in']:g} s")

    def _record_layer(self, m) -> None:
        """The next take of the base's shot, a layer of ``joints`` over its take ``take``: the
        base plays on the page from the count-in's end while the joints are read (refusals
        name the joint, the take or both rigs: ``LayerPlan.make``)."""
        from puppet.session.layers import LayerPlan

        if self.keying is not None:
            raise PuppetError("key poses are being taken: press done first, then record")
        if self._recording.state()["on"]:
            raise PuppetError("stop recording first to record a layer")
        shot, take = self.writer.take(m["shot"], m["take"])
        status = self.writer.status(shot, take)
        if status != "ok":
            raise PuppetError(f"shot {shot.name!r} take {take.number} is {status}: no base to "
                              "record a layer over")
        plan = LayerPlan.make(self.rig, self.writer.path(shot, take), joints=m["joints"])
        plan.tell = self._layer_note
        for note in plan.notes:
            self._layer_note(f"note: {note}")
        self._live(m)
        self.writer.use_shot(shot.key)
        self._layer = plan
        self.layering = {"shot": shot.key, "take": take.number, "joints": list(m["joints"])}
        try:
            self._recording.set(True, count_in_s=float(m["count_in"]))
        except BaseException:
            self._layer = self.layering = None
            self.switch.unlayer(tell=self.tell)
            raise
        where = ("on the page and on the motors (its servos driven, torque on)" if plan.drive
                 else "on the page")
        self._say(f"recording a layer of {', '.join(m['joints'])} over {shot.name} take "
                  f"{take.number} after a count-in of {m['count_in']:g} s: the base plays {where}")

    def _pick_joint(self, m) -> None:
        """A click on the figure picks the layer's joint there (the page that clicked ticks or
        unticks it): the joint with a servo of the bone under the click, or of the nearest bone
        above it (a hand picks its forearm)."""
        bone = m["bone"]
        if bone is None:
            raise PuppetError("no joint there: click on the figure to pick a layer's joint")
        skeleton = self.rig.skeleton
        joints = self._joints()
        at = bone
        while at >= 0 and skeleton.names[at] not in joints:
            at = int(skeleton.parents[at])
        if at < 0:
            raise PuppetError(f"bone {skeleton.names[bone]!r} has no joint with a servo (nor "
                              "any bone above it): pick another")
        joint = skeleton.names[at]
        self._server.send_to(self._client, {"type": "layer_joint", "joint": joint})
        self._say(f"joint {joint} picked for the layer (click it again to drop it)")

    def _layer_note(self, text: str) -> None:
        """A layer's note (its base's end, the layers it composes): said on the page (and in
        the log, on stderr)."""
        self._say(text.removeprefix("note: "))
        self._send()

    def _stop(self, m) -> None:
        self._recording.set(False)  # recorded() says the take

    def _note(self, m) -> None:
        take = self.writer.note(m["shot"], m["take"], m["text"])
        self._say(f"take {take.number}: note saved")

    def _circle(self, m) -> None:
        take = self.writer.circle(m["shot"], m["take"], m["on"])
        self._say(f"take {take.number} {'circled' if m['on'] else 'uncircled'}")

    def _lock(self, m) -> None:
        take = self.writer.lock_take(m["shot"], m["take"], m["on"])
        self._say(f"take {take.number} {'locked: read-only' if m['on'] else 'unlocked'}")

    def _delete(self, m) -> None:
        if self._reviewed(m):
            self._live(m)
        take = self.writer.delete(m["shot"], m["take"])
        self._say(f"take {take.number} moved into the session's trash (restore brings it back)")

    def _restore(self, m) -> None:
        take = self.writer.restore(m["shot"], m["take"])
        self._say(f"take {take.number} restored from the trash")

    def _reviewed(self, m) -> bool:
        shot = self.writer.shot(m["shot"])
        r = self.reviewing
        return r is not None and (r["shot"], r["take"]) == (shot.key, m["take"])

    def _playback(self, m):
        """(shot, take, path, Playback) of a take to review or compare, checked."""
        from puppet.take import Playback, TakeReader

        shot, take = self.writer.take(m["shot"], m["take"])
        status = self.writer.status(shot, take)
        if status != "ok":
            raise PuppetError(f"shot {shot.name!r} take {take.number} is {status}: nothing to play")
        path = self.writer.path(shot, take)
        reader = TakeReader(path)
        if len(reader) == 0:
            raise PuppetError(f"{path}: the take holds no readings")
        reader.check_rig([int(i) for i in self.rig.servo_map.ids],
                         dict(self.rig.servo_map.models), rig_name=self.rig.name)
        return shot, take, path, Playback.of_take(reader, self.rig.servo_map.ids, rig=self.rig)

    def _review(self, m) -> None:
        from puppet.take.markers import read_markers

        if self._recording.state()["on"]:
            raise PuppetError("stop recording first to review a take")
        shot, take, path, playback = self._playback(m)
        marks = [(playback.play_s(t), name) for t, name in read_markers(path)]
        self._source.review(playback, markers=marks)
        stored = _stored_sound(path)
        self.reviewing = {"shot": shot.key, "take": take.number,
                          "sound_offset_s": None if stored is None else stored.offset_s}
        self._say(f"reviewing {shot.name} take {take.number}: play, pause, scrub, speed")

    def _compare_take(self, m) -> None:
        if self.reviewing is None:
            raise PuppetError("review a take first, then compare another with it")
        shot, take, _, playback = self._playback(m)
        if (self.reviewing["shot"], self.reviewing["take"]) == (shot.key, take.number):
            raise PuppetError(f"take {take.number} is the one reviewed: compare another take")
        self._compare, self._compare_at = playback, None
        self.comparing = {"shot": shot.key, "take": take.number}
        self._say(f"comparing {shot.name} take {take.number} (magenta ghost) with take "
                  f"{self.reviewing['take']}")

    def _compare_off(self, m) -> None:
        self._compare = self.comparing = None
        self._key_poses.compare(None)
        self._say("compare off")

    def _live(self, m) -> None:
        if self.comparing is not None:
            self._compare_off(m)
        self._source.live()
        if self.reviewing is not None:
            self.reviewing = None
            self._say("live: the puppet")

    def _segment(self, m) -> None:
        segment = self.writer.add_segment(m["shot"], m["take"], m["name"], m["in_s"],
                                          m["out_s"], loop=m["loop"])
        kind = "loop" if segment.loop else "clip"
        self._say(f"take {m['take']}: {kind} {segment.name!r} {segment.in_s:.2f}-"
                  f"{segment.out_s:.2f} s")

    # ---- export (a `puppet batch` of the session's takes, beside the loop) ----
    def _export(self, m) -> None:
        """Export the chosen take, or the circled takes as a batch (``puppet batch SESSION
        --circled``), into the session's exports/ (exports/<shot>/take003.glb), then each of
        their clips as files of their own (exports/<shot>/take003.<clip>.glb, a loop blended);
        run beside the loop, its progress sent to the pages."""
        if self._export_thread is not None and self._export_thread.is_alive():
            raise PuppetError("an export is running: wait for it to finish")
        folder = self.writer.folder
        formats = [f for f in m["formats"]]
        if m["scope"] == "circled":
            chosen, _ = self.writer.chosen(circled=True)
            if not chosen:
                raise PuppetError(f"{folder}: no circled takes to export (circle one first)")
            batch = ["batch", str(folder), "--circled"]
            what = f"{len(chosen)} circled take(s)"
        else:
            if not (_text(m.get("shot")) and _take(m.get("take"))):
                raise PuppetError("studio export: field 'shot' or 'take' missing or invalid")
            shot, take = self.writer.take(m["shot"], m["take"])
            status = self.writer.status(shot, take)
            if status != "ok":
                raise PuppetError(f"shot {shot.name!r} take {take.number}: nothing to export "
                                  f"({status})")
            chosen = [(shot, take, self.writer.path(shot, take))]
            batch = ["batch", str(chosen[0][2]), "--out", str(folder / "exports" / shot.key)]
            what = f"{shot.name} take {take.number}"
        from puppet.studio.exports import recorded_fps

        fps = m["fps"] if m["fps"] is not None else recorded_fps([p for _, _, p in chosen])
        rate = [] if fps is None else ["--fps", f"{fps:g}"]
        keys = [] if m["keys"] is None else ["--keys", f"{m['keys']:g}"]
        jobs = [[*batch, "--formats", ",".join(formats), "--workers", "1", *rate, *keys]]
        for shot, take, path in chosen:
            for segment in take.segments:
                out = folder / "exports" / shot.key
                stem = f"{path.stem}.{_file_part(segment.name)}"
                files = [item for f in formats if f in CLIP_SUFFIX
                         for item in (f"--{f}", str(out / f"{stem}{CLIP_SUFFIX[f]}"))]
                if files:
                    jobs.append(["export", str(path), "--clip", f"{segment.in_s!r}",
                                 f"{segment.out_s!r}", *(["--loop"] if segment.loop else []),
                                 *files, *rate, *keys])
        self.export = {"running": True, "done": 0, "total": len(jobs), "ok": None,
                       "text": f"exporting {what} as {', '.join(formats)}…"}
        self._say(self.export["text"])
        self._export_thread = threading.Thread(target=self._run_export, args=(jobs, what),
                                               name="studio-export", daemon=True)
        self._export_thread.start()

    def _run_export(self, jobs: list[list[str]], what: str) -> None:
        export = dict(self.export)
        for n, args in enumerate(jobs):
            if args[0] == "export":
                for i, item in enumerate(args):
                    if item in ("--gltf", "--usd", "--pc2", "--bvh"):
                        Path(args[i + 1]).parent.mkdir(parents=True, exist_ok=True)
            command = [sys.executable, "-c", "from puppet.cli import main; main()", *args]
            proc = subprocess.run(command, capture_output=True, text=True)
            if proc.returncode != 0:
                err = (proc.stderr.strip().splitlines() or ["failed"])[-1]
                export.update(running=False, ok=False,
                              text=f"export of {what} failed: {err}")
                break
            export["done"] = n + 1
            self.export = dict(export)
            self._send()
        else:
            clips = len(jobs) - 1
            export.update(running=False, ok=True,
                          text=f"exported {what}" + (f" and {clips} clip(s)" if clips else "")
                          + f" into {self.writer.folder / 'exports'}")
        self.export = export
        self._say(export["text"], ok=bool(export["ok"]))
        self._send()

    def close(self) -> None:
        thread = self._export_thread
        if thread is not None:
            thread.join(timeout=600)
