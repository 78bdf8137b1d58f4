"""The torque guardian: a small child process that turns torque off when its parent dies.

``perform`` (and ``keys goto``, perform's start for one pose) computes and writes goals in its
own process, which holds the port. Killed there (SIGKILL, the OOM killer, a hang-up, a crash in
native code), no ``finally`` runs and the servos would keep torque on: the Bus Watchdog stops
their motion, never their torque. So before the port opens, the command starts a guardian: a
fresh interpreter (``LAUNCH``: not ``python -m``, which would run this module a second time
after the package imported it, with a warning on the user's terminal) deaf to SIGINT, SIGTERM
and SIGHUP, holding nothing, that reads its orders (one JSON line on stdin: port, baud,
latency, servos), answers ``ready`` and waits on stdin.

- The command ends its own way (torque off, read back): it writes ``done`` and the guardian
  exits without touching the bus.
- stdin ends without ``done``: the command's process is gone, and with it its lock on the port.
  The guardian opens the port (tried again for ``TAKEOVER_S`` while the kernel releases the dead
  process's lock), turns torque off (``DriveBus.torque_off``: one Sync Write, servo by servo,
  read back, Bus Watchdog cleared) and prints what it read back on the command's stderr.

Only a kill of both at once (the whole process group, a power cut, a frozen machine) leaves
the servos to their Bus Watchdog (``puppet release`` then turns torque off).
"""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time

from puppet.drive.errors import DriveError

TAKEOVER_S = 3.0
"""How long the guardian tries to open the port after its parent died (the dead process's
lock and file go with the kernel's cleanup of it, a few ms on a quiet machine)."""
TAKEOVER_PERIOD_S = 0.005
READY_TIMEOUT_S = 60.0
"""How long the command waits for its guardian's ``ready`` before refusing to turn torque on
(a fresh interpreter importing the bus stack: ~0.3 s quiet, seconds on a loaded machine)."""
STAND_DOWN_S = 10.0
"""How long the command waits for its guardian to exit after ``done``."""
READY, DONE = "ready", "done"
LAUNCH = "import sys; from puppet.drive.guardian import main; sys.exit(main())"
"""The guardian's command line after ``python -c``."""


class Guardian:
    """The command's side: start the guardian (``start``), wait for it before torque goes on
    (``wait_ready``), tell it the command turned torque off itself (``stand_down``).

    port: the serial port; models: {id: model name} of the servos to stop, one protocol;
    who: the command in words, for the guardian's lines ("perform", "keys goto").
    """

    def __init__(self, port: str, models: dict[int, str], *, baud: int, latency_ms: int | None,
                 who: str) -> None:
        self.orders = {"port": str(port), "models": {str(i): m for i, m in models.items()},
                       "baud": int(baud), "latency_ms": latency_ms, "who": who}
        self.proc: subprocess.Popen | None = None
        self._out = b""

    def start(self) -> None:
        """Start the guardian process and hand it its orders (it gets ready meanwhile)."""
        from puppet.child_signals import children_deaf_to_ctrl_c

        with children_deaf_to_ctrl_c():  # the command alone sees a Ctrl-C and stops its way
            self.proc = subprocess.Popen([sys.executable, "-c", LAUNCH],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                         close_fds=True)
        try:
            self.proc.stdin.write((json.dumps(self.orders) + "\n").encode())
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError):
            pass  # it ended already: wait_ready says so (torque stays off)

    def wait_ready(self, timeout_s: float = READY_TIMEOUT_S) -> None:
        """Wait for the guardian's ``ready``; DriveError when it does not come (torque must
        not go on unguarded)."""
        deadline = time.monotonic() + timeout_s
        fd = self.proc.stdout.fileno()
        while READY.encode() not in self._out:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            if select.select([fd], [], [], left)[0]:
                chunk = os.read(fd, 64)
                if not chunk:  # it died
                    break
                self._out += chunk
        else:
            return
        try:  # it closed its end: it is exiting
            why = f"ended before it was ready (exit status {self.proc.wait(timeout=STAND_DOWN_S)})"
        except subprocess.TimeoutExpired:
            why = f"was not ready within {timeout_s:.0f} s"
        raise DriveError(f"the torque guardian process {why}: torque stays off (a kill of this "
                         "process would leave it on)")

    def stand_down(self) -> str | None:
        """The command turned torque off itself: the guardian exits untouched. -> None, or a
        line saying the guardian had already gone (the command's own stop was unguarded)."""
        proc, self.proc = self.proc, None
        if proc is None:
            return None
        try:
            proc.stdin.write((DONE + "\n").encode())
            proc.stdin.close()
        except OSError:  # it is gone: its end of the pipe closed
            pass
        try:
            code = proc.wait(timeout=STAND_DOWN_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            code = proc.wait()
        proc.stdout.close()
        return None if code == 0 else f"warning: the torque guardian process ended with status {code}"


def _say(text: str) -> None:
    try:
        print(f"guardian: {text}", file=sys.stderr, flush=True)
    except OSError:  # the terminal is gone with the command
        pass


def take_over(orders: dict) -> dict[int, int | None]:
    """The command died: open its port and turn its servos' torque off, read back -> {id:
    Torque Enable, None when unreadable}. Lines go to stderr."""
    from puppet.bus.errors import BusError, PortError
    from puppet.bus.link import BusLink
    from puppet.drive.servos import DriveBus
    from puppet.servo_models import protocol_of

    models = {int(i): m for i, m in orders["models"].items()}
    port, who = orders["port"], orders["who"]
    link = BusLink(port, baud=orders["baud"], latency_ms=orders["latency_ms"],
                   protocol=protocol_of(models))
    deadline = time.monotonic() + TAKEOVER_S
    while True:
        try:
            link.open()
            break
        except PortError as err:  # the dead command's lock is still going, or the port is gone
            if time.monotonic() > deadline:
                _say(f"`puppet {who}` ended without turning torque off, and {err}: torque may "
                     f"still be on; `puppet release --port {port}` turns it off")
                return dict.fromkeys(models)
            time.sleep(TAKEOVER_PERIOD_S)
    try:
        after = DriveBus(link, list(models), models, _say).torque_off()
    except BusError as err:
        after = dict.fromkeys(models)
        _say(f"torque off failed: {err}")
    finally:
        link.close()
    off = [i for i, v in after.items() if v == 0]
    unknown = {i: v for i, v in after.items() if v != 0}
    _say(f"`puppet {who}` ended without turning torque off (killed?): torque off (read back): "
         f"servos {off}" + (f"; NOT confirmed: {unknown}; `puppet release --port {port}` turns "
                            "it off" if unknown else ""))
    return after


def main() -> int:
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):  # the command's to act on
        signal.signal(sig, signal.SIG_IGN)
    first = sys.stdin.readline()
    if not first:  # the command died before it gave orders: before its port opened
        return 0
    orders = json.loads(first)
    # Import the bus stack now, so that a takeover costs only the bus transactions.
    import puppet.drive.servos  # noqa: F401

    try:
        os.write(sys.stdout.fileno(), (READY + "\n").encode())
    except OSError:  # the command is gone already (killed during its setup): stop anyway
        pass
    line = sys.stdin.readline()
    if line.strip() == DONE:
        return 0
    after = take_over(orders)
    return 0 if after and set(after.values()) == {0} else 1

