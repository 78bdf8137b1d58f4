"""One serial link to a Dynamixel bus (Protocol 2.0 or 1.0), through the official dynamixel_sdk.

Every SDK call goes through here: the bus transactions (deadlines, settling after a failure,
the witness, retries of the caller's, the Fast Sync Read exchange). One link speaks one protocol
(a bus carries one: see ``puppet.servo_models``); the packets' bytes are ``puppet.bus.codec``'s
(``Wire``: where each protocol's packets keep their fields), the adapter's latency timer
``puppet.bus.latency``'s.
Protocol 1.0 has no Sync Read, Fast Sync Read, Reboot or broadcast ping, and no alert bit: its
status error byte carries the servo's hardware conditions (input voltage, overheating,
overload: the bits X-series Hardware Error Status uses) beside the instruction's own errors;
the link turns it into the Protocol 2.0 form (alert bit + error number) and keeps the hardware
bits per servo (``hardware_bits``), so everything above reads one form. The SDK's crash paths are absorbed and turned into typed
errors: ``SerialException``/``OSError`` (USB unplug) -> ``PortError``; ``IndexError`` on
short or error-only replies -> ``ServoCorrupt``/``ServoStatusError``; result codes ->
``ServoTimeout``/``ServoCorrupt``. The SDK's ``port.is_using`` flag, left True when a call
raises, is reset before every transaction (this link is the port's only user).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Collection, Iterable, Iterator, Mapping
from dataclasses import dataclass, field

import dynamixel_sdk
import dynamixel_sdk.port_handler as sdk_port_handler
import serial
import termios
from dynamixel_sdk import protocol2_packet_handler as p2
from dynamixel_sdk import robotis_def as rd

from puppet.bus import port_lock
from puppet.bus.codec import PROTOCOL, Wire, describe_status_error, fast_sync_read_crcs
from puppet.bus.errors import PortError, ServoCorrupt, ServoError, ServoStatusError, ServoTimeout
from puppet.bus.latency import DEFAULT_LATENCY_MS, adapter_latency_ms, lower_latency_timer, set_latency_assumption
from puppet.bus.port_lock import PortInUse
from puppet.servo_models import Item


PORT_ERRORS = (serial.SerialException, OSError, termios.error)
"""What pyserial raises when the adapter vanishes: SerialException ('device reports readiness to
read but returned no data'), OSError (EIO on write), termios.error (EIO from tcflush)."""
LATE = "late"
SILENT = "silent"
STALLED = "stalled"
"""Verdicts of ``BusLink.witness`` on a transaction that missed its deadline."""


def _failure(code: int, ids: Iterable[int], instruction: str, detail: str = "",
             deadline: bool = False) -> ServoError:
    """An SDK result code -> the matching typed error. ``deadline``: the SDK gave up because
    its deadline passed (no reply, or a reply cut short), as opposed to a bad CRC."""
    text = dynamixel_sdk.PacketHandler(PROTOCOL).getTxRxResult(code)
    detail = f"{text}{'; ' + detail if detail else ''}"
    if code == rd.COMM_RX_TIMEOUT:
        error: ServoError = ServoTimeout(ids, instruction, detail)
    else:
        error = ServoCorrupt(ids, instruction, detail)
    error.deadline = deadline or code == rd.COMM_RX_TIMEOUT
    return error


PING_PENDING = 0
"""In a witness's pending sizes: a ping witness of it is still unanswered (sizes are >= 5), so
no later ping can be judged (its reply and the earlier one's look alike)."""
WITNESS_SIZES = range(5, 21)
"""Data sizes of witness reads (of the control table from address 0, present on every model):
each outstanding witness of a servo reads a size of its own, so a late reply to an earlier
witness is never taken for this one's. Sizes below 5 are left to the reader's own reads and to
ping replies (3 data bytes)."""



@dataclass
class GroupRead:
    """Result of one group read of one item.

    values: {id: decoded value} for every servo that answered cleanly.
    errors: {id: status error byte} for every servo that answered (0 = clean; bit 7 = alert).
    failed: {id: ServoError} for every servo without a usable value.
    alone:  ids read by a Read of their own (``BusLink.group_read`` on Protocol 1.0).
    """

    values: dict[int, int] = field(default_factory=dict)
    errors: dict[int, int] = field(default_factory=dict)
    failed: dict[int, ServoError] = field(default_factory=dict)
    alone: set[int] = field(default_factory=set)

    def merge(self, other: "GroupRead") -> None:
        """Take in ``other``'s results (another part of the same read)."""
        self.values.update(other.values)
        self.errors.update(other.errors)
        self.failed.update(other.failed)
        self.alone |= other.alone


class BusLink:
    """The port plus one protocol's packet handler, with narrow error handling.

    port:  a port name ('/dev/ttyUSB0', '/dev/serial/by-id/...', a pty) or an already-open
           ``dynamixel_sdk.PortHandler``.
    baud:  bits per second (an SDK-supported rate, e.g. 1_000_000 or 4_000_000).
    latency_ms: the SDK's latency assumption (see ``set_latency_assumption``), ms; None: the
           adapter's own FTDI latency timer when the port has one, first set to 1 ms where
           it is above and writable (``lower_latency_timer``; ``latency_note`` says what was
           done), else 1: the SDK's timeouts then follow the real timer, not its 16 ms.
    poll_block_s: how long one non-blocking SDK serial read may wait in select() for bytes,
           seconds. The SDK busy-polls a ``timeout=0`` serial port; a short blocking read
           releases the GIL instead of spinning. 0 keeps the SDK's spinning.
    protocol: 2.0 (X-series, XL-320, MX(2.0)) or 1.0 (AX, RX, MX): the bus's one protocol.

    ``hardware_bits`` {id: bits}: Protocol 1.0 only, the hardware condition bits of each
    servo's latest status (X-series Hardware Error Status numbering; see ``Wire``).
    """

    def __init__(
        self,
        port: str | dynamixel_sdk.PortHandler,
        baud: int = 1_000_000,
        latency_ms: int | None = None,
        poll_block_s: float = 0.0002,
        protocol: float = PROTOCOL,
    ):
        self.wire = Wire(protocol)
        self.protocol = self.wire.protocol
        self.hardware_bits: dict[int, int] = {}
        if isinstance(port, dynamixel_sdk.PortHandler):
            self.port = port
            self.port_name: str = port.getPortName()
        else:
            self.port = dynamixel_sdk.PortHandler(str(port))
            self.port_name = str(port)
        self.latency_note: str | None = None
        """What was done about the adapter's latency timer (``lower_latency_timer``), or None."""
        if latency_ms is None:
            self.latency_note = lower_latency_timer(self.port_name)
            latency_ms = adapter_latency_ms(self.port_name) or DEFAULT_LATENCY_MS
        self.latency_ms = int(latency_ms)
        set_latency_assumption(self.latency_ms)
        self.settle_s = (self.latency_ms + 1) / 1000.0
        self._unsettled = False
        self.late_bytes = False  # ping_each's: a failed ping read bytes (a late reply)
        self._answered: dict[int, None] = {}  # servos that answered, oldest first: flush witnesses
        self._witness_pending: dict[int, set[int]] = {}  # id -> sizes of unanswered witness reads
        self.baud = int(baud)
        self.poll_block_s = float(poll_block_s)
        self.ph = dynamixel_sdk.PacketHandler(self.protocol)
        self._fast_packets: dict[tuple, bytes] = {}  # (ids, address, size) -> Fast Sync Read request

    # ---- port lifetime -------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return bool(self.port.is_open) and self.port.ser is not None

    def open(self) -> None:
        """Open the port (if needed) at ``baud`` and take its lock (``port_lock``: one program
        per port). PortError if it cannot; PortInUse naming the process that holds it."""
        try:
            if not self.port.is_open or self.port.getBaudRate() != self.baud or self.port.ser is None:
                if not self.port.setBaudRate(self.baud):
                    raise PortError(self.port_name, f"baud rate {self.baud} refused by the SDK")
            if self.poll_block_s > 0:
                self.port.ser.timeout = self.poll_block_s
            fd = self.port.ser.fileno()
        except (*PORT_ERRORS, ValueError) as exc:
            self.port.is_open = False
            raise PortError(self.port_name, "cannot open", exc) from exc
        try:
            port_lock.lock(fd, self.port_name)
        except PortInUse:
            self.close()
            raise
        self.port.is_using = False

    def close(self) -> None:
        """Close the port, ignoring the errors of a port that is already gone."""
        ser = self.port.ser
        self.port.is_open = False
        self.port.is_using = False
        if ser is not None:
            with contextlib.suppress(*PORT_ERRORS):
                ser.close()

    def rebuild(self) -> None:
        """Drop the PortHandler (left busy by an unplug) and open a fresh one on the same name."""
        self.close()
        self.port = dynamixel_sdk.PortHandler(self.port_name)
        self.open()

    def _fail(self, code: int, ids: Iterable[int], instruction: str, detail: str = "") -> ServoError:
        """The typed error for an SDK result code; a late reply may still be on its way, so the
        next instruction first lets the line settle (``_transaction``). The SDK zeroes the
        port's ``packet_timeout`` when its deadline fires: that tells a reply cut short by the
        deadline (which may still be arriving) from one with a bad CRC."""
        self._unsettled = True
        for dxl_id in ids:
            self._answered.pop(dxl_id, None)
        return _failure(code, ids, instruction, detail, deadline=self.port.packet_timeout == 0)

    def witness(self, witness_id: int, timeout_s: float | None = None, ping: bool = False) -> str:
        """Judge the transaction that just missed its deadline by the line's order.

        On a loaded machine the kernel can hold a reply (or the request) for hundreds of ms
        before either end sees it (the pseudo-terminal's and the USB serial driver's buffers
        are pushed by a kernel worker that competes for the CPU), so a deadline alone cannot
        tell a silent servo from a starved bus. The line is first-in first-out: ask
        ``witness_id`` (a servo that answered recently) for a read of a size no earlier,
        unanswered witness asked (``WITNESS_SIZES``) and read up to its reply. Bytes before
        it -> LATE (the failed transaction's reply was on its way); the witness's reply first
        -> SILENT (the failed servo really did not answer); nothing within ``timeout_s``
        (default: the SDK's own deadline for that reply) -> STALLED (no proof either way).
        Everything read is consumed; after STALLED the next instruction lets the line settle.
        ``ping``: ask with a ping instead (for a servo that answers nothing else); while an
        earlier ping witness of it is unanswered, STALLED at once (that late reply would pass for
        this one's, and this one's would then arrive unseen and answer a later read).
        """
        with self._transaction([witness_id], "witness", tx=False):
            return self._witness(witness_id, timeout_s, ping)

    def _witness(self, witness_id: int, timeout_s: float | None = None, ping: bool = False) -> str:
        pending = self._witness_pending.setdefault(witness_id, set())
        wire = self.wire
        if ping and PING_PENDING in pending:  # an earlier ping's reply would pass for this one's
            self._unsettled = True
            return STALLED
        size = wire.ping_size() if ping else next((n for n in WITNESS_SIZES if n not in pending), None)
        if size is None:  # every size still awaits its reply: the line is stalled
            self._unsettled = True
            return STALLED
        reply_size = size + wire.overhead
        if timeout_s is None:
            timeout_s = (2.0 * sdk_port_handler.LATENCY_TIMER + 2.0 + 0.01 * reply_size) / 1e3
        tx = wire.ping_packet(witness_id) if ping else wire.read_packet(witness_id, 0, size)
        start = wire.status_start(witness_id, size)
        got = bytearray()
        got += self.port.ser.read(self.port.ser.in_waiting or 0)
        self.port.ser.write(tx)
        deadline = time.monotonic() + timeout_s
        while True:
            at = got.find(start)
            if at >= 0 and len(got) >= at + reply_size:
                break
            if time.monotonic() > deadline:
                self._unsettled = True
                pending.add(PING_PENDING if ping else size)
                return STALLED
            got += self.port.ser.read(max(1, self.port.ser.in_waiting))
        before = bytes(got[:at])
        if before.endswith(tx):  # a half-duplex adapter echoes the host's own bytes
            before = before[: -len(tx)]
        pending.clear()  # the line is in order: every earlier witness reply came before this one
        for other in self._witness_pending.values():  # ... every earlier ping's too
            other.discard(PING_PENDING)
        self._unsettled = len(got) > at + reply_size
        return LATE if before else SILENT

    def heard_last(self, other_than: int) -> int | None:
        """The servo other than ``other_than`` that answered cleanly most recently (a witness
        for ``witness``), or None."""
        return next((i for i in reversed(self._answered) if i != other_than), None)

    def _heard(self, dxl_id: int) -> None:
        """``dxl_id`` answered cleanly: the newest flush witness."""
        self._answered.pop(dxl_id, None)
        self._answered[dxl_id] = None

    def _settle(self, ids: Iterable[int], instruction: str) -> None:
        """Before an instruction that follows a failed one: make sure no late reply is still on
        its way (it would be taken for this instruction's answer: Protocol 2.0 has no sequence
        numbers). With a servo that answered before, ``witness`` it (everything up to its reply
        is read and dropped); if the line stays stalled, fail this instruction unsent
        (ServoTimeout with ``line_stalled``). With none yet, wait ``settle_s`` and drop."""
        if not self._answered:
            self._unsettled = False
            time.sleep(self.settle_s)
            self.port.ser.reset_input_buffer()
            return
        witness = next(reversed(self._answered))
        if self._witness(witness) == STALLED:
            del self._answered[witness]  # it may have died since: the next flush asks another
            error = ServoTimeout(ids, instruction, "not sent: the line is stalled (replies still pending)")
            error.deadline = error.line_stalled = True
            raise error

    @contextlib.contextmanager
    def _transaction(self, ids: Iterable[int], instruction: str, tx: bool = True) -> Iterator[None]:
        """Run one SDK call: clear the busy flag before; map exceptions after.

        Before a new instruction (``tx``) that follows a failed one, wait ``settle_s`` and drop
        what arrived meanwhile: a reply that missed its deadline would otherwise be taken as the
        answer to the next instruction (Protocol 2.0 has no sequence numbers)."""
        if not self.is_open:
            raise PortError(self.port_name, "not open")
        self.port.is_using = False
        try:
            if tx and self._unsettled:
                self._settle(ids, instruction)
            yield
        except PORT_ERRORS as exc:
            self.port.is_using = False
            raise PortError(self.port_name, f"lost during {instruction}", exc) from exc
        except (IndexError, TypeError, ValueError) as exc:
            # The SDK indexes into replies without checking their length.
            self.port.is_using = False
            raise ServoCorrupt(ids, instruction, f"malformed reply ({type(exc).__name__} in the SDK)") from exc

    def _receive(self, dxl_id: int, size: int, echo: list | None = None) -> tuple[list, int]:
        """Status packets until one from ``dxl_id`` that can answer a read of ``size`` bytes
        (or the deadline already set): packets from others and late replies of another
        size (e.g. to a ping) are skipped, and ``echo`` (the instruction just sent, as a
        half-duplex adapter may echo it). -> (packet, SDK result code)."""
        wire = self.wire
        while True:
            rx, code = self.ph.rxPacket(self.port) if wire.p1 else self.ph.rxPacket(self.port, False)
            if code == rd.COMM_SUCCESS and rx == echo:
                continue
            if code != rd.COMM_SUCCESS or rx[wire.id_at] == dxl_id and not wire.stale(rx, size):
                if code == rd.COMM_SUCCESS and wire.p1:
                    self.hardware_bits[dxl_id] = wire.hardware_bits(rx)
                return rx, code

    # ---- single-servo instructions -------------------------------------------------------
    def ping(self, dxl_id: int) -> tuple[int, int]:
        """Ping one servo -> (model number, firmware version).

        The reply's length is checked: the SDK's ``ping`` would take any status from that id
        (e.g. a late reply to an earlier read) and return its bytes as a model number. A
        Protocol 1.0 ping answers with no data: Model Number (0, 2 bytes) and Firmware Version
        (2) are then read (one 3-byte read; the same addresses on every Protocol 1.0 model).
        """
        wire = self.wire
        with self._transaction([dxl_id], "ping"):
            rx, code = self._exchange(wire.ping_tx(dxl_id), dxl_id, wire.ping_size())
        if code != rd.COMM_SUCCESS:
            raise self._fail(code, [dxl_id], "ping")
        error, data = wire.error(rx), wire.data(rx)
        if error & 0x7F or len(data) != wire.ping_size():
            raise ServoStatusError([dxl_id], "ping", describe_status_error(error)
                                   + f", {len(data)} data bytes (a ping reply has "
                                   f"{wire.ping_size()})", error=error)
        self._heard(dxl_id)
        if wire.p1:
            data = self.read_bytes(dxl_id, 0, 3, "read Model Number")
        return data[0] | (data[1] << 8), data[2]

    def _exchange(self, tx: list, dxl_id: int, size: int) -> tuple[list, int]:
        """Send ``tx`` and take the status from ``dxl_id`` that can answer it (``size`` data
        bytes; late replies of another size skipped) -> (packet, SDK result code). On a
        half-duplex adapter that echoes the host's bytes, a Protocol 1.0 instruction reads like
        a status from its id (the format is the same): its echo is skipped."""
        rx, code, _ = self.ph.txRxPacket(self.port, tx)
        echo = self.wire.sent(tx) if self.wire.p1 else None
        if code == rd.COMM_SUCCESS and (rx == echo or self.wire.stale(rx, size)):
            rx, code = self._receive(dxl_id, size, echo)
        elif code == rd.COMM_SUCCESS and self.wire.p1:
            self.hardware_bits[dxl_id] = self.wire.hardware_bits(rx)
        return rx, code

    def broadcast_ping(self) -> dict[int, tuple[int, int]]:
        """Ping every id at once -> {id: (model number, firmware)}. Costs ~0.8 s (the SDK waits).
        Protocol 1.0 has no broadcast ping: ``ping_each`` instead."""
        if self.wire.p1:
            return self.ping_each(range(rd.BROADCAST_ID))
        with self._transaction([], "broadcast_ping"):
            found, code = self.ph.broadcastPing(self.port)
        if code not in (rd.COMM_SUCCESS, rd.COMM_RX_TIMEOUT):
            raise self._fail(code, [], "broadcast_ping")
        return {int(i): (int(v[0]), int(v[1])) for i, v in found.items()}

    def hardware_error(self, dxl_id: int, items) -> int:
        """Hardware Error Status bits of one servo whose model keeps ``items`` (ControlItems):
        the item where the model has it, else (Protocol 1.0) the bits of the status to a fresh
        read of its Present Position (``hardware_bits``)."""
        if items.hardware_error_status is not None:
            return self.read(dxl_id, items.hardware_error_status)
        self.read(dxl_id, items.present_position)
        return self.hardware_bits.get(dxl_id, 0)

    def ping_each(self, ids: Iterable[int]) -> dict[int, tuple[int, int]]:
        """Ping each of ``ids`` in turn -> {id: (model number, firmware)} of those that
        answered cleanly (a silent id costs one SDK deadline: ~4 ms with a 1 ms latency timer).
        ``late_bytes``: afterwards, whether a ping that failed read bytes (another id's reply,
        past its deadline: something answers, on a busy host)."""
        found = {}
        self.late_bytes = False
        read, heard = self.port.readPort, [0]

        def counted(length):  # the SDK drops another id's reply unseen: its bytes are counted
            data = read(length)
            heard[0] += len(data)
            return data

        self.port.readPort = counted
        try:
            for dxl_id in ids:
                before = heard[0]
                try:
                    found[int(dxl_id)] = self.ping(int(dxl_id))
                except ServoError:
                    # No settling before the next ping: a late reply carries this id, and the
                    # next ping takes only its own id's status (the SDK drops the others).
                    self._unsettled = False
                    self.late_bytes = self.late_bytes or heard[0] > before
        finally:
            del self.port.readPort  # the SDK's own again
        return found

    def read(self, dxl_id: int, item: Item) -> int:
        """Read one item of one servo -> value. The reply's length is checked (the SDK does not)."""
        return self.read_with_status(dxl_id, item)[0]

    def read_with_status(self, dxl_id: int, item: Item) -> tuple[int, int]:
        """Read one item -> (value, status error byte with its alert bit)."""
        data, error = self._read_raw(dxl_id, item.address, item.size, f"read {item.name}")
        return item.decode(data), error

    def read_bytes(self, dxl_id: int, address: int, size: int, instruction: str = "read") -> list:
        """Read ``size`` bytes from ``address`` of one servo -> the data bytes."""
        return self._read_raw(dxl_id, address, size, instruction)[0]

    def _read_raw(self, dxl_id: int, address: int, size: int, instruction: str) -> tuple[list, int]:
        """One read. When it follows a failure with no servo left to witness the line (the
        settling was a wait and a flush, which prove nothing), its answer is kept only once a
        witness of the same servo shows the line in order behind it: replies a stalled line
        held (the same or another read of this size, sent again while it was stalled) may
        still be coming, and the first would pass for this read's (a Status Return Level of 2
        as Hardware Error Status 0x02). Bytes before the witness's reply: read again;
        no witness reply: ServoTimeout with ``line_stalled`` (not proven: the caller's
        patience tries again)."""
        wire = self.wire
        while True:
            unproven = self._unsettled and not self._answered
            with self._transaction([dxl_id], instruction):
                rx, code = self._exchange(wire.read_tx(dxl_id, address, size), dxl_id, size)
            if code != rd.COMM_SUCCESS:
                raise self._fail(code, [dxl_id], instruction)
            data, error = wire.data(rx), wire.error(rx)
            if error & 0x7F or len(data) != size:
                raise ServoStatusError([dxl_id], instruction, describe_status_error(error)
                                       + f", {len(data)} of {size} data bytes", error=error)
            self._heard(dxl_id)
            if not unproven:
                return data, int(error)
            verdict = self.witness(dxl_id)
            if verdict == SILENT:  # nothing was held: the answer was this read's own
                return data, int(error)
            if verdict == STALLED:
                stalled = ServoTimeout([dxl_id], instruction,
                                       "answered, but the line could not show it was the answer")
                stalled.deadline = stalled.line_stalled = True
                raise stalled

    def write(self, dxl_id: int, item: Item, value: int) -> None:
        """Write one item of one servo and wait for its status."""
        instruction = f"write {item.name}"
        with self._transaction([dxl_id], instruction):
            if self.wire.p1:  # through _exchange: an echoed Write reads like its status
                rx, code = self._exchange(self.wire.write_tx(dxl_id, item.address, item.encode(value)),
                                          dxl_id, 0)
                error = self.wire.error(rx) if code == rd.COMM_SUCCESS else 0
            else:
                code, error = self.ph.writeTxRx(self.port, dxl_id, item.address, item.size,
                                                item.encode(value))
        if code != rd.COMM_SUCCESS:
            raise self._fail(code, [dxl_id], instruction)
        if error & 0x7F:
            raise ServoStatusError([dxl_id], instruction, describe_status_error(error), error=error)

    def write_no_reply(self, dxl_id: int, item: Item, value: int) -> None:
        """Write one item without waiting for a status (for a servo whose Status Return Level
        is below 2: it executes writes but does not answer them)."""
        instruction = f"write {item.name}"
        with self._transaction([dxl_id], instruction):
            code = self.ph.writeTxOnly(self.port, dxl_id, item.address, item.size, item.encode(value))
        if code != rd.COMM_SUCCESS:
            raise self._fail(code, [dxl_id], instruction)

    def reboot(self, dxl_id: int) -> None:
        """Send Reboot to one servo (clears a latched hardware error; RAM returns to defaults).
        Protocol 1.0 has no Reboot (ValueError)."""
        self._not_on_p1("reboot")
        with self._transaction([dxl_id], "reboot"):
            code, error = self.ph.reboot(self.port, dxl_id)
        if code != rd.COMM_SUCCESS:
            raise self._fail(code, [dxl_id], "reboot")
        if error & 0x7F:
            raise ServoStatusError([dxl_id], "reboot", describe_status_error(error), error=error)

    # ---- group instructions --------------------------------------------------------------
    def _sync_read_request(self, ids: list[int], item: Item, *, fast: bool
                           ) -> tuple[list | None, ServoError | None]:
        """Send a Sync Read (``fast``: Fast Sync Read) request of ``item`` to ``ids`` as one
        transaction; a Fast Sync Read also takes its one reply packet.

        -> (rx, None): rx the Fast Sync Read reply (None for Sync Read, whose replies are read
        one by one after); or (None, error): the error every servo of ``ids`` gets when the line
        stayed stalled (ServoTimeout with ``line_stalled``) or the SDK call failed.
        """
        instruction = "fast_sync_read" if fast else "sync_read"
        rx = None
        try:
            with self._transaction(ids, instruction):
                if fast:
                    rx, code = self._fast_exchange(ids, item)
                else:
                    code = self.ph.syncReadTx(self.port, item.address, item.size, ids, len(ids), fast)
        except ServoTimeout as exc:
            if not exc.line_stalled:
                raise
            return None, exc
        if code != rd.COMM_SUCCESS:
            return None, self._fail(code, ids, instruction)
        return rx, None

    def _fast_exchange(self, ids: list[int], item: Item) -> tuple[bytearray | None, int]:
        """Send a Fast Sync Read and take its one status packet -> (packet, SDK result code):
        what the SDK's ``syncReadTx`` + ``rxPacket(port, True)`` do (the same bytes, deadline,
        header hunt and result codes), with the request built once per (ids, item) and the
        reply read in whole runs of the bytes still missing (the SDK rebuilds the request
        with its stuffing pass and CRC table on every call)."""
        key = (tuple(ids), item.address, item.size)
        packet = self._fast_packets.get(key)
        if packet is None:
            packet = self._fast_packets[key] = self.wire.fast_sync_read_packet(
                ids, item.address, item.size)
        port = self.port
        port.clearPort()
        if port.writePort(packet) != len(packet):
            return None, rd.COMM_TX_FAIL
        port.setPacketTimeout((11 + item.size) * len(ids))
        return self._fast_status(port, 8 + (item.size + 4) * len(ids))

    @staticmethod
    def _fast_status(port, expected: int) -> tuple[bytearray, int]:
        """One Fast Sync Read status packet -> (packet, SDK result code), as the SDK's
        ``rxPacket(port, True)`` finds it: skip bytes until ``FF FF FD`` (not ``FD``) starts a
        plausible status (reserved 0, id <= 254, length <= 1024, instruction 0x55), read the
        length it gives; past the deadline (``setPacketTimeout``), COMM_RX_TIMEOUT with no
        byte, else COMM_RX_CORRUPT. Its CRC is left to ``fast_sync_read``, which checks it in
        the same pass as the segments'. Reads ``expected`` bytes (the packet of a full answer)
        at once, then what is missing."""
        buf = bytearray()
        wait = expected
        while True:
            buf += port.readPort(wait - len(buf))
            if len(buf) < 11:
                if port.isPacketTimeout():
                    return buf, rd.COMM_RX_CORRUPT if buf else rd.COMM_RX_TIMEOUT
                continue
            start = 0
            while start < len(buf) - 3 and not (buf[start] == 0xFF and buf[start + 1] == 0xFF
                                                and buf[start + 2] == 0xFD and buf[start + 3] != 0xFD):
                start += 1
            if start:
                del buf[:start]
                continue
            length = buf[p2.PKT_LENGTH_L] | (buf[p2.PKT_LENGTH_H] << 8)
            if (buf[p2.PKT_RESERVED] != 0 or buf[p2.PKT_ID] > rd.BROADCAST_ID
                    or length > p2.RXPACKET_MAX_LEN or buf[p2.PKT_INSTRUCTION] != 0x55):
                del buf[0]
                continue
            wait = length + 7
            if len(buf) < wait:
                if port.isPacketTimeout():
                    return buf, rd.COMM_RX_CORRUPT
                continue
            del buf[wait:]
            return buf, rd.COMM_SUCCESS

    def sync_read(self, ids: list[int], item: Item) -> GroupRead:
        """Sync Read (0x82) of one item -> GroupRead with per-servo values, errors and failures.

        Unlike ``GroupSyncRead``, every servo that answered keeps its value when another one
        fails, and each status error byte (alert bit) is kept.
        """
        self._not_on_p1("sync_read")
        _, failure = self._sync_read_request(ids, item, fast=False)
        if failure is not None:
            return GroupRead(failed=dict.fromkeys(ids, failure))
        return self._replies(dict.fromkeys(ids, item), "sync_read")

    def group_read(self, items: Mapping[int, Item], *, fast: bool = False,
                   bulk: Collection[int] = ()) -> GroupRead:
        """One item per servo ({id: Item}, the servo's own address) by the fastest transactions
        the bus has: on Protocol 2.0 one Sync Read (``fast``: Fast Sync Read) per distinct
        item; on Protocol 1.0 (no Sync Read) one Bulk Read of the ``bulk`` servos (MX) and
        one Read per other servo (AX / RX have no Bulk Read). ``GroupRead.alone``: the ids
        read by a Read of their own. After a Read not sent because the line stayed stalled,
        the rest fail with the same error, unsent."""
        if not self.wire.p1:
            read = self.fast_sync_read if fast else self.sync_read
            first = next(iter(items.values()), None)
            if all(item is first for item in items.values()):  # one item for all: one transaction
                return read(list(items), first) if items else GroupRead()
            by_item: dict[Item, list[int]] = {}
            for dxl_id, item in items.items():
                by_item.setdefault(item, []).append(dxl_id)
            if len(by_item) == 1:
                item, ids = next(iter(by_item.items()))
                return read(ids, item)
            out = GroupRead()
            for item, ids in by_item.items():
                out.merge(read(ids, item))
            return out
        bulk_items = {i: item for i, item in items.items() if i in bulk}
        out = self.bulk_read(bulk_items) if bulk_items else GroupRead()
        stalled: ServoError | None = None
        for dxl_id, item in items.items():
            if dxl_id in bulk_items:
                continue
            out.alone.add(dxl_id)
            if stalled is not None:
                out.failed[dxl_id] = stalled
                continue
            try:
                out.values[dxl_id], out.errors[dxl_id] = self.read_with_status(dxl_id, item)
            except ServoError as exc:
                out.failed[dxl_id] = exc
                if exc.line_stalled:
                    stalled = exc
        return out

    def bulk_read(self, items: Mapping[int, Item]) -> GroupRead:
        """Protocol 1.0 Bulk Read (0x92; MX series only) of one item per servo ({id: Item}):
        one instruction, one status per servo in the listed order -> GroupRead as
        ``sync_read``'s. (Sent through the packet handler's ``bulkReadTx``: the SDK's
        Protocol 1.0 ``GroupBulkRead`` raises TypeError in dynamixel-sdk 4.x.)"""
        if not self.wire.p1:
            raise ValueError("BusLink.bulk_read: the Protocol 1.0 Bulk Read (use sync_read on 2.0)")
        ids = list(items)
        param: list[int] = []
        for dxl_id, item in items.items():
            param += [item.size, int(dxl_id), item.address]
        try:
            with self._transaction(ids, "bulk_read"):
                code = self.ph.bulkReadTx(self.port, param, len(param))
        except ServoTimeout as exc:
            if not exc.line_stalled:
                raise
            return GroupRead(failed=dict.fromkeys(ids, exc))
        if code != rd.COMM_SUCCESS:
            return GroupRead(failed=dict.fromkeys(ids, self._fail(code, ids, "bulk_read")))
        return self._replies(items, "bulk_read")

    def _replies(self, items: Mapping[int, Item], instruction: str) -> GroupRead:
        """The status packets of a Sync Read or Bulk Read, one per servo in ``items``' order."""
        out = GroupRead()
        wire = self.wire
        for dxl_id, item in items.items():
            # The deadline is shared by all replies; after it expires, each readRx returns at
            # once with whatever is already buffered.
            with self._transaction([dxl_id], instruction, tx=False):
                rx, code = self._receive(dxl_id, item.size)
            if code != rd.COMM_SUCCESS:
                out.failed[dxl_id] = self._fail(code, [dxl_id], instruction)
                continue
            data, error = wire.data(rx), wire.error(rx)
            out.errors[dxl_id] = int(error)
            if error & 0x7F or len(data) != item.size:
                out.failed[dxl_id] = ServoStatusError(
                    [dxl_id], instruction,
                    describe_status_error(error) + f", {len(data)} of {item.size} data bytes", error=error)
                continue
            out.values[dxl_id] = item.decode(data)
            self._heard(dxl_id)
        return out

    def _not_on_p1(self, instruction: str) -> None:
        if self.wire.p1:
            raise ValueError(f"BusLink.{instruction}: Protocol 1.0 has no {instruction}")

    def fast_sync_read(self, ids: list[int], item: Item) -> GroupRead:
        """Fast Sync Read (0x8A) of one item: one reply packet holding every servo's segment.

        Each segment ``[ERR ID data CRC]`` is checked here, in one CRC pass with the packet's
        own CRC (the SDK checks neither the segment CRCs nor their count). A failed packet
        fails every servo (there is no partial answer): a bad packet CRC as ServoCorrupt.
        """
        instruction = "fast_sync_read"
        self._not_on_p1(instruction)
        rx, failure = self._sync_read_request(ids, item, fast=True)
        if failure is not None:
            return GroupRead(failed=dict.fromkeys(ids, failure))
        out = GroupRead()
        seg = item.size + 4
        full, sums = fast_sync_read_crcs(rx, len(ids), item.size)
        if sums is None:
            return GroupRead(failed=dict.fromkeys(ids, self._fail(rd.COMM_RX_CORRUPT, ids, instruction)))
        if not full:
            # A normal status (e.g. Instruction Error from old firmware) or a short packet.
            error = rx[8] if len(rx) > 8 else 0
            err = ServoStatusError(
                [rx[4]] if rx[4] != rd.BROADCAST_ID else ids, instruction,
                f"reply from id {rx[4]} with {len(rx)} bytes, expected {8 + seg * len(ids)}"
                + (f" ({describe_status_error(error)})" if error else ""), error=error)
            out.failed = dict.fromkeys(ids, err)
            return out
        pos = 8
        for expected_id, crc in zip(ids, sums):
            error, dxl_id = rx[pos], rx[pos + 1]
            got_crc = rx[pos + seg - 2] | (rx[pos + seg - 1] << 8)
            if dxl_id != expected_id or crc != got_crc:
                out.failed[expected_id] = ServoCorrupt([expected_id], instruction, "bad segment")
            else:
                out.errors[dxl_id] = int(error)
                if error & 0x7F:
                    out.failed[dxl_id] = ServoStatusError(
                        [dxl_id], instruction, describe_status_error(error), error=error)
                else:
                    out.values[dxl_id] = item.decode(rx[pos + 2: pos + 2 + item.size])
                    self._heard(dxl_id)
            pos += seg
        return out

    def sync_write(self, item: Item, values: Mapping[int, int]) -> None:
        """Sync Write (0x83) of one item to several servos (no reply)."""
        ids = list(values)
        param: list[int] = []
        for dxl_id, value in values.items():
            param.append(int(dxl_id))
            param.extend(item.encode(value))
        with self._transaction(ids, "sync_write"):
            code = self.ph.syncWriteTxOnly(self.port, item.address, item.size, param, len(param))
        if code != rd.COMM_SUCCESS:
            raise self._fail(code, ids, "sync_write")


__all__ = ["BusLink", "GroupRead", "PORT_ERRORS", "LATE", "SILENT", "STALLED"]
