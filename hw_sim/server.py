"""The bus server on a pseudo-terminal, the ``serve`` context manager and the ``SimBus`` handle.

The server owns the pty's master end and keeps its own slave fd open, so the SDK can close and
reopen the port (``setBaudRate`` does) without the master reading EIO. By default it runs in a
forked child process and is controlled over a pipe: the SDK busy-polls while holding the GIL, so
a responder thread would compete with it for the interpreter.
The child serves at real-time priority where the system allows it (``hold_the_line``): a real
bus answers whatever the host's load, and an ordinary process on a loaded machine can be kept
off the CPU for seconds.
"""

from __future__ import annotations

import collections
import errno
import multiprocessing
import os
import pty
import random
import select
import signal
import tempfile
import termios
import threading
import time
import tty
from contextlib import contextmanager
from typing import Iterator

from hw_sim import codec, codec1
from hw_sim.control_table import get_model
from hw_sim.device_bus import DeviceBus
from hw_sim.errors import HwSimError
from hw_sim.faults import REPLY_KINDS, Fault, make_schedule
from hw_sim.motion import Programmatic, make_motion
from hw_sim.servo import Servo

INTER_BYTE_GAP_S = 0.0015  # a servo drops a partial instruction after this silence
BITS_PER_BYTE = 10  # 8N1


def bus_protocol(servos: dict[int, str]) -> float:
    """The one protocol the servos ``{id: model_name}`` speak (1.0 or 2.0); HwSimError naming
    the servos of each protocol when they differ: a simulated bus carries one protocol, as a
    real one does (a 2.0 packet is noise to a 1.0 servo and the other way round)."""
    by_protocol: dict[float, list[str]] = {}
    for dxl_id, name in sorted(servos.items()):
        by_protocol.setdefault(get_model(name).protocol, []).append(f"{dxl_id} ({name})")
    if len(by_protocol) > 1:
        parts = "; ".join(f"Protocol {p}: servos {', '.join(ids)}"
                          for p, ids in sorted(by_protocol.items()))
        raise HwSimError(f"one bus carries one protocol, these servos mix two: {parts}")
    return next(iter(by_protocol), codec.PROTOCOL)


def _baud_index(model, dxl_id: int, baud: int) -> int:
    """The model's Baud Rate value for ``baud``; HwSimError naming the servo if it has none."""
    try:
        return model.baud_index(baud)
    except ValueError as exc:
        raise HwSimError(f"servo {dxl_id}: {exc}") from None


class _Offset:
    """A motion source shifted by ``offset`` counts (the twin of a duplicate-id fault)."""

    def __init__(self, source, offset: float) -> None:
        self.source, self.offset = source, offset

    def position(self, joint: int, t: float) -> float:
        return self.source.position(joint, t) + self.offset


class Server:
    """A simulated bus on a pty. Build it, then ``run(conn)`` (blocking) in a child or thread.

    servos: {id: model_name}; motion: a motion spec (see motion.make_motion); faults: a fault
    spec (see faults.make_schedule); timing: model return delay + byte time; baud: bits/s for the
    timing model (servos' Baud Rate item is set to match); return_delay_us: Return Delay Time
    (even, 0..508 us; None = the model default 500 us); echo: half-duplex echo from the start;
    strict_baud: servos answer only when the host's port speed (read from the pty's termios,
    as set by ``PortHandler.setBaudRate``) equals their Baud Rate item, and the timing model
    uses that speed, as on a real bus.
    """

    def __init__(self, servos: dict[int, str], *, motion=None, faults=None, timing: bool = False,
                 baud: int = 1_000_000, return_delay_us: int | None = None, echo: bool = False,
                 strict_baud: bool = False, seed: int = 0) -> None:
        if not servos:
            raise HwSimError("a bus needs at least one servo")
        if isinstance(baud, bool) or not isinstance(baud, int) or baud <= 0:
            raise HwSimError(f"baud {baud!r} is not a positive whole number of bit/s")
        self.t0 = time.monotonic()
        self.motion = Programmatic(make_motion(motion))
        self.schedule = make_schedule(faults)
        self.timing = timing
        self.baud = baud
        self.byte_s = BITS_PER_BYTE / baud
        self.echo = echo
        self.strict_baud = strict_baud
        rng = random.Random(seed)
        rd = None if return_delay_us is None else int(return_delay_us) // 2
        if rd is not None and not 0 <= rd <= 254:
            raise HwSimError(f"return_delay_us={return_delay_us} is outside 0..508")
        self.protocol = bus_protocol(servos)
        self.codec = codec1 if self.protocol == codec1.PROTOCOL else codec
        servo_list = []
        for dxl_id, model_name in servos.items():
            top = codec1.MAX_ID if self.protocol == codec1.PROTOCOL else codec.MAX_ID
            if not 0 <= int(dxl_id) <= top:
                raise HwSimError(f"servo id {dxl_id} is outside 0..{top}")
            model = get_model(model_name)
            servo_list.append(Servo(model, int(dxl_id), motion=self.motion, now=0.0,
                                    baud_index=_baud_index(model, dxl_id, baud), return_delay=rd,
                                    rng=random.Random(rng.random())))
        self.bus = DeviceBus(servo_list, rng=random.Random(rng.random()), protocol=self.protocol)
        self.windows: list[tuple[float | None, Fault, list]] = []  # (end_s, fault, undo state)
        self.traffic: collections.deque = collections.deque(maxlen=1024)
        self.counts = collections.Counter()
        self.master = self.slave = -1
        self.path: str | None = None
        self.link_dir = tempfile.mkdtemp(prefix="hw_sim-")
        self.link = os.path.join(self.link_dir, "ttyDXL0")
        self._open_pty()
        self._stop = False

    # ---- the pseudo-terminal ----------------------------------------------------------------
    def _open_pty(self) -> None:
        self.master, self.slave = pty.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.parser = self.codec.InstructionParser()
        self._last_rx = 0.0
        tmp = self.link + ".tmp"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(self.path, tmp)
        os.replace(tmp, self.link)

    def unplug(self) -> None:
        """The adapter vanishes: the master closes, the SDK's fd is hung up (reads return no
        data, so pyserial raises SerialException), and the port path disappears."""
        if self.master < 0:
            return
        os.close(self.master)
        os.close(self.slave)
        self.master = self.slave = -1
        self.path = None
        if os.path.lexists(self.link):
            os.unlink(self.link)

    def replug(self) -> None:
        """The adapter comes back as a new pty; ``link`` points to it again."""
        if self.master >= 0:
            return
        self._open_pty()

    def close(self) -> None:
        self.unplug()
        if os.path.lexists(self.link):  # a child that was killed leaves its link behind
            os.unlink(self.link)
        try:
            os.rmdir(self.link_dir)
        except OSError:
            pass

    def now(self) -> float:
        return time.monotonic() - self.t0

    # ---- faults -----------------------------------------------------------------------------
    def _hit(self, fault: Fault) -> list[Servo]:
        return [s for s in self.bus.servos if fault.hits(s.dxl_id)]

    def activate(self, fault: Fault, now: float) -> None:
        """Start ``fault`` now; it ends at now + duration (if any)."""
        kind, undo = fault.kind, []
        end = None if fault.duration_s is None else now + fault.duration_s
        if kind in REPLY_KINDS:
            self.bus.reply_faults.append(fault)
        elif kind in ("power_cycle", "power_off"):
            for s in self._hit(fault):
                if s.powered:
                    s.power_off()
                    undo.append(s)
        elif kind == "power_on":
            for s in self._hit(fault):
                if not s.powered:
                    s.power_on(now)
        elif kind == "unplug":
            self.unplug()
        elif kind == "replug":
            self.replug()
        elif kind == "duplicate_id":
            for s in self._hit(fault):
                twin = Servo(s.model, s.dxl_id, motion=_Offset(self.motion, fault.params["offset"]),
                             now=now, baud_index=s.baud_index, return_delay=s.return_delay)
                twin.joint = s.joint
                self.bus.twins.append(twin)
                undo.append(twin)
            self.bus._reindex()
        elif kind == "hardware_error":
            for s in self._hit(fault):
                bits = fault.params["bits"]
                if bits & 0x04:
                    s.temperature = s.get("Temperature Limit") + 3
                if bits & 0x01:
                    s.voltage = s.get("Max Voltage Limit") + 5
                s.latch_hardware_error(bits)
        elif kind == "noise":
            for s in self._hit(fault):
                s.noise = fault.params["amplitude"]
                undo.append(s)
        elif kind == "echo":
            self.echo = True
        elif kind == "load":
            for s in self._hit(fault):
                s.refresh(now)
                s.load_ma, s.heat_gain = fault.params["current"], fault.params["heat"]
                if fault.params["temperature"] is not None:  # already warm: heats on from there
                    s.temperature = fault.params["temperature"]
                undo.append(s)
        if kind not in ("power_on", "replug", "hardware_error") or end is not None:
            self.windows.append((end, fault, undo))

    def _deactivate(self, fault: Fault, undo: list, now: float) -> None:
        kind = fault.kind
        if kind in REPLY_KINDS:
            self.bus.reply_faults.remove(fault)
        elif kind in ("power_cycle", "power_off"):
            for s in undo:
                if not s.powered:
                    s.power_on(now)
        elif kind == "unplug":
            self.replug()
        elif kind == "duplicate_id":
            for twin in undo:
                self.bus.twins.remove(twin)
            self.bus._reindex()
        elif kind == "noise":
            for s in undo:
                s.noise = 0
        elif kind == "echo":
            self.echo = False
        elif kind == "load":
            for s in undo:
                s.refresh(now)
                s.load_ma, s.heat_gain = 0.0, 1.0

    def clear_faults(self) -> None:
        """End every active fault (power returns, the adapter is replugged, twins leave).
        Latched hardware errors stay until a reboot, as on a real servo."""
        now = self.now()
        for _, fault, undo in reversed(self.windows):
            self._deactivate(fault, undo, now)
        self.windows.clear()
        self.echo = False

    def advance(self, now: float) -> None:
        """Start scheduled faults that are due and end the ones whose time is up."""
        if self.windows:
            keep = []
            for end, fault, undo in self.windows:
                if end is not None and end <= now:
                    self._deactivate(fault, undo, now)
                else:
                    keep.append((end, fault, undo))
            self.windows = keep
        for fault in self.schedule.due(now):
            self.activate(fault, fault.start_s if fault.start_s <= now else now)

    def _next_event(self) -> float | None:
        times = [end for end, _, _ in self.windows if end is not None]
        nxt = self.schedule.next_start()
        if nxt is not None:
            times.append(nxt)
        return min(times) if times else None

    # ---- serving ------------------------------------------------------------------------------
    def _on_bytes(self, data: bytes, t_rx: float) -> None:
        parser = self.parser
        if parser.pending and t_rx - self._last_rx > INTER_BYTE_GAP_S:
            parser.reset()
        self._last_rx = t_rx
        now = t_rx - self.t0
        self.traffic.append((now, "rx", bytes(data)))
        instructions = parser.feed(data)
        if not instructions:
            return
        if self.strict_baud:
            speed = _port_speed(self.slave)
            self.bus.port_baud = speed
            self.byte_s = BITS_PER_BYTE / (speed or self.baud)
        if self.echo:
            self._send(data)
        line_free = t_rx
        for ins in instructions:
            self.counts[ins.inst] += 1
            replies = self.bus.handle(ins, now)
            if not replies:
                # A write that nobody answers still holds the line for its own bytes.
                line_free += ins.raw_len * self.byte_s if self.timing else 0.0
                continue
            if not self.timing:
                out = b"".join(r for r, _ in replies)
                self._send(out)
                self.traffic.append((now, "tx", out))
                continue
            t = line_free + ins.raw_len * self.byte_s
            for pkt, delay in replies:
                t += delay + len(pkt) * self.byte_s
                self._wait_turn(t)
                self._send(pkt)
                self.traffic.append((t - self.t0, "tx", pkt))
            line_free = t

    def _wait_turn(self, t: float) -> None:
        """Wait until monotonic time ``t``, a reply's turn on the line (sleep for most of it,
        spin the last 0.2 ms). Bytes the host sends meanwhile wait their turn: replies go out
        in the order of the instructions, as the pseudo-terminal delivers them in order (a
        starved kernel can deliver instructions long after they were sent, back to back: a
        reply dropped because the next instruction showed up would look like a silent servo)."""
        while True:
            rem = t - time.monotonic()
            if rem <= 0:
                return
            if rem > 3e-4:
                time.sleep(rem - 2e-4)

    def _send(self, data: bytes) -> None:
        """Write all of ``data`` to the host; if nobody drains the pty for 50 ms, drop the rest
        (counted as tx_overflow) rather than stall the bus."""
        view = memoryview(data)
        while view and self.master >= 0:
            try:
                n = os.write(self.master, view)
            except BlockingIOError:
                n = 0
            except OSError as exc:
                if exc.errno != errno.EIO:
                    raise
                return
            view = view[n:]
            if view and not select.select([], [self.master], [], 0.05)[1]:
                self.counts["tx_overflow"] += 1
                return

    def run(self, conn=None) -> None:
        """Serve until ``stop`` arrives on ``conn`` (or it closes); with no conn, until stop()."""
        ctrl = conn.fileno() if conn is not None else -1
        while not self._stop:
            nxt = self._next_event()
            now = self.now()
            timeout = 0.2 if nxt is None else max(0.0, min(0.2, nxt - now))
            fds = [fd for fd in (self.master, ctrl) if fd >= 0]
            try:
                ready, _, _ = select.select(fds, [], [], timeout)
            except InterruptedError:
                continue
            t_rx = time.monotonic()
            if self.windows or self.schedule.next_start() is not None:
                self.advance(t_rx - self.t0)
            if self.master >= 0 and self.master in ready:
                try:
                    data = os.read(self.master, 65536)
                except BlockingIOError:
                    data = b""
                except OSError as exc:
                    if exc.errno != errno.EIO:
                        raise
                    data = b""
                if data:
                    self._on_bytes(data, t_rx)
            if ctrl >= 0 and ctrl in ready:
                try:
                    cmd, args = conn.recv()
                except (EOFError, OSError):
                    break
                try:
                    result = ("ok", self.command(cmd, *args))
                except (HwSimError, KeyError, ValueError, TypeError) as exc:
                    result = ("err", exc)
                conn.send(result)
        self.close()

    def stop(self) -> None:
        self._stop = True

    def command(self, cmd: str, *args):
        """Control commands (from SimBus over the pipe)."""
        now = self.now()
        if cmd == "stop":
            self._stop = True
            return None
        if cmd == "port":
            return self.path
        if cmd == "inject":
            self.advance(now)
            self.activate(args[0], now)
            return self.path
        if cmd == "clear_faults":
            self.clear_faults()
            return self.path
        if cmd == "set_positions":
            self.motion.set_positions(args[0])
            return None
        if cmd == "servo_get":
            return self.bus.servo(args[0]).get(args[1]) if self._refresh(args[0], now) else None
        if cmd == "servo_set":
            s = self.bus.servo(args[0])
            s.set(args[1], args[2])
            self.bus._reindex()
            return None
        if cmd == "servo_read":
            s = self.bus.servo(args[0])
            s.refresh(now)
            return bytes(s.mem[args[1]:args[1] + args[2]])
        if cmd == "servo_attr":
            s = self.bus.servo(args[0])
            return {"powered": s.powered, "model": s.model.name, "noise": s.noise,
                    "joint": s.joint, "hardware_error": s.hardware_error}[args[1]]
        if cmd == "traffic":
            out = list(self.traffic)
            self.traffic.clear()
            return out
        if cmd == "counts":
            return dict(self.counts)
        raise HwSimError(f"unknown control command {cmd!r}")

    def _refresh(self, dxl_id: int, now: float) -> bool:
        self.bus.servo(dxl_id).refresh(now)
        return True




SERVER_RT_PRIORITY = 1
"""The round-robin real-time priority the forked server asks for (the lowest: above every
ordinary process, below the kernel's own real-time threads)."""


def hold_the_line() -> bool:
    """Serve at real-time priority (SCHED_RR, ``SERVER_RT_PRIORITY``) where the system allows
    it (root, or an RLIMIT_RTPRIO above 0) -> whether it does. Servos are hardware: they answer
    whatever the host's load. An ordinary process on a loaded 2-core machine can wait 1-3 s
    after its wake-up (measured beside busy processes: the server's 0.2 s select() returned
    after 1.7-2.8 s; a timer sleep at nice -10 as late as at nice 0, at SCHED_RR never over
    50 ms), and a bus that pauses past ``perform``'s patience is one whose servos all went
    silent. The server sleeps in select() between instructions, so it takes little time from
    the rest. Where not allowed, it serves as an ordinary process."""
    try:
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(SERVER_RT_PRIORITY))
    except (OSError, AttributeError):
        return False
    return True


def _child_main(server: Server, conn, parent_conn) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    hold_the_line()
    # The fork copied the parent's end of the control pipe: closed here, the parent's death (a
    # SIGKILL, a crash) is an end of file on ``conn`` and the bus stops, instead of outliving it
    # as an orphan that holds the pty and whatever else the parent had open.
    parent_conn.close()
    server.run(conn)


_TERMIOS_SPEEDS = {getattr(termios, f"B{rate}"): rate for rate in (
    9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600, 1000000,
    1152000, 1500000, 2000000, 2500000, 3000000, 3500000, 4000000) if hasattr(termios, f"B{rate}")}


def _port_speed(fd: int) -> int | None:
    """The line speed the host set on the pty (bit/s), or None if not a standard rate."""
    try:
        return _TERMIOS_SPEEDS.get(termios.tcgetattr(fd)[5])
    except termios.error:
        return None


class ServoView:
    """Read access to one simulated servo for assertions (and direct setup writes).

    ``get(name)``: the item's current value (signed where it is), e.g. get("Present Position");
    ``set(name, value)``: store a value with no access rules (test setup);
    ``read(addr, size)``: raw control-table bytes; ``powered``, ``model``, ``hardware_error``.
    """

    def __init__(self, bus: "SimBus", dxl_id: int) -> None:
        self._bus, self.id = bus, dxl_id

    def get(self, name: str) -> int:
        return self._bus._call("servo_get", self.id, name)

    __getitem__ = get

    def set(self, name: str, value: int) -> None:
        self._bus._call("servo_set", self.id, name, value)

    def read(self, addr: int, size: int) -> bytes:
        return self._bus._call("servo_read", self.id, addr, size)

    @property
    def powered(self) -> bool:
        return self._bus._call("servo_attr", self.id, "powered")

    @property
    def model(self) -> str:
        return self._bus._call("servo_attr", self.id, "model")

    @property
    def hardware_error(self) -> int:
        return self._bus._call("servo_attr", self.id, "hardware_error")


class SimBus:
    """A running simulated bus (yielded by ``serve``).

    port: the pty path ('/dev/pts/N') to hand to ``dynamixel_sdk.PortHandler``; after an
        unplug it is None, after a replug the new pty's path.
    link: a stable symlink to the current pty (like /dev/serial/by-id/...): the same path works
        again after a replug.
    """

    def __init__(self, server: Server, *, process: bool = True) -> None:
        self._server = server
        self.link = server.link
        self.servo_ids = [s.dxl_id for s in server.bus.servos]
        self._lock = threading.Lock()
        self._conn, child_conn = multiprocessing.Pipe()
        if process:
            ctx = multiprocessing.get_context("fork")
            self._worker = ctx.Process(target=_child_main, args=(server, child_conn, self._conn),
                                       name="hw_sim-bus", daemon=True)
        else:
            self._worker = threading.Thread(target=server.run, args=(child_conn,),
                                            name="hw_sim-bus", daemon=True)
        self._worker.start()
        if process:
            child_conn.close()
            # The child owns the pty now; our copies would keep a dead bus's port alive.
            os.close(server.master)
            os.close(server.slave)
            server.master = server.slave = -1

    def _call(self, cmd: str, *args):
        with self._lock:
            self._conn.send((cmd, args))
            status, value = self._conn.recv()
        if status == "err":
            raise value
        return value

    @property
    def port(self) -> str | None:
        return self._call("port")

    def inject(self, kind: str, ids=None, *, duration_s: float | None = None, **params) -> None:
        """Start a fault now (kinds and params: hw_sim.faults). ids: an id, ids, or None (all);
        duration_s: None = until ``clear_faults`` (power_cycle defaults to 0.2 s)."""
        fault = Fault.make(kind, ids, duration_s=duration_s, **params)
        self._call("inject", fault)

    def clear_faults(self) -> None:
        """End all active faults (power on, replug, no twins); latched hardware errors stay."""
        self._call("clear_faults")

    def set_positions(self, ticks: dict[int, int]) -> None:
        """Programmatic motion: shaft positions in counts per joint id (torque off: Present
        Position follows them exactly while the servo has not been re-based)."""
        self._call("set_positions", {int(k): float(v) for k, v in ticks.items()})

    def servo(self, dxl_id: int) -> ServoView:
        """The servo with id ``dxl_id`` (KeyError if none)."""
        self._call("servo_attr", dxl_id, "model")
        return ServoView(self, dxl_id)

    def traffic(self) -> list[tuple[float, str, bytes]]:
        """Bytes seen since the last call: [(t_s, 'rx'|'tx', bytes)], rx = from the host."""
        return self._call("traffic")

    def counts(self) -> dict:
        """Instructions received by code, e.g. {0x82: 120}."""
        return self._call("counts")

    def close(self) -> None:
        if not self._worker.is_alive():
            return
        try:
            self._call("stop")
        except (EOFError, OSError, BrokenPipeError):
            pass
        self._worker.join(timeout=2.0)
        if isinstance(self._worker, multiprocessing.process.BaseProcess):
            if self._worker.is_alive():
                self._worker.terminate()
                self._worker.join(timeout=1.0)
            self._server.close()  # the child removed the link; tidy the folder here too
        self._conn.close()


def _servo_models(servos, model: str) -> dict[int, str]:
    if isinstance(servos, dict):
        return {int(k): str(v) for k, v in servos.items()}
    return {int(i): model for i in servos}


@contextmanager
def serve(servos, *, model: str = "XL330-M288", motion=None, faults=None, timing: bool = False,
          baud: int = 1_000_000, return_delay_us: int | None = None, echo: bool = False,
          strict_baud: bool = False, process: bool = True, seed: int = 0) -> Iterator[SimBus]:
    """Run a simulated bus for the duration of the block.

    servos: iterable of ids, or {id: model_name}. model: model for plain ids (any of
    ``hw_sim.control_table.MODELS``: "XL330-M288", "XL430-W250", "AX-12A", "MX-28", "XL-320"...);
    all of one protocol (HwSimError naming the servos otherwise). motion: None (hold still at 2048), a built-in name ("wave",
    "walk", "spin", "hold"), "replay:PATH", a keyframe file path, or an object with
    ``position(joint, t) -> counts``. faults: None, a fault file path, a FaultSchedule or a list
    of Faults (times in seconds from the start). timing: delay replies by return delay + byte
    time at ``baud``. return_delay_us: Return Delay Time (None = 500 us model default).
    echo: half-duplex echo. strict_baud: servos answer only when the host's port speed equals
    their Baud Rate item (as on a real bus; off by default). seed: fault randomness.
    process: serve from a forked child (default) or a thread.
    Yields a running SimBus; stops it on exit.
    """
    server = Server(_servo_models(servos, model), motion=motion, faults=faults, timing=timing,
                    baud=baud, return_delay_us=return_delay_us, echo=echo,
                    strict_baud=strict_baud, seed=seed)
    bus = SimBus(server, process=process)
    try:
        yield bus
    finally:
        bus.close()
