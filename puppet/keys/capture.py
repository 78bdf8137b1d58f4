"""Capturing key poses from the puppet: a key is the median of the readings over a hold window.

The puppeteer holds a pose and presses Enter; the key is taken from the readings of the next
``HOLD_S`` seconds (keep holding still that long): each servo's ticks are the median of its
good readings there (servo jitter does not enter the key), rounded to whole ticks. A key pressed
while a servo is flagged in most of that window (silent, out of range) is refused, naming it.

KeySession holds the shot being made and applies the puppeteer's commands (one line each):
    (empty)   a new key, ``step`` frames after the last one (the first lands on frame 1)
    r N       replace key N with the held pose (its frame and interpolation kept)
    d N       delete key N
    i F       insert a key with the held pose at frame F
    t N F     retime key N to frame F (``puppet.keys.shot.retime``: refused if keys would reorder)
    m N KIND  key N's interpolation (linear, smooth, step: how the frames after it are filled)
    m KIND    the interpolation of the keys taken from now on
    q         finish (end of input and Ctrl-C too)
After every change the shot is written whole (``puppet.keys.shot.write_shot``): a crash keeps
every key made before it.

KeyDesk takes those commands from any thread (the terminal's Enter, the live view's Space, Key
button, key buttons and timeline) and applies them in order on the loop's thread once each one's hold window
is over: one capture path whoever pressed.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import deque

import numpy as np

from puppet.errors import PuppetError
from puppet.keys.shot import insert_key, interpolate, remove_key, replace_key, retime, write_shot
from puppet.take import TakeError
from puppet.take.keys import Key, Keys, check_interpolation

HOLD_S = 0.2
"""Hold window after the key press, seconds: the key is the median of its readings."""
HOLD_NS = int(HOLD_S * 1e9)
KEPT_READINGS = 4096
"""Readings kept while waiting for a hold window to end (a bound, not a tuning)."""
WAITING_COMMANDS = 64
"""Commands a KeyDesk holds waiting for the loop (a bound: more are refused)."""
WINDOW_WAIT_NS = 10_000_000_000
"""Longest wait for a reading after the hold window (a stalled reader), ns; then the key is
taken from the readings there are (or refused when there are none)."""
QUIT_WAIT_NS = 2_000_000_000
"""After ``q`` (or end of input), how long the keys still in their hold window may wait for
their readings, all together, ns (ten hold windows: a reading bus answers in well under it);
then those not taken are dropped, each said, and the capture ends: q always ends it."""


class KeyRefused(PuppetError):
    """A key that cannot be taken (a flagged servo) or a command that cannot be applied."""


def held_pose(readings, press_ns: int, ids) -> tuple[np.ndarray, np.ndarray, int]:
    """(ticks (k,) int32, ok (k,) bool, readings used) of the readings with
    press_ns <= t_ns <= press_ns + HOLD_NS: each servo's median over its good readings there.

    KeyRefused naming the servos without a reading in more than half of the window: said as
    late replies (a busy host; press again) when every one missing was late, else as flagged
    (silent, out of range); a single missing reading does not refuse the key.
    """
    window = [r for r in readings if press_ns <= r.t_ns <= press_ns + HOLD_NS]
    if not window:
        raise KeyRefused("no reading in the hold window: is the bus reading?")
    ok = np.stack([r.ok for r in window])  # (w, k)
    bad = (~ok).sum(axis=0) * 2 > len(window)
    if bad.any():
        named = [int(i) for i in np.asarray(ids)[bad]]
        late = np.stack([r.late if r.late is not None else np.zeros_like(r.ok) for r in window])
        if (ok | late)[:, bad].all():
            raise KeyRefused(f"servo(s) {named}: their replies came late while holding (a busy "
                             "host, not a fault): key not taken; press again")
        raise KeyRefused(f"servo(s) {named} flagged (silent or out of range) while holding: "
                         "key refused; check them and press again")
    ticks = np.where(ok, np.stack([r.ticks for r in window]), np.nan)
    held = np.rint(np.nanmedian(ticks, axis=0)).astype(np.int32)
    return held, np.ones(len(held), bool), len(window)


class KeySession:
    """A shot being captured into ``path``.

    header: the shot's TakeWriter keywords (``puppet.take.header.take_header``). fps: the shot's frames
    per second; step: frames between a key and the next; interpolation: of every new key.
    keys: the shot's Keys so far. written: whether the shot file was written yet (at the
    first key taken; a session that takes none writes nothing).
    """

    def __init__(self, path, header: dict, *, fps: float, step: int,
                 interpolation: str = "linear"):
        self.path, self.header, self.step = path, header, int(step)
        self.interpolation = interpolation
        self.ids = np.asarray(header["ids"])
        self.keys = Keys(float(fps), [])
        self.readings: deque = deque(maxlen=KEPT_READINGS)
        self.written = False  # the shot file was written (a key was taken): nothing before

    def needs_pose(self, command: str) -> bool:
        """Whether ``command`` takes the held pose (a new, replaced or inserted key)."""
        word = command.split()[:1]
        return not word or word[0] in ("r", "i")

    def apply(self, command: str, press_ns: int | None = None) -> str:
        """Apply one command line (press_ns: when it was given, for those that take the pose);
        the shot is written; returns what happened, in words. KeyRefused / TakeError: refused,
        nothing changed."""
        parts = command.split()
        try:
            if not parts:
                ticks, ok, used = held_pose(self.readings, press_ns, self.ids)
                frame = self.keys.keys[-1].frame + self.step if self.keys.keys else 1
                new = insert_key(self.keys, Key(frame, ticks, ok, self.interpolation), self.path)
                said = f"key {new.keys[-1].id}: frame {frame} ({used} readings held)"
            elif parts[0] == "r" and len(parts) == 2:
                ticks, ok, used = held_pose(self.readings, press_ns, self.ids)
                index = int(parts[1])
                new = replace_key(self.keys, index, Key(0, ticks, ok), self.path)
                said = f"key {index}: replaced ({used} readings held)"
            elif parts[0] == "d" and len(parts) == 2:
                index = int(parts[1])
                new = remove_key(self.keys, index, self.path)
                said = f"key {index}: deleted ({len(new.keys)} keys left)"
            elif parts[0] == "t" and len(parts) == 3:
                index, frame = int(parts[1]), int(parts[2])
                new = retime(self.keys, {index: frame}, self.path)
                said = f"key {index}: retimed to frame {frame}"
            elif parts[0] == "i" and len(parts) == 2:
                ticks, ok, used = held_pose(self.readings, press_ns, self.ids)
                frame = int(parts[1])
                new = insert_key(self.keys, Key(frame, ticks, ok, self.interpolation), self.path)
                index = next(k.id for k in new.keys if k.frame == frame)
                said = f"key {index}: inserted at frame {frame} ({used} readings held)"
            elif parts[0] == "m" and len(parts) == 3:
                index = int(parts[1])
                new = interpolate(self.keys, {index: parts[2]}, self.path)
                said = f"key {index}: {parts[2]}"
            elif parts[0] == "m" and len(parts) == 2:
                self.interpolation = check_interpolation(parts[1], self.path)
                new = self.keys
                said = f"new keys: {parts[1]}"
            else:
                raise KeyRefused(f"unknown command {command.strip()!r}: Enter (a key), r N "
                                "(replace), d N (delete), i FRAME (insert), t N FRAME (retime), "
                                "m [N] linear|smooth|step (interpolation), q (finish)")
        except ValueError:
            raise KeyRefused(f"{command.strip()!r}: N and FRAME are whole numbers") from None
        if new is not self.keys:  # a change of the keys: the shot is written whole
            write_shot(self.path, self.header, new)
            self.written = True
        self.keys = new
        return said


class KeyDesk:
    """A KeySession's commands from any thread, applied in order on the loop's thread.

    press(command, origin) (any thread) queues a command line stamped with the time it was
    pressed (its hold window starts there); feed(readings) and step() (the loop's thread) hand
    the session the readings and apply every command whose hold window is over. tell: called
    with each outcome's words (the terminal's echo). Fields: session; version (counts changes
    of the keys); finished (a ``q`` was applied).
    """

    def __init__(self, session: KeySession, tell=None):
        self.session = session
        self.tell = tell
        self.version = 0
        self.finished = False
        self._commands: queue.Queue = queue.Queue(maxsize=WAITING_COMMANDS)
        self._pending = None  # (command, press_ns, origin) waiting for its hold window to end
        self._quit = threading.Event()  # q (or end of input) was pressed, at _quit_ns
        self._quit_ns = 0

    def press(self, command: str, origin=None) -> None:
        """Queue one command line (any thread); ``origin`` comes back with its outcome.
        ``q`` is never refused: it ends the capture at the next step, however many commands
        wait (those whose hold window is over are applied first, the others are dropped and
        said). KeyRefused when WAITING_COMMANDS wait already (the loop is stalled)."""
        if command.strip() == "q":
            if not self._quit.is_set():
                self._quit_ns = time.monotonic_ns()
                self._quit.set()
            return
        try:
            self._commands.put_nowait((command, time.monotonic_ns(), origin))
        except queue.Full:
            raise KeyRefused(f"{command.strip() or 'key'!r} refused: {WAITING_COMMANDS} commands "
                             "wait already (is the bus reading?)") from None

    def feed(self, readings) -> None:
        """The readings the loop drained (oldest first)."""
        self.session.readings.extend(readings)

    def step(self) -> list[tuple[object, bool, str]]:
        """Apply the commands whose hold window is over, in order; returns (origin, taken,
        words) per command applied (taken False: refused, words say why)."""
        outcomes = []
        session = self.session
        quitting = self._quit.is_set()
        give_up = quitting and time.monotonic_ns() - self._quit_ns >= QUIT_WAIT_NS
        if self._pending is None and self._commands.empty() and not quitting:
            return outcomes  # the loop's usual frame: nothing pressed
        while not self.finished:
            if self._pending is None:
                try:
                    self._pending = self._commands.get_nowait()
                except queue.Empty:
                    self.finished = quitting
                    break
            command, press_ns, origin = self._pending
            if session.needs_pose(command):
                latest = session.readings[-1].t_ns if session.readings else 0
                if latest <= press_ns + HOLD_NS and time.monotonic_ns() - press_ns < WINDOW_WAIT_NS:
                    if not give_up:
                        break  # the hold window is not over (after q: QUIT_WAIT_NS at most)
                    self._pending = None  # q waited long enough: this one is not taken
                    outcome = (origin, False, f"refused: {command.strip() or 'key'!r} not taken: "
                                              f"q ended the capture before its hold window "
                                              f"(no readings for {QUIT_WAIT_NS / 1e9:g} s)")
                    if self.tell is not None:
                        self.tell(*outcome)
                    outcomes.append(outcome)
                    continue
            self._pending = None
            try:
                outcome = (origin, True, session.apply(command, press_ns))
                self.version += 1
            except (KeyRefused, TakeError) as err:
                outcome = (origin, False, f"refused: {err}")
            if self.tell is not None:
                self.tell(*outcome)
            outcomes.append(outcome)
        return outcomes

    @property
    def busy(self) -> bool:
        """A command waits (queued or in its hold window)."""
        return self._pending is not None or not self._commands.empty()


__all__ = ["HOLD_S", "KeyDesk", "KeyRefused", "KeySession", "TakeError", "held_pose"]
