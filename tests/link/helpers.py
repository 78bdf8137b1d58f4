"""Helpers of the live link's tests: a running ``puppet`` command with its port read, and the
keys of a .glb's animation. Load by path (pytest runs with --import-mode=importlib)."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pygltflib


class Puppet:
    """A running ``puppet ...`` command; its stderr lines collected on a thread."""

    def __init__(self, argv, program=("puppet",), stdin=None):
        self.proc = subprocess.Popen([*program, *map(str, argv)], stdin=stdin,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines: list[str] = []
        self.out: list[str] = []
        for stream, into in ((self.proc.stderr, self.lines), (self.proc.stdout, self.out)):
            threading.Thread(target=self._collect, args=(stream, into), daemon=True).start()

    @classmethod
    def python(cls, argv) -> "Puppet":
        """This Python (bpy's) running ``argv``, its output collected the same way."""
        return cls(argv, program=(sys.executable,))

    @staticmethod
    def _collect(stream, into):
        for line in stream:
            into.append(line.rstrip("\n"))

    def listening(self, wait_until) -> tuple[int, str | None]:
        """(port, token) from 'link: listening on HOST:PORT [token T]'."""
        line = wait_until(lambda: next((x for x in self.lines
                                        if x.startswith("link: listening")), None)
                          or (self.proc.poll() is not None and "exited"))
        assert line != "exited", "\n".join(self.lines)
        words = line.split()
        where = words[3]
        token = words[5] if len(words) > 5 else None
        return int(where.rsplit(":", 1)[1]), token


def gltf_keys(path: Path, names) -> tuple[np.ndarray, np.ndarray]:
    """(frames, b, 3) translations and (frames, b, 4) rotations of a .glb's animation, per
    joint in ``names`` order."""
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()

    def data(index, width):
        accessor = gltf.accessors[index]
        view = gltf.bufferViews[accessor.bufferView]
        start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
        return np.frombuffer(blob, np.float32, accessor.count * width, start).reshape(-1, width)

    node_of = {gltf.nodes[i].name: i for i in range(len(gltf.nodes))}
    channels = {}
    animation = gltf.animations[0]
    for channel in animation.channels:
        sampler = animation.samplers[channel.sampler]
        width = 4 if channel.target.path == "rotation" else 3
        channels[(channel.target.node, channel.target.path)] = data(sampler.output, width)
    t = np.stack([channels[(node_of[n], "translation")] for n in names], 1)
    q = np.stack([channels[(node_of[n], "rotation")] for n in names], 1)
    return t.astype(np.float64), q.astype(np.float64)


def reference_vertices(rig, take) -> np.ndarray:
    """(frames, n, 3) the solver's vertices of every frame at 30 fps (model frame, the rig's
    vertex order), solved here with the pipeline."""
    from puppet.loop import Pipeline
    from puppet.take import Playback, TakeReader

    frames = Playback.of_take(TakeReader(take), rig.servo_map.ids, fps=30.0, rig=rig)
    out = []
    with Pipeline(rig, render=False) as pipeline:
        for reading in frames:
            pipeline.solve(reading)
            out.append(pipeline.deformed().copy())
    return np.array(out)
