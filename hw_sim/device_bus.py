"""The servos on one bus and what they answer: instruction dispatch, Status Return Level,
broadcast rules, reply order, and the per-reply faults (drop, bad CRC, truncation, error status,
duplicate-id collision).

One bus speaks one protocol: its ``codec`` is ``hw_sim.codec`` (Protocol 2.0) or
``hw_sim.codec1`` (Protocol 1.0: PING with an empty status, READ / WRITE / REG_WRITE with a
1-byte address and length, ACTION, RESET, SYNC_WRITE, BULK_READ answered by MX models only, no
status for any broadcast but Bulk Read's). The servos answer in Protocol 2.0 error numbers; the
codec's ``error_byte`` turns them into its status byte.

``DeviceBus.handle(instruction, now)`` returns the replies as ``[(bytes, return_delay_s), ...]``
in wire order; the server adds the timing model and writes them.
"""

from __future__ import annotations

import random

from hw_sim import codec, codec1
from hw_sim.codec import Instruction
from hw_sim.faults import Fault
from hw_sim.servo import Servo

CLEAR_KEY = b"\x01\x44\x58\x4c\x22"
BACKUP_KEYS = (b"\x01\x43\x54\x52\x4c", b"\x02\x43\x54\x52\x4c")
Replies = list[tuple[bytes, float]]


def _le16(value: int) -> bytes:
    return bytes((value & 0xFF, value >> 8))


def _collide(packets: list[bytes]) -> bytes:
    """Two servos talking at once: the open-drain line ANDs their bytes (the longer tail stays)."""
    out = bytearray(max(packets, key=len))
    for p in packets:
        for k, b in enumerate(p):
            out[k] &= b
    return bytes(out)


class DeviceBus:
    """servos: the simulated servos (ids may change through writes); twins: extra servos
    sharing an id with a real one (duplicate_id fault)."""

    def __init__(self, servos: list[Servo], rng: random.Random | None = None,
                 protocol: float = codec.PROTOCOL) -> None:
        self.codec = codec1 if protocol == codec1.PROTOCOL else codec
        self.servos = list(servos)
        self.twins: list[Servo] = []
        self.reply_faults: list[Fault] = []
        # The host's line speed (bit/s) when known: servos whose Baud Rate item differs hear
        # only noise and stay silent. None = everyone listens (the pty's speed is not checked).
        self.port_baud: int | None = None
        self.rng = rng or random.Random(1)
        self._reindex()
        if self.codec is codec1:
            self._handlers = {
                codec1.PING: self._ping, codec1.READ: self._read, codec1.WRITE: self._write,
                codec1.REG_WRITE: self._reg_write, codec1.ACTION: self._action,
                codec1.RESET: self._factory_reset, codec1.SYNC_WRITE: self._sync_write,
                codec1.BULK_READ: self._bulk_read}
            return
        self._handlers = {
            codec.PING: self._ping, codec.READ: self._read, codec.WRITE: self._write,
            codec.REG_WRITE: self._reg_write, codec.ACTION: self._action,
            codec.FACTORY_RESET: self._factory_reset, codec.REBOOT: self._reboot,
            codec.CLEAR: self._clear, codec.BACKUP: self._backup,
            codec.SYNC_READ: self._sync_read, codec.FAST_SYNC_READ: self._sync_read,
            codec.BULK_READ: self._bulk_read, codec.FAST_BULK_READ: self._bulk_read,
            codec.SYNC_WRITE: self._sync_write, codec.BULK_WRITE: self._bulk_write,
        }

    # ---- lookup --------------------------------------------------------------------------
    def _reindex(self) -> None:
        self.by_id: dict[int, list[Servo]] = {}
        for s in self.servos + self.twins:
            self.by_id.setdefault(s.dxl_id, []).append(s)
        self._secondary = any(s.secondary_id is not None for s in self.servos)

    def servo(self, dxl_id: int) -> Servo:
        """The (first) servo answering to ``dxl_id``; KeyError names the id."""
        for s in self.servos:
            if s.dxl_id == dxl_id:
                return s
        raise KeyError(f"no simulated servo with id {dxl_id} (ids: {sorted(self.by_id)})")

    def _listening(self, s: Servo) -> bool:
        return s.powered and (self.port_baud is None
                              or s.model.baud_rates.get(s.baud_index) == self.port_baud)

    def _targets(self, dxl_id: int) -> list[Servo]:
        return [s for s in self.by_id.get(dxl_id, ()) if self._listening(s)]

    def _shadows(self, dxl_id: int) -> list[Servo]:
        """Servos whose Secondary ID is ``dxl_id``: they execute but never reply."""
        if not self._secondary:
            return []
        return [s for s in self.servos
                if self._listening(s) and s.secondary_id == dxl_id and s.dxl_id != dxl_id]

    # ---- faults on replies -------------------------------------------------------------------
    def _reply_fault(self, dxl_id: int) -> Fault | None:
        for f in self.reply_faults:
            if f.kind != "late" and f.hits(dxl_id) and (f.params["p"] >= 1.0 or self.rng.random() < f.params["p"]):
                return f
        return None

    def _late_s(self, dxl_id: int) -> float:
        """Seconds a ``late`` fault adds before ``dxl_id``'s reply (0 when none hits it)."""
        return sum(f.params["ms"] / 1e3 for f in self.reply_faults if f.kind == "late" and f.hits(dxl_id)
                   and (f.params["p"] >= 1.0 or self.rng.random() < f.params["p"]))

    def _finish(self, dxl_id: int, packets: list[bytes], error: int = 0) -> bytes | None:
        """Combine colliding packets and apply this id's reply fault, if any."""
        if not packets:
            return None
        pkt = packets[0] if len(packets) == 1 else _collide(packets)
        if self.reply_faults:
            f = self._reply_fault(dxl_id)
            if f is not None:
                if f.kind == "drop":
                    return None
                if f.kind == "bad_crc":
                    return pkt[:-1] + bytes([pkt[-1] ^ 0x5A])
                if f.kind == "truncate":
                    keep = f.params["keep"]
                    return pkt[:len(pkt) // 2 if keep is None else keep]
                if f.kind == "error_status":
                    return self.codec.status_packet(dxl_id, f.params["error"] | error)
        return pkt

    # ---- dispatch ------------------------------------------------------------------------
    def handle(self, ins: Instruction, now: float) -> Replies:
        if not ins.crc_ok:
            if ins.dxl_id == codec.BROADCAST_ID:
                return []
            return self._each(ins.dxl_id, lambda s: (codec.ERR_CRC, b""), need=2)
        handler = self._handlers.get(ins.inst)
        if handler is None:
            if ins.dxl_id == codec.BROADCAST_ID:
                return []
            return self._each(ins.dxl_id, lambda s: (codec.ERR_INSTRUCTION, b""), need=2)
        self.now = now
        return handler(ins, now)

    def _each(self, dxl_id: int, fn, need: int, after=None) -> Replies:
        """Run ``fn(servo) -> (error, data)`` on the servos at ``dxl_id`` (or all, broadcast) and
        reply when Status Return Level >= ``need`` and the target was unicast; ``after(servo)``
        runs once the reply is built (reboot, reset)."""
        if dxl_id == codec.BROADCAST_ID:
            for s in [s for s in self.servos + self.twins if self._listening(s)]:
                fn(s)
                if after:
                    after(s)
            self._reindex()
            return []
        packets, delay, alert = [], 0.0, 0
        for s in self._targets(dxl_id):
            level = s.status_return_level  # the level the instruction arrived under
            err, data = fn(s)
            if level >= need:
                alert = self.codec.error_byte(0, s.hardware_error)
                packets.append(self.codec.status_packet(
                    dxl_id, self.codec.error_byte(err, s.hardware_error), data))
                delay = s.return_delay_s
            if after:
                after(s)
        for s in self._shadows(dxl_id):
            fn(s)
            if after:
                after(s)
        self._reindex()
        pkt = self._finish(dxl_id, packets, alert)
        return [(pkt, delay + self._late_s(dxl_id))] if pkt else []

    def _ping(self, ins: Instruction, now: float) -> Replies:
        if ins.dxl_id != codec.BROADCAST_ID:
            return self._each(ins.dxl_id, self._ping_data, need=0)
        if self.codec is codec1:
            return []  # Protocol 1.0: no status for a broadcast
        out = []
        for dxl_id in sorted(self.by_id):
            packets = [codec.status_packet(dxl_id, codec.error_byte(0, s.hardware_error),
                                           self._ping_data(s)[1])
                       for s in self._targets(dxl_id)]
            pkt = self._finish(dxl_id, packets)
            if pkt:
                out.append((pkt, self.servo(dxl_id).return_delay_s + self._late_s(dxl_id)))
        return out

    def _ping_data(self, s: Servo) -> tuple[int, bytes]:
        """Protocol 2.0: model number and firmware; Protocol 1.0: an empty status."""
        if self.codec is codec1:
            return 0, b""
        return 0, bytes(s.mem[0:2]) + bytes([s.firmware])

    def _address(self, p: bytes) -> tuple[int, bytes]:
        """(address, rest) of a Read / Write's parameters: 1 address byte on Protocol 1.0."""
        if self.codec is codec1:
            return p[0], p[1:]
        return p[0] | p[1] << 8, p[2:]

    def _read(self, ins: Instruction, now: float) -> Replies:
        p = ins.params
        if ins.dxl_id == codec.BROADCAST_ID:
            return []  # a broadcast Read is not executed at all
        if len(p) != (2 if self.codec is codec1 else 4):
            return self._each(ins.dxl_id, lambda s: (codec.ERR_DATA_LENGTH, b""), need=1)
        addr, rest = self._address(p)
        length = rest[0] if self.codec is codec1 else rest[0] | rest[1] << 8
        return self._each(ins.dxl_id, lambda s: s.read(addr, length, now), need=1)

    def _write(self, ins: Instruction, now: float) -> Replies:
        p = ins.params
        if len(p) < (2 if self.codec is codec1 else 3):
            return self._each(ins.dxl_id, lambda s: (codec.ERR_DATA_LENGTH, b""), need=2)
        addr, data = self._address(p)
        return self._each(ins.dxl_id, lambda s: (s.write(addr, data, now), b""), need=2)

    def _reg_write(self, ins: Instruction, now: float) -> Replies:
        p = ins.params
        if len(p) < (2 if self.codec is codec1 else 3):
            return self._each(ins.dxl_id, lambda s: (codec.ERR_DATA_LENGTH, b""), need=2)
        addr, data = self._address(p)
        data = bytes(data)

        def reg(s: Servo):
            err = s.check_write(addr, data)
            if not err:
                s.registered = (addr, data)
                s.registered_flag = 1
            return err, b""
        return self._each(ins.dxl_id, reg, need=2)

    def _action(self, ins: Instruction, now: float) -> Replies:
        def act(s: Servo):
            if s.registered is None:
                return codec.ERR_INSTRUCTION, b""
            addr, data = s.registered
            s.registered, s.registered_flag = None, 0
            return s.write(addr, data, now), b""
        return self._each(ins.dxl_id, act, need=2)

    def _factory_reset(self, ins: Instruction, now: float) -> Replies:
        if self.codec is codec1:  # Protocol 1.0 RESET: everything, the ID included
            return self._each(ins.dxl_id, lambda s: (0, b""), need=2,
                              after=lambda s: s.factory_reset(0xFF, now))
        option = ins.params[0] if len(ins.params) == 1 else None
        if option not in (0xFF, 0x01, 0x02):
            if ins.dxl_id == codec.BROADCAST_ID:
                return []
            return self._each(ins.dxl_id, lambda s: (codec.ERR_DATA_RANGE, b""), need=2)
        if ins.dxl_id == codec.BROADCAST_ID and option == 0xFF:
            return []  # ignored (firmware >= 42)

        def check(s: Servo):
            return (codec.ERR_ACCESS if s.torque else 0), b""

        def reset(s: Servo):
            if not s.torque:
                s.factory_reset(option, now)
        return self._each(ins.dxl_id, check, need=2, after=reset)

    def _reboot(self, ins: Instruction, now: float) -> Replies:
        return self._each(ins.dxl_id, lambda s: (0, b""), need=2, after=lambda s: s.reboot(now))

    def _clear(self, ins: Instruction, now: float) -> Replies:
        if bytes(ins.params) != CLEAR_KEY:
            return self._each(ins.dxl_id, lambda s: (codec.ERR_DATA_RANGE, b""), need=2)
        return self._each(ins.dxl_id, lambda s: (s.clear_multi_turn(now), b""), need=2)

    def _backup(self, ins: Instruction, now: float) -> Replies:
        if bytes(ins.params) not in BACKUP_KEYS:
            return self._each(ins.dxl_id, lambda s: (codec.ERR_DATA_RANGE, b""), need=2)
        return self._each(ins.dxl_id,
                          lambda s: ((codec.ERR_RESULT_FAIL if s.torque else 0), b""), need=2)

    # ---- group instructions ----------------------------------------------------------------
    def _group_read(self, requests: list[tuple[int, int, int]], fast: bool, now: float,
                    bulk: bool = False) -> Replies:
        """requests: [(id, addr, length)] in listed order -> one status per id, or one fast
        packet. bulk: a Bulk Read (answered only by models that have it)."""
        if not fast:
            out = []
            for dxl_id, addr, length in requests:
                packets, delay, alert = [], 0.0, 0
                for s in self._targets(dxl_id):
                    if s.status_return_level >= 1 and (s.model.spec.bulk_read or not bulk):
                        err, data = s.read(addr, length, now)
                        alert = self.codec.error_byte(0, s.hardware_error)
                        packets.append(self.codec.status_packet(
                            dxl_id, self.codec.error_byte(err, s.hardware_error), data))
                        delay = s.return_delay_s
                pkt = self._finish(dxl_id, packets, alert)
                if pkt:
                    out.append((pkt, delay + self._late_s(dxl_id)))
            return out
        n = 1 + sum(length + 4 for _, _, length in requests)
        out = bytearray(codec.HEADER + bytes((codec.BROADCAST_ID, n & 0xFF, n >> 8, codec.STATUS)))
        crc = codec.crc16(out)
        delay, late = None, 0.0
        for dxl_id, addr, length in requests:
            segs = []
            for s in self._targets(dxl_id):
                if s.status_return_level >= 1:
                    err, data = s.read(addr, length, now)
                    segs.append(bytes((codec.error_byte(err, s.hardware_error), dxl_id)) + data)
                    delay = s.return_delay_s if delay is None else delay
            if not segs:
                continue  # a missing servo leaves a hole: the packet comes up short
            fault = self._reply_fault(dxl_id) if self.reply_faults else None
            if fault is not None and fault.kind == "drop":
                continue
            late += self._late_s(dxl_id) if self.reply_faults else 0.0  # a late segment holds the rest
            if fault is not None and fault.kind == "error_status":
                segs = [bytes((fault.params["error"] | seg[0], dxl_id)) for seg in segs]
            # Each servo sends its segment and the CRC of everything it heard before plus its own
            # segment; twins (duplicate id) talk at once and the line ANDs their bytes, CRCs too.
            wires = [seg + _le16(codec.crc16(seg, crc)) for seg in segs]
            wire = wires[0] if len(wires) == 1 else _collide(wires)
            seg, crc_bytes = wire[:-2], wire[-2:]
            if fault is not None and fault.kind == "truncate":
                out += wire[:len(seg) // 2]
                break
            sent = crc_bytes if fault is None or fault.kind != "bad_crc" else bytes(
                (crc_bytes[0] ^ 0x5A, crc_bytes[1]))
            out += seg + sent
            crc = codec.crc16(wire, crc)
        if delay is None:
            return []
        return [(bytes(out), delay + late)]

    def _sync_read(self, ins: Instruction, now: float) -> Replies:
        p = ins.params
        if ins.dxl_id != codec.BROADCAST_ID or len(p) < 5:
            return []
        addr, length = p[0] | p[1] << 8, p[2] | p[3] << 8
        return self._group_read([(i, addr, length) for i in p[4:]],
                                ins.inst == codec.FAST_SYNC_READ, now)

    def _bulk_read(self, ins: Instruction, now: float) -> Replies:
        p = ins.params
        if self.codec is codec1:  # 00, then (length, id, address) per servo
            if ins.dxl_id != codec1.BROADCAST_ID or len(p) < 4 or (len(p) - 1) % 3:
                return []
            reqs = [(p[k + 1], p[k + 2], p[k]) for k in range(1, len(p), 3)]
            return self._group_read(reqs, False, now, bulk=True)
        if ins.dxl_id != codec.BROADCAST_ID or not p or len(p) % 5:
            return []
        reqs = [(p[k], p[k + 1] | p[k + 2] << 8, p[k + 3] | p[k + 4] << 8)
                for k in range(0, len(p), 5)]
        return self._group_read(reqs, ins.inst == codec.FAST_BULK_READ, now, bulk=True)

    def _sync_write(self, ins: Instruction, now: float) -> Replies:
        p = ins.params
        if ins.dxl_id != codec.BROADCAST_ID or len(p) < (2 if self.codec is codec1 else 4):
            return []
        if self.codec is codec1:
            addr, length, body = p[0], p[1], p[2:]
        else:
            addr, length, body = p[0] | p[1] << 8, p[2] | p[3] << 8, p[4:]
        if length == 0 or len(body) % (length + 1):
            return []
        for k in range(0, len(body), length + 1):
            for s in self._targets(body[k]) + self._shadows(body[k]):
                s.write(addr, body[k + 1:k + 1 + length], now)
        self._reindex()
        return []

    def _bulk_write(self, ins: Instruction, now: float) -> Replies:
        p = ins.params
        if ins.dxl_id != codec.BROADCAST_ID:
            return []
        k = 0
        while k + 5 <= len(p):
            dxl_id, addr, length = p[k], p[k + 1] | p[k + 2] << 8, p[k + 3] | p[k + 4] << 8
            data = p[k + 5:k + 5 + length]
            if len(data) != length:
                break
            for s in self._targets(dxl_id) + self._shadows(dxl_id):
                s.write(addr, data, now)
            k += 5 + length
        self._reindex()
        return []
