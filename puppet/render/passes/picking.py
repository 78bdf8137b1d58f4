"""Picking pass: which triangle, and where on it, lies under a pixel of a rendered frame.

The pass draws the renderer's own skinned vertices (its transform-feedback buffer) and index
buffer with the same camera projection and the same back-face culling as ``Renderer.draw``,
into a float framebuffer holding (triangle id + 1, barycentric coordinates) per pixel; a
geometry shader numbers the triangles and gives each corner its unit barycentric, which the
rasterizer interpolates perspective-correctly. Only the asked pixel is rasterized (scissor),
so a pick costs one skinning pass and a one-pixel draw.
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from puppet.render.camera import Camera
from puppet.render.passes.base import GLPass
from puppet.render.passes.mesh import SKINNED_FLOATS

PICK_VERTEX = """
#version 330
in vec3 in_position;
uniform mat4 u_view_proj;
void main() { gl_Position = u_view_proj * vec4(in_position, 1.0); }
"""

PICK_GEOMETRY = """
#version 330
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
flat out int v_triangle;
out vec3 v_bary;
void main() {
    for (int k = 0; k < 3; ++k) {
        gl_Position = gl_in[k].gl_Position;
        v_triangle = gl_PrimitiveIDIn;
        v_bary = vec3(k == 0 ? 1.0 : 0.0, k == 1 ? 1.0 : 0.0, k == 2 ? 1.0 : 0.0);
        EmitVertex();
    }
    EndPrimitive();
}
"""

PICK_FRAGMENT = """
#version 330
flat in int v_triangle;
in vec3 v_bary;
out vec4 out_pick;
void main() { out_pick = vec4(float(v_triangle + 1), v_bary); }
"""


@dataclass(frozen=True)
class Pick:
    """A surface point under a pixel: triangle index into F and its barycentric coordinates
    (3,) (non-negative, summing to one), for the T and camera the pick was made with."""

    triangle: int
    bary: tuple[float, float, float]


class Picker(GLPass):
    """Picks surface points of a Renderer's character (sharing its context and buffers).

    renderer: the Renderer whose frames are picked; the picker must be released before it.
    """

    def __init__(self, renderer):
        super().__init__(renderer.ctx)
        self.renderer = renderer
        ctx = renderer.ctx
        self._pixel = np.zeros(4, np.float32)
        with self.building():
            self._prog = self.own(ctx.program(vertex_shader=PICK_VERTEX, geometry_shader=PICK_GEOMETRY,
                                              fragment_shader=PICK_FRAGMENT))
            mesh = renderer.mesh
            positions = (mesh.skinned, f"3f {4 * (SKINNED_FLOATS - 3)}x", "in_position")
            self._vao = self.own(ctx.vertex_array(self._prog, [positions], index_buffer=mesh.ibo,
                                                  index_element_size=4))
            size = (renderer.width, renderer.height)
            self._fbo = self.own(ctx.framebuffer(self.own(ctx.texture(size, 4, dtype="f4")),
                                                 self.own(ctx.depth_renderbuffer(size))))

    def view_proj(self, camera: Camera) -> np.ndarray:
        """(4, 4) float32 world to clip of ``camera`` exactly as the renderer draws (rows flipped)."""
        return self.renderer.view_proj(camera)

    def pick(self, T: np.ndarray, camera: Camera, x: int, y: int) -> Pick | None:
        """The surface point under pixel (x, y) (image coordinates, top row 0) of the frame drawn
        with T (4m, 3) and camera; None on the background (or off the image)."""
        r = self.renderer
        if not (0 <= int(x) < r.width and 0 <= int(y) < r.height):
            return None
        ctx = self.ctx
        r.skin_every_vertex(T)
        self._prog["u_view_proj"].write(np.ascontiguousarray(self.view_proj(camera).T, np.float32))
        self._fbo.use()
        ctx.scissor = (int(x), int(y), 1, 1)
        self._fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        if r.cull_back_faces:
            ctx.enable(moderngl.CULL_FACE)
        ctx.front_face = "cw"  # the flipped projection mirrors the winding, as in Renderer.draw
        self._vao.render(moderngl.TRIANGLES)
        ctx.front_face = "ccw"
        ctx.disable(moderngl.CULL_FACE)
        ctx.disable(moderngl.DEPTH_TEST)
        ctx.scissor = None
        self._fbo.read_into(self._pixel, viewport=(int(x), int(y), 1, 1), components=4, dtype="f4")
        triangle = int(round(float(self._pixel[0]))) - 1
        if triangle < 0:
            return None
        bary = np.clip(self._pixel[1:4].astype(np.float64), 0.0, 1.0)
        bary /= max(bary.sum(), 1e-12)
        return Pick(triangle, (float(bary[0]), float(bary[1]), float(bary[2])))

    def coverage(self, T: np.ndarray, camera: Camera, out: np.ndarray) -> np.ndarray:
        """Where the character drawn with T (4m, 3) and camera covers the frame: ``out``
        (height, width) float32, top row first, filled with triangle index + 1 (0: background)."""
        ctx = self.ctx
        r = self.renderer
        r.skin_every_vertex(T)
        self._prog["u_view_proj"].write(np.ascontiguousarray(self.view_proj(camera).T, np.float32))
        self._fbo.use()
        self._fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        if r.cull_back_faces:
            ctx.enable(moderngl.CULL_FACE)
        ctx.front_face = "cw"
        self._vao.render(moderngl.TRIANGLES)
        ctx.front_face = "ccw"
        ctx.disable(moderngl.CULL_FACE)
        ctx.disable(moderngl.DEPTH_TEST)
        self._fbo.read_into(out, components=1, dtype="f4")
        return out

    def __enter__(self) -> "Picker":
        return self

    def __exit__(self, *exc) -> None:
        self.release()

