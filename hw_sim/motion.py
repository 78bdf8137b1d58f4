"""Motion sources: where each servo's shaft is (encoder counts, continuous) at time t (s).

A MotionSource has ``position(joint: int, t: float) -> float``; ``t`` is seconds since the bus
started, ``joint`` the id the servo was created with. Positions are continuous counts
(4096 per turn) and may leave 0..4095 (the servo then counts past the wrap).

- ``Hold``: every joint still (2048 unless told otherwise).
- ``Programmatic``: positions set by tests (``SimBus.set_positions``).
- ``Wave`` / ``Walk`` / ``Spin``: built-in performances.
- ``WithinLimits``: every servo of a rig swings across its own joint range, centre ± 0.35 × span
  (``hw-sim --rig``'s default motion).
- ``OneAtATime``: a person following ``puppet calibrate --guided``: each servo in turn is turned
  the way calibrate asks (its joint's positive direction, or the negative one when the limits
  leave more room there), held and brought back (``hw-sim --motion guided``).
- ``Keyframes``: linear interpolation of a keyframe file, looping.
- ``Replay``: sample-and-hold replay of recorded ticks: a puppet take (.mcap), or CSV / NPZ.

Keyframe / replay CSV format (``#`` starts a comment)::

    t, 1, 2, 3          # header: 't' then servo ids
    0.0, 2048, 2048, 1000
    0.5, 2300, 1800, 5000
"""

from __future__ import annotations

import bisect
import csv
import math
from pathlib import Path
from typing import Protocol

from hw_sim.control_table import TICKS_PER_TURN
from hw_sim.errors import MotionFileError

CENTER = 2048.0


class MotionSource(Protocol):
    def position(self, joint: int, t: float) -> float: ...


class Hold:
    """Every joint holds ``center`` counts (or its own entry in ``positions``)."""

    def __init__(self, positions: dict[int, float] | None = None, center: float = CENTER):
        self.positions = dict(positions or {})
        self.center = center

    def position(self, joint: int, t: float) -> float:
        return self.positions.get(joint, self.center)


class Programmatic:
    """Positions set from code override ``fallback`` (default: hold 2048) joint by joint."""

    def __init__(self, fallback: MotionSource | None = None):
        self.positions: dict[int, float] = {}
        self.fallback = fallback or Hold()

    def position(self, joint: int, t: float) -> float:
        p = self.positions.get(joint)
        return self.fallback.position(joint, t) if p is None else p

    def set_positions(self, ticks: dict[int, float]) -> None:
        self.positions.update({int(k): float(v) for k, v in ticks.items()})


class Wave:
    """A travelling sine wave down the chain: amplitude (counts), period (s), phase per joint."""

    def __init__(self, amplitude: float = 600.0, period_s: float = 2.0, phase: float = 0.5):
        self.amplitude, self.period_s, self.phase = amplitude, period_s, phase

    def position(self, joint: int, t: float) -> float:
        w = 2.0 * math.pi / self.period_s
        return CENTER + self.amplitude * math.sin(w * t - self.phase * joint)


class Walk:
    """A walk cycle: joints in groups of 3 per leg (hip, knee, ankle), legs half a cycle apart;
    odd-numbered legs mirror. Period in seconds."""

    def __init__(self, period_s: float = 1.2):
        self.period_s = period_s

    def position(self, joint: int, t: float) -> float:
        leg, part = divmod(joint - 1, 3)
        phase = 2.0 * math.pi * (t / self.period_s) + (math.pi if leg % 2 else 0.0)
        if part == 0:    # hip: swing +-25 deg
            deg = 25.0 * math.sin(phase)
        elif part == 1:  # knee: bends only during swing
            deg = 50.0 * max(0.0, math.sin(phase + 0.6)) ** 2
        else:            # ankle: follows the hip, smaller
            deg = -12.0 * math.sin(phase + 0.3)
        return CENTER + deg * TICKS_PER_TURN / 360.0


class Spin:
    """Continuous rotation: ``rpm`` turns per minute, so Present Position passes 4095 and 0."""

    def __init__(self, rpm: float = 30.0):
        self.rpm = rpm

    def position(self, joint: int, t: float) -> float:
        direction = 1.0 if joint % 2 else -1.0
        return CENTER + direction * self.rpm / 60.0 * TICKS_PER_TURN * t


class WithinLimits:
    """A performance fitted to a rig: each servo swings sinusoidally across its own joint range,
    each a little behind the one before.

    Joint angle ``centre + reach · span · sin(2π t / period_s + phase)`` with ``centre`` the
    middle of ``limits_deg`` and ``span`` their width, degrees: with the default ``reach`` of
    0.35 a knee with limits [-5, 120] swings 13.75°..101.25°, bending only the way it bends.
    servos: objects with ``id``, ``zero_ticks``, ``sign``, ``gear`` (servo turns per joint turn)
    and ``limits_deg`` (low, high), e.g. ``hw_sim.rig_servos.RigServo``. Ids it does not name
    hold 2048.
    """

    def __init__(self, servos, period_s: float = 2.4, reach: float = 0.35):
        if not 0.0 <= reach <= 0.5:
            raise ValueError(f"reach must be 0..0.5 of the span (0.5 touches the limits), got {reach}")
        self.period_s = period_s
        self.params: dict[int, tuple[float, float, float]] = {}
        for k, s in enumerate(servos):
            low, high = s.limits_deg
            centre_deg, amplitude_deg = 0.5 * (low + high), reach * (high - low)
            ticks_per_deg = s.sign * s.gear * TICKS_PER_TURN / 360.0
            self.params[int(s.id)] = (s.zero_ticks + centre_deg * ticks_per_deg,
                                      amplitude_deg * ticks_per_deg, 0.6 * k)

    def position(self, joint: int, t: float) -> float:
        centre, amplitude, phase = self.params.get(joint, (CENTER, 0.0, 0.0))
        return centre + amplitude * math.sin(2.0 * math.pi * t / self.period_s + phase)


#: Degrees a person following ``puppet calibrate --guided`` turns each joint, toward the side
#: ``guided_direction`` picks. Device-side copy of ``puppet.rig.guided_calibration.TURN_DEG``
#: (hw_sim imports nothing of puppet; tests/hw_sim/test_hwsim_guided_motion.py checks they agree).
GUIDED_TURN_DEG = 30.0


def guided_direction(limits_deg) -> int:
    """+1 or -1: the side ``calibrate --guided`` asks a joint with ``limits_deg`` (low, high) to
    turn toward: positive unless the upper limit is below GUIDED_TURN_DEG and the lower side has
    more room (a knee with limits [-90, 10] bends negative). Device-side copy of
    ``puppet.rig.guided_calibration.turn_direction``."""
    low, high = (float(x) for x in limits_deg)
    return 1 if high >= GUIDED_TURN_DEG or high >= -low else -1


#: The default guided person's timings, s: rest before the first servo, ramp out (and back),
#: hold, rest after each (``OneAtATime``; ``OneAtATime.at_pace`` divides them).
GUIDED_SETTLE_S, GUIDED_RAMP_S, GUIDED_HOLD_S, GUIDED_REST_S = 5.0, 0.4, 3.0, 1.2
#: ``OneAtATime.at_pace``'s accepted pace (both included): at 4 a joint is held 0.75 s.
PACE = (0.1, 4.0)


class OneAtATime:
    """A person following ``puppet calibrate --guided``: the puppet rests, then each servo in turn
    (in the order given: the rig file's) is turned the way calibrate asks (``guided_direction``:
    positive, or negative when the joint's limits leave more room that way), held, and brought
    back to rest; every other servo stays at rest. Once the last is back, all rest.

    A sequence starts when the host first asks for positions after the bus has been quiet for
    ``quiet_s`` seconds (so each run of the calibration gets the whole sequence, whenever it is
    started): ``settle_s`` at rest (the host reads the rest pose), then per servo ``ramp_s`` out
    to ``reach_deg`` of joint turn (0.9 of the limit on that side when that is nearer),
    ``hold_s`` held, ``ramp_s`` back, ``rest_s`` at rest.
    servos: objects with ``id``, ``zero_ticks``, ``sign``, ``gear`` (servo turns per joint turn)
    and ``limits_deg`` (low, high), e.g. ``hw_sim.rig_servos.RigServo``. Ids it does not name
    hold 2048. The boot-time position (t = 0) is not a host asking.
    """

    def __init__(self, servos, reach_deg: float = GUIDED_TURN_DEG, settle_s: float = GUIDED_SETTLE_S,
                 ramp_s: float = GUIDED_RAMP_S, hold_s: float = GUIDED_HOLD_S, rest_s: float = GUIDED_REST_S,
                 quiet_s: float = 2.0):
        self.settle_s, self.ramp_s, self.hold_s, self.rest_s = settle_s, ramp_s, hold_s, rest_s
        self.quiet_s = quiet_s
        self.period_s = 2.0 * ramp_s + hold_s + rest_s   # one servo's turn, s
        self.params: dict[int, tuple[float, float, int]] = {}   # id -> (rest, reach ticks, turn)
        for k, s in enumerate(servos):
            low, high = s.limits_deg
            direction = guided_direction(s.limits_deg)
            room = high if direction > 0 else -low
            reach = direction * (min(reach_deg, 0.9 * room) if room > 0.0 else reach_deg)
            self.params[int(s.id)] = (float(s.zero_ticks),
                                      reach * s.sign * s.gear * TICKS_PER_TURN / 360.0, k)
        self.start: float | None = None    # when the current sequence began, s
        self.last_asked: float | None = None

    @classmethod
    def at_pace(cls, servos, pace: float) -> "OneAtATime":
        """A person ``pace`` times as quick as the default one (``hw-sim --pace``): every
        duration but ``quiet_s`` divided by ``pace`` (2: rests 2.5 s, holds each joint 1.5 s)."""
        if not (math.isfinite(pace) and PACE[0] <= pace <= PACE[1]):
            raise ValueError(f"must be {PACE[0]:g}..{PACE[1]:g} (1: the default person), got {pace}")
        return cls(servos, settle_s=GUIDED_SETTLE_S / pace, ramp_s=GUIDED_RAMP_S / pace,
                   hold_s=GUIDED_HOLD_S / pace, rest_s=GUIDED_REST_S / pace)

    def position(self, joint: int, t: float) -> float:
        if t > 0.0:
            if self.last_asked is None or t - self.last_asked > self.quiet_s:
                self.start = t
            self.last_asked = t if self.last_asked is None else max(self.last_asked, t)
        rest, reach, turn = self.params.get(joint, (CENTER, 0.0, 0))
        if self.start is None:
            return rest
        local = t - self.start - self.settle_s - turn * self.period_s
        if local <= 0.0 or local >= self.period_s - self.rest_s:
            return rest
        out = min(local, self.period_s - self.rest_s - local) / self.ramp_s
        return rest + reach * min(out, 1.0)


def _check_regular(path: Path) -> None:
    """MotionFileError unless ``path`` is missing (its reader says so) or a regular file: a FIFO
    or a device would block or never end."""
    if path.exists() and not path.is_file():
        raise MotionFileError(path, None, "not a regular file (only regular files are read)")


def _read_table(path: Path) -> tuple[list[int], list[float], list[list[float]]]:
    """Parse the CSV format above: (ids, times, rows of positions)."""
    _check_regular(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise MotionFileError(path, None, f"cannot read: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:
        from hw_sim.faults import text_line

        raise MotionFileError(path, text_line(path, exc.start), "not UTF-8 text (a motion file "
                              "is a CSV of ticks)") from None
    ids: list[int] | None = None
    times: list[float] = []
    rows: list[list[float]] = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        cells = [c.strip() for c in next(csv.reader([line]))]
        if ids is None:
            if cells[0].lower() not in ("t", "t_s", "time"):
                raise MotionFileError(path, lineno, f"header must start with 't', got {cells[0]!r}")
            try:
                ids = [int(c) for c in cells[1:]]
            except ValueError:
                raise MotionFileError(path, lineno, f"servo ids must be integers: {cells[1:]}") from None
            if not ids:
                raise MotionFileError(path, lineno, "header names no servo ids")
            continue
        if len(cells) != len(ids) + 1:
            raise MotionFileError(path, lineno, f"expected {len(ids) + 1} columns, got {len(cells)}")
        try:
            values = [float(c) for c in cells]
        except ValueError:
            raise MotionFileError(path, lineno, f"not a number in {cells}") from None
        if times and values[0] <= times[-1]:
            raise MotionFileError(path, lineno, f"time {values[0]} is not after {times[-1]}")
        times.append(values[0])
        rows.append(values[1:])
    if ids is None or not times:
        raise MotionFileError(path, None, "no keyframes (need a header line and at least one row)")
    return ids, times, rows


TAKE_TOPIC = "/puppet/servo_readings"


def _read_take(path: Path) -> tuple[list[int], list[float], list[list[float]]]:
    """(ids, times from 0 s, rows of ticks) of a puppet take, read with the mcap library only.

    Payload (XCDR1 little endian): 4-byte header, int64 t_ns, uint32 k, int32[k] ticks, ...
    """
    import json
    import struct

    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Metadata
    from mcap.stream_reader import StreamReader

    _check_regular(path)
    ids: list[int] | None = None
    channel_ids: set[int] = set()
    times: list[float] = []
    rows: list[list[float]] = []
    try:
        with open(path, "rb") as stream:
            try:
                for record in StreamReader(stream).records:
                    if isinstance(record, Metadata) and record.name == "puppet.take":
                        ids = [int(i) for i in json.loads(record.metadata["ids"])]
                    elif isinstance(record, Channel) and record.topic == TAKE_TOPIC:
                        channel_ids.add(record.id)
                    elif isinstance(record, Message) and record.channel_id in channel_ids:
                        data = record.data
                        t_ns, k = struct.unpack_from("<qI", data, 4)
                        rows.append(list(struct.unpack_from(f"<{k}i", data, 16)))
                        times.append(t_ns * 1e-9)
            except (McapError, EOFError, struct.error):
                if not rows:  # a truncated tail after good readings is a crash, not an error
                    raise
    except OSError as exc:
        raise MotionFileError(path, None, f"cannot read: {exc.strerror}") from exc
    except (McapError, EOFError, struct.error, KeyError, ValueError) as exc:
        raise MotionFileError(path, None, f"not a readable puppet take: {exc}") from exc
    if ids is None or not rows:
        raise MotionFileError(path, None, "no 'puppet.take' metadata or no servo readings")
    if any(len(r) != len(ids) for r in rows):
        raise MotionFileError(path, None, f"readings do not have {len(ids)} ticks (ids {ids})")
    t0 = times[0]
    return ids, [t - t0 for t in times], rows


class _Table:
    def __init__(self, ids: list[int], times: list[float], rows: list[list[float]],
                 loop: bool) -> None:
        self.ids = {j: k for k, j in enumerate(ids)}
        self.times, self.rows, self.loop = times, rows, loop
        self.duration = times[-1] - times[0]

    def _local_t(self, t: float) -> float:
        t0 = self.times[0]
        if self.loop and self.duration > 0:
            return t0 + (t - t0) % self.duration if t > t0 else t0
        return t


class Keyframes(_Table):
    """Linear interpolation between keyframes; loops over its duration by default.
    Joints not in the file hold 2048."""

    @classmethod
    def from_file(cls, path: str | Path, loop: bool = True) -> "Keyframes":
        return cls(*_read_table(Path(path)), loop=loop)

    def position(self, joint: int, t: float) -> float:
        col = self.ids.get(joint)
        if col is None:
            return CENTER
        t = self._local_t(t)
        times = self.times
        k = bisect.bisect_right(times, t)
        if k == 0:
            return self.rows[0][col]
        if k >= len(times):
            return self.rows[-1][col]
        t0, t1 = times[k - 1], times[k]
        a = (t - t0) / (t1 - t0)
        return self.rows[k - 1][col] * (1 - a) + self.rows[k][col] * a


class Replay(_Table):
    """Sample-and-hold replay of recorded ticks (raw Present Position counts), played once then
    holding the last sample (``loop=True`` to repeat). From a puppet take (.mcap: the
    "puppet.take" metadata's ids and the /puppet/servo_readings messages; a truncated tail is
    tolerated), CSV (format above), or NPZ with arrays ``t`` (seconds, or ``t_ns``), ``ids`` (k,)
    and ``ticks`` (N, k). Time starts at the first sample."""

    @classmethod
    def from_file(cls, path: str | Path, loop: bool = False) -> "Replay":
        path = Path(path)
        if path.suffix == ".mcap":
            return cls(*_read_take(path), loop=loop)
        if path.suffix == ".npz":
            import numpy as np

            _check_regular(path)
            try:
                data = np.load(path)
                t = data["t"] if "t" in data else data["t_ns"] * 1e-9
                ids = [int(i) for i in data["ids"]]
                ticks = np.asarray(data["ticks"], dtype=float)
            except (OSError, KeyError, ValueError) as exc:
                raise MotionFileError(path, None, f"need arrays t|t_ns, ids, ticks: {exc}") from exc
            if ticks.shape != (len(t), len(ids)):
                raise MotionFileError(path, None, f"ticks shape {ticks.shape} != ({len(t)}, {len(ids)})")
            t = [float(x) - float(t[0]) for x in t]
            return cls(ids, t, ticks.tolist(), loop=loop)
        return cls(*_read_table(path), loop=loop)

    def position(self, joint: int, t: float) -> float:
        col = self.ids.get(joint)
        if col is None:
            return CENTER
        k = bisect.bisect_right(self.times, self._local_t(t))
        return self.rows[max(k - 1, 0)][col]


BUILTIN = {"hold": Hold, "still": Hold, "wave": Wave, "walk": Walk, "spin": Spin}


def make_motion(spec) -> MotionSource:
    """A motion source from None (hold), a built-in name, "replay:PATH", a keyframe file path,
    or an object with ``position(joint, t)``."""
    if spec is None:
        return Hold()
    if hasattr(spec, "position"):
        return spec
    text = str(spec)
    if text in BUILTIN:
        return BUILTIN[text]()
    if text.startswith("replay:"):
        return Replay.from_file(text[len("replay:"):])
    path = Path(text)
    if not path.exists():
        raise MotionFileError(path, None, f"not a built-in motion ({', '.join(sorted(BUILTIN))}) "
                                          "and no such file")
    return Keyframes.from_file(path)
