"""``puppet export``: a take into files for other tools (PC2 point cache, BVH skeleton)."""

from __future__ import annotations

import sys

import click
import numpy as np

from puppet.cli.common import fail, open_take


@click.command()
@click.argument("take")
@click.option("--rig", "rig_path", default=None, help="Rig to solve on (default: the take's).")
@click.option("--pc2", default=None, help="Point cache of the deformed mesh (Blender Mesh Cache).")
@click.option("--bvh", default=None, help="Sensed joint rotations as BVH.")
@click.option("--fps", default=30.0, show_default=True, help="Samples per second.")
def export(take: str, rig_path: str | None, pc2: str | None, bvh: str | None, fps: float) -> None:
    """Export a take as a mesh point cache (PC2) and a BVH skeleton.

    \b
    Example:
      puppet export take.mcap --pc2 mesh.pc2 --bvh skeleton.bvh
    """
    from puppet.export import BvhWriter, Pc2Writer
    from puppet.pipeline import Pipeline, run_frames
    from puppet.take import PlaybackClock

    if not pc2 and not bvh:
        fail("nothing to write: give --pc2 FILE and/or --bvh FILE")
    rig, reader = open_take(take, rig_path)
    sk = rig.skeleton
    ids = [int(i) for i in rig.servo_map.ids]
    writers = []
    try:
        with Pipeline(rig, render=False) as pipeline:
            if pc2:
                cache = Pc2Writer(pc2, len(rig.V), sample_rate=1.0)
                writers.append(cache)
            if bvh:
                offsets = sk.heads - np.where(sk.parents[:, None] >= 0, sk.heads[sk.parents], 0.0)
                motion = BvhWriter(bvh, names=list(sk.names), parents=sk.parents, offsets=offsets,
                                   frame_time=1.0 / fps)
                writers.append(motion)
                rotations = np.empty((sk.bone_count, 3, 3))

            clock = PlaybackClock(reader.readings(ids=ids), fps=fps)
            bar = click.progressbar(length=clock.frame_count(reader.t_last_ns - reader.t_first_ns),
                                    label="export", file=sys.stderr)

            def write(p: Pipeline) -> None:
                bar.update(1)
                if pc2:
                    cache.write(p.deformed().astype(np.float32))
                if bvh:
                    motion.write(sk.joint_rotations(p.angles, rotations))

            with bar:
                summary = run_frames(pipeline, (f.reading for f in clock), on_frame=write)
    finally:
        for w in writers:
            w.close()
    click.echo(f"frames: {summary.frames}" + (f"\npc2: {pc2}" if pc2 else "") + (f"\nbvh: {bvh}" if bvh else ""))


COMMANDS = (export,)
