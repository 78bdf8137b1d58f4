"""Bones pass: the skeleton overlay, each bone a diamond moving with its handle, colored by state."""

from __future__ import annotations

import moderngl
import numpy as np

from puppet.render import shaders
from puppet.render.errors import RenderInputError
from puppet.render.overlay import BONE_CORNERS, rest_segments, state_color
from puppet.render.passes.base import GLPass


class BonesPass(GLPass):
    """Draws bones over the frame: m handles, width_px [px] wide, in a width x height frame.

    The instance buffer grows on demand (rebuilt when the bone count changes). ``posed``:
    (b, 9) float32 heads, tails and colours of the bones drawn last (None before any).
    """

    def __init__(self, ctx, *, m: int, width_px: float, width: int, height: int):
        super().__init__(ctx)
        self.m = m
        self.width_px = float(width_px)
        self._viewport = (float(width), float(height))
        self._vbo = None
        self._vao = None
        self._source = None
        self._rest = None
        self.posed = None
        with self.building():
            self._prog = self.own(ctx.program(vertex_shader=shaders.source(shaders.BONE_VERTEX),
                                              fragment_shader=shaders.source(shaders.BONE_FRAGMENT)))
            self._corners = self.own(ctx.buffer(BONE_CORNERS))

    def set_camera(self, view_proj_gl: np.ndarray) -> None:
        """Apply the (4, 4) column-major projection."""
        self._prog["u_view_proj"].write(view_proj_gl)
        self._prog["u_viewport"].value = self._viewport

    def draw(self, bones, bone_states, blocks: np.ndarray) -> None:
        """Draw bones (b, 2, 3) rest heads and tails (or a Skeleton), bone i moved by handle i's
        blocks[i] (4, 3), with b states or None, into the bound framebuffer."""
        if bones is not self._source:
            rest = rest_segments(bones)
            if len(rest) > self.m:
                raise RenderInputError(f"bones: {len(rest)} bones but only {self.m} handles")
            if self._rest is None or len(rest) != len(self._rest):
                self.posed = np.zeros((len(rest), 9), dtype=np.float32)
                if self._vbo is not None:
                    self.disown(self._vao)
                    self.disown(self._vbo)
                self._vbo = self.own(self.ctx.buffer(reserve=self.posed.nbytes, dynamic=True))
                self._vao = self.own(self.ctx.vertex_array(
                    self._prog,
                    [(self._corners, "2f", "in_corner"), (self._vbo, "3f 3f 3f/i", "in_head", "in_tail", "in_color")],
                ))
            self._rest = rest
            self._source = bones
        rest = self._rest
        count = len(rest)
        if bone_states is not None and len(bone_states) != count:
            raise RenderInputError(f"bone_states: {len(bone_states)} states for {count} bones")
        inst = self.posed
        posed = inst[:, :6].reshape(count, 2, 3)
        np.matmul(rest, blocks[:count], out=posed, casting="same_kind")  # (b,2,4) @ (b,4,3)
        for i in range(count):
            inst[i, 6:9] = state_color(None if bone_states is None else bone_states[i], i)
        self._vbo.write(inst)
        self._prog["u_width_px"].value = self.width_px
        self._vao.render(moderngl.TRIANGLE_STRIP, instances=count)
