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
    """Blender: the live link's add-on, and a rig's character to import."""


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


@blender.command()
@click.option("--rig", "rig_path", default=None, metavar="RIG",
              help="The rig file (default: the built-in critter).")
@click.option("--out", default="character.glb", show_default=True,
              help="The character's glTF binary (.glb) to import in Blender.")
@click.option("--force", is_flag=True, help="Replace an existing file of another kind.")
def character(rig_path: str | None, out: str, force: bool) -> None:
    """Write the rig's character at rest (its mesh, its skin, every joint) as a .glb for
    Blender: File > Import > glTF 2.0, then the add-on drives its armature with --link.

    \b
    Example:
      puppet blender character --out critter.glb     # the built-in critter
    """
    from puppet.cli.common import rig_files
    from puppet.export.character import write_character
    from puppet.rig import builtin, load_rig

    rig = builtin() if rig_path is None else load_rig(rig_path)
    path = write_character(rig, out, inputs=rig_files(rig), force=force)
    click.echo(f"character: {path} ({rig.name}, {len(rig.skeleton.names)} joints)")


COMMANDS = (blender,)
