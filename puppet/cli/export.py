"""``puppet export``: a take into files for other tools (glTF, USD, PC2, BVH)."""

from __future__ import annotations

import json
import sys

import click

from puppet import limits
from puppet.cli.common import (InRange, force_option, keys_option, keys_units_option, layer_options,
                               open_take, space_option)


@click.command()
@click.argument("take")
@click.option("--rig", "rig_path", default=None, help="Rig to solve on (default: the take's).")
@click.option("--gltf", default=None, help="glTF binary (.glb): the character, its skin and every "
                                           "joint animated; its scene extras puppet_fps, "
                                           "puppet_frame_start, puppet_frame_end give the take's "
                                           "rate and range (Blender: scene custom properties).")
@click.option("--usd", default=None, help="USD (.usdc/.usda; .usdz: packaged with its textures): "
                                          "exact mesh points per frame, the skeleton (UsdSkel) and, "
                                          "for a glTF character, its UVs, colours, materials "
                                          "(textures in <name>_textures/ beside it) and nodes.")
@click.option("--pc2", default=None, help="Point cache of the deformed mesh in the character "
                                          "file's vertex order (Blender Mesh Cache).")
@click.option("--bvh", default=None, help="Every joint as BVH, named as in the rig (whitespace and "
                                          "control characters -> _, accents dropped; dots and .L/.R "
                                          "kept); End Sites reach the mesh's farthest vertex.")
@click.option("--fps", default="30", show_default=True,
              help=f"Frames per second, resampled from the reading times ({limits.FPS}).")
@click.option("--up", type=click.Choice(["y", "z"]), default="y", show_default=True,
              help="Up axis of the PC2 points: z for Blender's Mesh Cache.")
@space_option
@keys_option
@keys_units_option
@click.option("--sound", "sound_path", default=None, metavar="FILE",
              help="The sound the glTF extras, USD layer data and BVH comment name (its file, "
                   "hash, rate, the take's offset); default: the take's own.")
@click.option("--clip", nargs=2, type=InRange(limits.SECONDS_FROM_START), default=None, metavar="IN OUT",
              help="Only the segment from IN to OUT seconds of the take's play time (a "
                   "studio clip).")
@click.option("--loop", is_flag=True,
              help="With --clip: a loop, its seam blended in solve space (no pop when it "
                   "repeats).")
@layer_options()
@click.option("--json", "as_json", is_flag=True, help="Print the report as one JSON line.")
@force_option
def export(take: str, rig_path: str | None, gltf: str | None, usd: str | None, pc2: str | None,
           bvh: str | None, fps: str, up: str, space: str, keys: float | None,
           keys_units: float | None, as_json: bool, force: bool, sound_path: str | None,
           clip: tuple[float, float] | None, loop: bool, layers) -> None:
    """Export a take; frame 1 is the take's first reading in every format.

    An output estimated over 16 GiB (puppet.limits.EXPORT_BYTES: a long take of a dense mesh
    as PC2 or USD) is refused before anything is written, unless --force.

    \b
    Examples:
      puppet export take.mcap --gltf anim.glb --fps 24
      puppet export take.mcap --usd anim.usdc --pc2 mesh.pc2 --up z --bvh skeleton.bvh
      puppet export take.mcap --gltf anim.glb --keys 0.5   # editable keys
      puppet export arms.mcap --gltf anim.glb --punch arms.mcap=2:8   # a layer held 2-8 s
    """
    from puppet.export import ExportError, Outputs, export_take
    from puppet.export.run import check_fps

    if loop and clip is None:
        raise click.UsageError("--loop is of a clip: give --clip IN OUT")
    fps_value = check_fps(fps)
    outputs = Outputs(gltf=gltf, usd=usd, pc2=pc2, bvh=bvh, force=force)
    if not outputs.items():
        raise ExportError("export", "nothing to write: give --gltf, --usd, --pc2 and/or --bvh FILE")
    rig, reader = open_take(take, rig_path)
    sound = None
    if sound_path is not None:  # decoded: refused here when it is not a sound
        from puppet.sound import load_sound, sound_ref

        stored = reader.metadata.sound
        sound = sound_ref(load_sound(sound_path), stored.offset_s if stored is not None else 0.0)
    bar = None

    def progress(done: int, total: int) -> None:
        nonlocal bar
        if bar is None:
            bar = click.progressbar(length=total, label="export", file=sys.stderr)
            bar.__enter__()
        bar.update(1)

    try:
        report = export_take(rig, reader, outputs, fps=fps_value, up=up, space=space, keys=keys,
                             keys_units=keys_units, progress=progress, sound=sound,
                             clip=None if clip is None else (clip[0], clip[1], loop),
                             layers=layers)
    finally:
        if bar is not None:
            bar.__exit__(None, None, None)
    for warning in report.warnings:
        click.echo(f"warning: {warning}", err=True)
    click.echo(json.dumps(report.as_dict()) if as_json else report.text())


COMMANDS = (export,)
