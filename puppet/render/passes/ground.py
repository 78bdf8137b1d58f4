"""Ground pass: the ground plane (a backdrop drawn once per camera) and the contact shadow.

The character is a few spheres that occlude the ground: vertices are grouped into clusters
(k-means on rest positions); each cluster becomes a sphere whose center is the exact mean of
its skinned vertices, linear in T: center_c = Q[c] @ T with Q[c, 4j:4j+4] = mean over i in c
of w_ij [v_i 1]. Their occlusion is drawn into a small texture that follows the character, and
a shadow square over the backdrop samples it: feet near the floor get a dark, tight contact
shadow and the body a soft one, for any pose and any number of handles.
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from puppet.render import shaders
from puppet.render.clusters import cluster_labels
from puppet.render.passes.base import GLPass

#: Backdrops (background and unshadowed ground) kept, one per camera: the loop's and a viewer's.
BACKDROPS = 2


@dataclass(frozen=True)
class ShadowSpheres:
    """Q: (k, 4m) float32 (centers = Q @ T, (k, 3)); radii: (k,) float32 [scene units]."""

    Q: np.ndarray
    radii: np.ndarray


def shadow_spheres(V: np.ndarray, W: np.ndarray, count: int = 24, iterations: int = 8) -> ShadowSpheres:
    """Spheres for V (n, 3) rest positions and W (n, m) weights; count: at most this many."""
    V = np.asarray(V, dtype=np.float64)
    W = np.asarray(W, dtype=np.float64)
    labels = cluster_labels(V, count, iterations)
    Vh = np.concatenate([V, np.ones((len(V), 1))], axis=1)
    Q, radii = [], []
    for c in range(int(labels.max()) + 1):
        members = labels == c
        size = members.sum()
        Q.append((W[members].T @ Vh[members] / size).reshape(-1))  # (m, 4) flattened as T's rows
        center = V[members].mean(axis=0)
        radii.append(np.sqrt(np.mean(np.sum((V[members] - center) ** 2, axis=1))))
    return ShadowSpheres(Q=np.array(Q, dtype=np.float32), radii=np.array(radii, dtype=np.float32))


def ground_axes(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit axes (3,) spanning the ground plane (perpendicular to the unit vector up)."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    a = np.cross(up, helper)
    a /= np.linalg.norm(a)
    return a, np.cross(up, a)


class GroundPass(GLPass):
    """The ground under V (n, 3) rest positions [scene units] and its contact shadow.

    spheres: the character's ShadowSpheres; center (3,), radius: the scene's extent; up: (3,)
    unit; background: display RGB; shadow_resolution: the occlusion texture's side [texels];
    width, height: the frame [px] (backdrops).
    """

    def __init__(self, ctx, V, spheres: ShadowSpheres, *, center, radius: float, up, background,
                 shadow_resolution: int, width: int, height: int):
        super().__init__(ctx)
        self._size = (width, height)
        self._background = background
        floor = float((V @ up).min())
        ground_center = center + up * (floor - center @ up - 1e-3 * radius)
        extent = 2.2 * radius
        self._shadow_Q = spheres.Q
        self._spheres = np.zeros((len(spheres.radii), 4), dtype=np.float32)
        self._spheres[:, 3] = spheres.radii * 1.5  # a wider, softer shadow than the bare clusters
        axis_a, axis_b = ground_axes(up)
        # The shadow texture covers the character's footprint plus a penumbra margin, and
        # follows the character: its center is the mean of the sphere centers, on the ground.
        footprint = np.abs((V - center) @ np.stack([axis_a, axis_b], axis=1)).max()
        shadow_half = float(footprint + 0.3 * radius)
        self._shadow_center = np.zeros(3, dtype=np.float32)
        self._shadow_mean = np.zeros(3, dtype=np.float32)
        self._floor_offset = ((ground_center @ up) * up).astype(np.float32)
        self._flatten = (np.eye(3) - np.outer(up, up)).astype(np.float32)
        uniforms = {
            "u_center": tuple(ground_center),
            "u_extent": extent,
            "u_shadow_a": tuple(axis_a * shadow_half),
            "u_shadow_b": tuple(axis_b * shadow_half),
            "u_shadow_half": shadow_half,
            "u_ground_color": (0.5, 0.5, 0.48),
            "u_background": background,
            "u_up": tuple(up),
        }
        corners = [ground_center + extent * (sa * axis_a + sb * axis_b)
                   for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        quad = np.array([corners[i] for i in (0, 1, 2, 0, 2, 3)], dtype=np.float32)  # two triangles
        self.backdrops: dict[bytes, moderngl.Framebuffer] = {}  # camera key -> backdrop
        with self.building():
            self._build(shadow_resolution, uniforms, quad)

    def _build(self, shadow_resolution: int, uniforms: dict, quad: np.ndarray) -> None:
        ctx = self.ctx
        self._occlusion_prog = self.own(ctx.program(
            vertex_shader=shaders.source(shaders.OCCLUSION_VERTEX),
            fragment_shader=shaders.source(shaders.OCCLUSION_FRAGMENT, SPHERES=len(self._spheres)),
        ))
        unit_quad = self.own(ctx.buffer(np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]], dtype=np.float32)))
        self._occlusion_vao = self.own(ctx.vertex_array(self._occlusion_prog, [(unit_quad, "2f", "in_corner")]))
        self._occlusion_texture = self.own(ctx.texture((shadow_resolution, shadow_resolution), 1, dtype="f1"))
        self._occlusion_texture.repeat_x = self._occlusion_texture.repeat_y = False
        self._occlusion_fbo = self.own(ctx.framebuffer(self._occlusion_texture))
        # The ground without its shadow is the backdrop of every frame (drawn once per camera and
        # copied in, when not multisampled); each frame draws only the shadow square over it.
        self._ground_prog = self.own(ctx.program(
            vertex_shader=shaders.source(shaders.GROUND_VERTEX),
            fragment_shader=shaders.source(shaders.LIGHTING, shaders.GROUND_FRAGMENT, SHADOWED=0),
        ))
        vbo = self.own(ctx.buffer(quad))
        self._ground_vao = self.own(ctx.vertex_array(self._ground_prog, [(vbo, "3f", "in_position")]))
        self._shadow_prog = self.own(ctx.program(
            vertex_shader=shaders.source(shaders.SHADOW_SQUARE_VERTEX),
            fragment_shader=shaders.source(shaders.LIGHTING, shaders.GROUND_FRAGMENT, SHADOWED=1),
        ))
        self._shadow_vao = self.own(ctx.vertex_array(self._shadow_prog, [(unit_quad, "2f", "in_corner")]))
        for prog in (self._occlusion_prog, self._ground_prog, self._shadow_prog):
            for name, value in uniforms.items():
                uniform = prog.get(name, None)
                if uniform is not None:
                    uniform.value = value
        self._shadow_prog["u_visibility"].value = 1

    def set_camera(self, view_proj_gl: np.ndarray, lights: dict) -> None:
        """Apply the (4, 4) column-major projection and the lights (uniform name -> value)."""
        for prog in (self._ground_prog, self._shadow_prog):
            prog["u_view_proj"].write(view_proj_gl)
            for name, value in lights.items():
                uniform = prog.get(name, None)
                if uniform is not None:
                    uniform.value = value

    def occlude(self, T: np.ndarray) -> None:
        """Move the spheres with T (4m, 3) and draw their ground occlusion into the texture."""
        np.matmul(self._shadow_Q, T, out=self._spheres[:, :3], casting="same_kind")
        np.mean(self._spheres[:, :3], axis=0, out=self._shadow_mean)
        np.matmul(self._flatten, self._shadow_mean, out=self._shadow_center)
        self._shadow_center += self._floor_offset
        self._occlusion_prog["u_spheres"].write(self._spheres)
        self._occlusion_prog["u_shadow_center"].write(self._shadow_center)
        self._shadow_prog["u_shadow_center"].write(self._shadow_center)
        self._occlusion_fbo.use()
        self._occlusion_vao.render(moderngl.TRIANGLE_STRIP)

    def lay_backdrop(self, target, camera_key: bytes, multisampled: bool) -> None:
        """Bind ``target`` with the background and the unshadowed ground in it, depth cleared:
        a copy of this camera's backdrop (drawn on its first use; the BACKDROPS cameras used
        last are kept: the loop's stays while a viewer orbits), or, multisampled, drawn in place."""
        ctx = self.ctx
        if multisampled:  # a single-sampled backdrop cannot be copied into a multisampled target
            target.use()
            target.clear(*self._background, 1.0)
            self._ground_vao.render(moderngl.TRIANGLES)
            return
        backdrop = self.backdrops.pop(camera_key, None)  # put back last: the newest used
        if backdrop is None:
            if len(self.backdrops) < BACKDROPS:
                color = self.own(ctx.renderbuffer(self._size, 4))
                depth = self.own(ctx.depth_renderbuffer(self._size))
                backdrop = self.own(ctx.framebuffer(color, depth))
            else:  # reuse the least recently used camera's
                backdrop = self.backdrops.pop(next(iter(self.backdrops)))
            backdrop.use()
            backdrop.clear(*self._background, 1.0)
            self._ground_vao.render(moderngl.TRIANGLES)  # depth test off: depth stays cleared
        self.backdrops[camera_key] = backdrop
        ctx.copy_framebuffer(target, backdrop)
        target.use()

    def draw_shadow(self) -> None:
        """The shadow square over the ground, into the bound framebuffer (after the mesh: the
        early depth test skips the shadow it hides)."""
        self._occlusion_texture.use(location=1)
        self._shadow_vao.render(moderngl.TRIANGLE_STRIP)
