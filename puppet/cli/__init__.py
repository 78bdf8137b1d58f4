"""The puppet command line: one module per command (group); each parses, calls its part, prints.

Nothing imports this package. Every library error (``PuppetError``) and every file-system error
becomes ``Error: <message>`` on stderr with exit status 1, here and only here; an unexpected
error does too (its traceback only with ``PUPPET_DEBUG=1``).
"""

from __future__ import annotations

from puppet.session import signals as _signals

_signals.early()  # a Ctrl-C from here on, before a command's own handlers, is kept (no traceback)

import os  # noqa: E402

# On a small machine OpenBLAS worker threads busy-wait after every numpy call and steal the
# core the solver, the renderer and the bus reader need; puppet's numpy work is small.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import click  # noqa: E402

from puppet.errors import PuppetError  # noqa: E402


def _os_message(err: OSError) -> str:
    """An OSError in words, naming the file it concerns."""
    where = f"{err.filename}: " if err.filename else ""
    return f"{where}{err.strerror or err}"


SIGNAL_COMMANDS = frozenset({"demo", "live", "record", "keys", "play", "view", "perform", "batch",
                             "studio"})
"""Commands that stop through ``puppet.session.signals`` (a session, perform, batch): a signal
before their handlers are set is theirs; every other command gets Python's own handlers back."""


class _PuppetGroup(click.Group):
    """A click group that turns library and file-system errors into ``Error: …``, exit 1."""

    def resolve_command(self, ctx: click.Context, args: list[str]):
        name, command, rest = super().resolve_command(ctx, args)
        if name not in SIGNAL_COMMANDS:  # no session: Ctrl-C is Python's KeyboardInterrupt there
            if _signals.release_early() is not None:
                raise click.Abort()
        return name, command, rest

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except (click.ClickException, click.exceptions.Exit, click.Abort, KeyboardInterrupt):
            raise
        except PuppetError as err:
            raise click.ClickException(str(err)) from None
        except OSError as err:
            raise click.ClickException(_os_message(err)) from None
        except Exception as err:  # noqa: BLE001 - the one place a bug meets the user
            if os.environ.get("PUPPET_DEBUG"):
                raise
            raise click.ClickException(
                f"internal error: {type(err).__name__}: {err} "
                "(run with PUPPET_DEBUG=1 for the traceback, and please report it)") from None


@click.group(cls=_PuppetGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="puppet")
def main() -> None:
    """Turn a posed puppet of Dynamixel servos into rendered character animation.

    \b
    Examples:
      puppet demo                          built-in character on a simulated bus
      puppet rig info --json               check the built-in rig
      hw-sim --rig my.toml &               a simulated bus with the rig's servos; prints its port
      puppet scan --port /dev/ttyUSB0
      puppet calibrate --rig my.toml --port /dev/ttyUSB0
      puppet live --rig my.toml --port /dev/ttyUSB0 --record take.mcap --out live.mp4
      puppet play take.mcap --out take.mp4 --speed 0.5
      puppet demo --view                   watch in a browser; drag the tail
      puppet perform take.mcap --rig my.toml --port /dev/ttyUSB0
      puppet release --port /dev/ttyUSB0   torque off on every servo, watchdog cleared
      puppet export take.mcap --gltf anim.glb --pc2 mesh.pc2 --up z --fps 24
      puppet rig init creature.glb --out creature.toml    a starting rig for your character
      puppet rig axes creature.toml --out sheet.png       each joint turned: pick axes
      puppet calibrate --rig creature.toml --port /dev/ttyUSB0 --guided
      puppet batch session/*.mcap --out exports/ --formats gltf,usd
      puppet studio shoot --demo           a session of shots and takes on one page
      puppet session list shoot            a studio session's shots and takes
    """


def _register() -> None:
    from puppet.cli import (batch, blender, bus, demo, export, keys, live, perform, play, record,
                            release, rig, session_folder, studio, view)

    for module in (demo, live, record, keys, play, export, batch, bus, rig, view, perform,
                   release, blender, session_folder, studio):
        for command in module.COMMANDS:
            main.add_command(command)


_register()
