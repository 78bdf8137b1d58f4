"""Every command of the README's "Using it" block runs as written, in order, in one folder.

Substitutions a reader makes too:

- ``/dev/ttyUSB0`` becomes the port printed by the most recent earlier ``hw-sim --rig RIG`` line
  serving the rig file the line names with ``--rig`` (a line naming no rig, like ``scan``: the
  most recent ``hw-sim --rig`` line's port);
- ``my.toml`` is the built-in rig copied as the README says (its ``mesh`` pointing at
  ``critter.npz``, nothing added: ``calibrate`` writes ``my.calibration.toml`` beside it, which
  the later lines read); ``faults.txt`` is a small
  fault file; ``creature.glb`` is the skinned test character of ``tests/rig/character.py``;
  ``ax.toml`` is the built-in Protocol 1.0 variant (``critter_ax.toml``) copied the same way;
- the manual step the README describes below the block: once ``rig init`` has written
  ``creature.toml``, before the first line that serves or calibrates it, the test fills in two
  of its commented ``[[servo]]`` blocks (``model``, ``joint``, ``axis``) as a user would;
- Enter is pressed when a command asks (``calibrate --guided``: "hold the rest pose");
- ``session/`` (a day of takes, for ``batch``) holds copies of the takes recorded so far.

``hw-sim`` lines keep serving until the end; ``live`` and ``record`` (which run until Ctrl-C) get
Ctrl-C once their take holds readings; ``--view`` commands and ``puppet view`` get Ctrl-C once
their page answers (and their take, if any, holds readings). Every command must exit 0 and write the files it names
(--out, --record, --pc2, --bvh, --frames). A README line the test has no input file or port for
fails with the line quoted.

The block runs as independent parts (``readme_parts``), one test each, so parallel workers
share them: lines that name a common file (``my.toml``, ``take.mcap``, ``shoot/``) are in one part,
in the README's order, with the ``hw-sim`` line that serves their port; a line batching
``session/`` with every earlier line that records a take; every line that serves the page (its
default port) in one part. Each part runs in a folder of its own with the inputs above.
"""

from __future__ import annotations

import importlib.util
import re
import shlex
import signal
import subprocess
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import click
import pytest

from puppet.rig.load import BUILTIN_AX_RIG, BUILTIN_RIG

CHARACTER_MODULE = Path(__file__).resolve().parents[1] / "rig" / "character.py"

README = Path(__file__).resolve().parents[2] / "README.md"
PORT_PLACEHOLDER = "/dev/ttyUSB0"
OUTPUT_OPTIONS = ("--out", "--record", "--pc2", "--bvh", "--frames")
UNTIL_CTRL_C = ("live", "record")  # puppet commands that run until Ctrl-C unless --seconds
CHARACTER_RIG = "creature.toml"
#: The user's edit of the fresh creature.toml: {joint: {key: TOML value}} for the blocks filled in.
CHARACTER_SERVOS = {
    "neck": {"model": '"XL330-M288"', "axis": '"x"'},
    "tail base": {"model": '"XL430-W250"', "axis": '"z"'},
}
"""Two servos of two models on two axes: each more is 5 s more of hw-sim's guided person (one
servo at a time) and the same steps of calibrate --guided again."""


def using_it_commands() -> list[str]:
    """The command lines of the first ```bash block after '## Using it' (comments dropped)."""
    text = README.read_text()
    section = text[text.index("## Using it"):]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    return [line for line in (shlex.join(shlex.split(raw, comments=True)) for raw in block.splitlines())
            if line]


def command_arguments(argv: list[str]) -> list[str]:
    """A line's arguments after its command's words (``puppet keys retime a b``: ``[a, b]``)."""
    if argv[0] != "puppet":
        return argv[1:]
    from puppet.cli import main

    command, rest = main, argv[1:]
    while isinstance(command, click.Group) and rest and rest[0] in command.commands:
        command, rest = command.commands[rest[0]], rest[1:]
    return rest


def named_files(argv: list[str]) -> set[str]:
    """The files and folders a line names (the first part of each path: ``shoot/takes/a.mcap``
    is ``shoot``); option names, numbers and the port placeholder are not."""
    return {arg.split("/")[0] for arg in command_arguments(argv)
            if not arg.startswith("-") and arg != PORT_PLACEHOLDER
            and not re.fullmatch(r"[\d.=:,+-]+", arg)}


def serves_page(argv: list[str]) -> bool:
    """The line serves the live page (until Ctrl-C) on its default port."""
    return "--view" in argv or argv[:2] in (["puppet", "view"], ["puppet", "studio"])


def records_take(argv: list[str]) -> bool:
    """The line writes a take (.mcap) in the folder."""
    return any(argv[k + 1].endswith(".mcap") for k, a in enumerate(argv[:-1])
               if a in ("--out", "--record"))


def readme_parts(commands: list[str]) -> list[list[str]]:
    """The lines split into parts that run apart, each in the README's order: a line is in the
    part of every earlier line it shares a named file with, of the ``hw-sim`` line that serves
    its port (as ``port_for`` picks it), of every earlier take it batches as ``session/``; the
    lines that serve the page share its default port, so they are one part."""
    part = list(range(len(commands)))  # union-find over the lines

    def root(i: int) -> int:
        while part[i] != i:
            part[i] = part[part[i]]
            i = part[i]
        return i

    def join(i: int, j: int) -> None:
        part[root(i)] = root(j)

    servers: dict[str, int] = {}  # rig file -> its latest hw-sim line
    latest = None
    first_named: dict[str, int] = {}
    takes: list[int] = []
    page: int | None = None
    for i, line in enumerate(commands):
        argv = shlex.split(line)
        for name in named_files(argv):
            join(i, first_named.setdefault(name, i))
        rig = option(argv, "--rig")
        if argv[0] == "hw-sim" and rig is not None:
            servers[rig] = latest = i
        if PORT_PLACEHOLDER in argv:
            server = latest if rig is None else servers.get(rig)
            if server is not None:  # else the line fails as it runs, quoted (port_for)
                join(i, server)
        if any(a.startswith("session/") for a in argv):
            for take in takes:
                join(i, take)
        if records_take(argv):
            takes.append(i)
        if serves_page(argv):
            if page is None:
                page = i
            join(i, page)
    groups: dict[int, list[str]] = {}
    for i, line in enumerate(commands):
        groups.setdefault(root(i), []).append(line)
    return sorted(groups.values(), key=lambda lines: commands.index(lines[0]))


def character_module():
    """tests/rig/character.py (the shared skinned glTF test character), loaded by path as
    tests/rig/conftest.py does (pytest runs with --import-mode=importlib)."""
    spec = importlib.util.spec_from_file_location("readme_test_character", CHARACTER_MODULE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def fill_session(folder: Path) -> None:
    """session/: the takes recorded so far, as a day of takes a user batches (journey 4)."""
    session = folder / "session"
    session.mkdir(exist_ok=True)
    for number, take in enumerate(sorted(folder.glob("*.mcap")), start=1):
        (session / f"take{number:02d}.mcap").write_bytes(take.read_bytes())


def write_inputs(folder: Path) -> None:
    """The files the README's commands read: my.toml, ax.toml, faults.txt, creature.glb."""
    text = BUILTIN_RIG.read_text().replace('mesh = "critter.npz"',
                                           f'mesh = "{BUILTIN_RIG.parent / "critter.npz"}"')
    (folder / "my.toml").write_text(text)
    (folder / "ax.toml").write_text(BUILTIN_AX_RIG.read_text().replace(
        'mesh = "critter.npz"', f'mesh = "{BUILTIN_AX_RIG.parent / "critter.npz"}"'))
    (folder / "faults.txt").write_text("0.5 drop ids=3 for=0.2\n1.0 noise ids=2 amplitude=3 for=0.5\n")
    character_module().write_glb(folder / "creature.glb")


def fill_in_servos(rig: Path) -> None:
    """The user's step after `rig init`: uncomment a [[servo]] block per servo, set model and axis."""
    rig.write_text(character_module().enable_servos(rig.read_text(), CHARACTER_SERVOS))


def option(argv: list[str], name: str) -> str | None:
    """The value after ``name`` in argv, or None."""
    return argv[argv.index(name) + 1] if name in argv[:-1] else None


def port_for(line: str, ports: dict[str, str], latest: str | None) -> str:
    """The port a README line means by /dev/ttyUSB0: that of the latest ``hw-sim --rig RIG`` serving
    the rig the line names with --rig (none named: the latest ``hw-sim --rig``'s); ``ports`` is
    {rig file: port}. Fails quoting the line when no such hw-sim line came before it."""
    rig = option(shlex.split(line), "--rig")
    port = latest if rig is None else ports.get(rig)
    assert port is not None, f"{line!r}: no 'hw-sim --rig {rig or 'RIG'}' line before it gives a port"
    return port


def view_url(run: "Background", line: str, timeout: float = 180) -> str:
    """The URL a --view command prints on stderr ('view: URL'), once it is serving."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for text in list(run.errors):
            if text.startswith("view: "):
                return text.split()[1]
        assert run.proc.poll() is None, f"{line!r} ended: {''.join(run.errors)[-2000:]}"
        time.sleep(0.2)
    raise AssertionError(f"{line!r}: printed no 'view: URL' line")


def open_page(run: "Background", url: str, line: str, timeout: float = 180) -> tuple[int, bytes]:
    """(HTTP status, body) of the view's page, retried while the command is still starting."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            with urllib.request.urlopen(url, timeout=60) as page:
                return page.status, page.read()
        except (urllib.error.URLError, ConnectionError):
            assert run.proc.poll() is None, f"{line!r} ended: {''.join(run.errors)[-2000:]}"
            assert time.monotonic() < deadline, f"{line!r}: {url} never answered"
            time.sleep(0.5)


def readings_in(take: Path) -> int:
    from puppet.take import TakeError, TakeReader

    try:
        return len(TakeReader(take))
    except (TakeError, OSError):
        return 0


class Background:
    """A command started like `cmd &`, its output read on a thread (so it never blocks)."""

    def __init__(self, argv: list[str], cwd: Path, interrupt_and_wait) -> None:
        self.argv = argv
        self.interrupt_and_wait = interrupt_and_wait
        self.proc = subprocess.Popen(argv, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        self.lines: list[str] = []
        self.errors: list[str] = []
        self._got_line = threading.Event()
        self._readers = [threading.Thread(target=self._read, daemon=True),
                         threading.Thread(target=self._read_errors, daemon=True)]
        for reader in self._readers:
            reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line.strip())
            self._got_line.set()
        self._got_line.set()  # end of output

    def _read_errors(self) -> None:
        self.errors.extend(self.proc.stderr)

    def first_line(self, timeout: float = 120) -> str:
        """The first line it printed (hw-sim: the port), waiting up to ``timeout`` s for it."""
        self._got_line.wait(timeout)
        return self.lines[0] if self.lines else ""

    def interrupt(self, timeout: float = 120) -> tuple[int, str]:
        """Ctrl-C; (exit code, stderr)."""
        try:
            self.interrupt_and_wait(self.proc, timeout, read_stderr=False)
        except AssertionError as stuck:
            self.errors.append(f"\n{stuck}\n")
        for reader in self._readers:
            reader.join(timeout=30)
        return self.proc.returncode, "".join(self.errors)


def test_readme_lists_the_commands_a_user_needs():
    commands = using_it_commands()
    assert any(c.startswith("hw-sim --rig") for c in commands)
    for name in ("rig info", "scan", "calibrate", "live", "record", "play", "export", "demo",
                 "rig init", "rig axes"):
        assert any(c.startswith(f"puppet {name}") for c in commands), name
    assert any(c.startswith("puppet calibrate") and "--guided" in c for c in commands)


def _part_id(lines: list[str]) -> str:
    """A test id for a part: its first line's words (``puppet demo --ax``: ``demo-ax``), and
    how many lines it has."""
    words = [w.strip("-") for w in lines[0].split()[:4] if w != "puppet"]
    return re.sub(r"[^\w.-]+", "_", "-".join(words)) + f"+{len(lines) - 1}"


PARTS = readme_parts(using_it_commands())


def test_the_parts_hold_every_line_once_in_the_readmes_order():
    commands = using_it_commands()
    assert sorted(line for part in PARTS for line in part) == sorted(commands)
    for part in PARTS:
        assert part == [line for line in commands if line in part]
    [page] = [part for part in PARTS if any(serves_page(shlex.split(line)) for line in part)]
    assert all(line in page for line in commands if serves_page(shlex.split(line)))
    [mine] = [part for part in PARTS if "hw-sim --rig my.toml" in part]
    assert "puppet scan --port /dev/ttyUSB0" in mine  # a port of the latest hw-sim --rig
    assert any(line.startswith("puppet batch 'session/") for line in mine)  # its takes
    assert len(PARTS) > 4  # what runs apart


@pytest.mark.parametrize("lines", PARTS, ids=[_part_id(p) for p in PARTS])
def test_every_using_it_command_runs_as_written(tmp_path, interrupt_and_wait, lines):
    write_inputs(tmp_path)
    servers: list[Background] = []
    ports: dict[str, str] = {}   # rig file -> port of the latest hw-sim serving it
    latest_port = None
    servos_filled = False
    try:
        for line in lines:
            started = time.monotonic()
            argv = shlex.split(line)
            rig = option(argv, "--rig")
            if rig == CHARACTER_RIG and not servos_filled:
                assert (tmp_path / rig).exists(), f"{line!r}: no 'rig init' line before it writes {rig}"
                fill_in_servos(tmp_path / rig)
                servos_filled = True
            if any(a.startswith("session/") for a in argv):
                fill_session(tmp_path)
            if argv[0] == "hw-sim":
                server = Background(argv, tmp_path, interrupt_and_wait)
                servers.append(server)
                assert server.first_line().startswith("/dev/"), (line, server.proc.poll(),
                                                                 "".join(server.errors))
                if rig is not None:
                    ports[rig] = latest_port = server.first_line()
                continue
            if PORT_PLACEHOLDER in argv:
                port = port_for(line, ports, latest_port)
                argv = [port if a == PORT_PLACEHOLDER else a for a in argv]
            outputs = [argv[k + 1] for k, a in enumerate(argv[:-1]) if a in OUTPUT_OPTIONS]
            if serves_page(argv):  # serves until Ctrl-C
                take = option(argv, "--record")
                run = Background(argv, tmp_path, interrupt_and_wait)
                url = view_url(run, line)
                status, html = open_page(run, url, line)  # the page a user opens
                assert status == 200, (line, status)
                assert b"<html" in html.lower(), line
                deadline = time.monotonic() + 180
                while take is not None and readings_in(tmp_path / take) < 20 and run.proc.poll() is None:
                    assert time.monotonic() < deadline, f"{line!r}: no readings recorded"
                    time.sleep(0.2)
                code, stderr = run.interrupt()
            elif argv[:2] in (["puppet", c] for c in UNTIL_CTRL_C) and "--seconds" not in argv:
                take = argv[argv.index("--record" if argv[1] == "live" else "--out") + 1]
                run = Background(argv, tmp_path, interrupt_and_wait)
                deadline = time.monotonic() + 180
                while readings_in(tmp_path / take) < 20 and run.proc.poll() is None:
                    assert time.monotonic() < deadline, f"{line!r}: no readings recorded"
                    time.sleep(0.2)
                code, stderr = run.interrupt()
            else:
                result = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True,
                                        input="\n", timeout=600)
                code, stderr = result.returncode, result.stderr
            assert code == 0, f"{line!r} exited {code}:\n{stderr[-3000:]}"
            if "--guided" in argv:  # every servo the user filled in was found, in the file's order
                found = [row.split(" (")[0].strip() for row in result.stdout.splitlines()
                         if row.startswith("  ") and ": servo " in row]
                assert found == [j for j in character_module().NAMES if j in CHARACTER_SERVOS], (
                    line, result.stdout, stderr)
            assert "Traceback" not in stderr, (line, stderr)
            if argv[:2] == ["puppet", "calibrate"] and "--out" not in argv and "--guided" not in argv:
                from puppet.rig import load_rig  # the rig reads what calibrate wrote beside it

                written = tmp_path / Path(option(argv, "--rig")).with_suffix(".calibration.toml")
                assert written.is_file(), f"{line!r} did not write {written.name}"
                assert load_rig(tmp_path / option(argv, "--rig")).calibration.path == written
            for name in outputs:
                assert (tmp_path / name).exists(), f"{line!r} did not write {name}"
            print(f"{time.monotonic() - started:6.1f} s  {line}")  # shown with -s or on failure
    finally:
        for server in servers:
            code, stderr = server.interrupt()
            assert code == 0, stderr


def test_each_line_gets_the_port_of_the_bus_serving_its_rig():
    ports = {"my.toml": "/dev/pts/1", "creature.toml": "/dev/pts/2"}
    assert port_for("puppet calibrate --rig creature.toml --port /dev/ttyUSB0 --guided", ports,
                    "/dev/pts/2") == "/dev/pts/2"
    assert port_for("puppet record --rig my.toml --port /dev/ttyUSB0 --out t.mcap", ports,
                    "/dev/pts/2") == "/dev/pts/1"
    assert port_for("puppet scan --port /dev/ttyUSB0", ports, "/dev/pts/1") == "/dev/pts/1"
    line = "puppet live --rig other.toml --port /dev/ttyUSB0"
    with pytest.raises(AssertionError) as failure:
        port_for(line, ports, "/dev/pts/1")
    assert str(failure.value).startswith(f"{line!r}: no 'hw-sim --rig other.toml' line before it")


@pytest.mark.parametrize("command", ["puppet rig info my.toml --json"])
def test_the_block_is_parsed_into_runnable_lines(command):
    assert command in using_it_commands()
