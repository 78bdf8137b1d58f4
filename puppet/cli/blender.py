"""``puppet blender addon``: write the Blender add-on; and the ``--link`` option the live, demo,
play and keys commands share (each solve streamed to Blender: ``puppet.session.outputs.Link``)."""

from __future__ import annotations

import click

link_option = click.option(
    "--link", "link_address", is_flag=False, flag_value="", default=None, metavar="[HOST:]PORT",
    help="Stream each solve to Blender's puppet_link add-on (default 127.0.0.1:9100; another "
         "host prints a token the add-on needs).")


@click.group()
def blender() -> None:
    """Blender: the live link's add-on."""


@blender.command()
@click.option("--out", default="puppet_link.zip", show_default=True,
              help="The add-on's zip file (install it in Blender's preferences).")
@click.option("--force", is_flag=True, help="Replace an existing file of another kind.")
def addon(out: str, force: bool) -> None:
    """Write the Blender add-on that receives ``--link`` (install: Edit > Preferences >
    Add-ons > Install from Disk, pick the zip, tick "puppet link").

    \b
    Example:
      puppet blender addon --out puppet_link.zip
    """
    from puppet.link.addon import write_addon

    path = write_addon(out, force=force)
    click.echo(f"add-on: {path}")


COMMANDS = (blender,)
