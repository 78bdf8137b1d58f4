"""Offscreen renderer of a skinned character: skinning in the vertex shader, one shaded pass.

The renderer orchestrates its passes (puppet.render.passes: mesh, ground, bones, antialias),
each of which owns and releases its GL objects. Per frame (draw):
1. T (4m, 3) is copied into one uniform buffer of handle transforms (the only upload);
2. skinning pass: a vertex shader blends each vertex's handles (M @ T), skins its normal and
   (shading "vertex") lights it, each vertex drawn exactly once, into a transform-feedback
   buffer (also what skinned_positions() reads back, of every vertex);
3. contact shadow: the shadow spheres move (Q @ T, k x 4m, tiny) and their ground occlusion is
   drawn into a small texture;
4. the backdrop (background and unshadowed ground, drawn once per camera) is copied into the
   target framebuffer (multisampled with MSAA: drawn there), then the mesh (lit by key, fill,
   rim and a sky/ground ambient), the shadow square on the ground under the character, and the
   optional skeleton overlay;
5. MSAA resolve or FXAA filter (over the character's rectangle: a box bounding every skinned
   vertex computed from T on the CPU, puppet.render.bounds; nothing read back), and read back
   as RGB into a preallocated array.
The projection is flipped vertically so that the read-back rows are already in image order
(top row first): no copy, no flip.
"""

import moderngl
import numpy as np

from puppet.render.bounds import SkinnedBounds
from puppet.render.camera import Camera
from puppet.render.context import create_context
from puppet.render.errors import RenderInputError
from puppet.render.lod import simplified_triangles
from puppet.render.passes.antialias import AntialiasPass
from puppet.render.passes.bones import BonesPass
from puppet.render.passes.ground import GroundPass, shadow_spheres
from puppet.render.passes.mesh import SKINNED_FLOATS, MeshPass, check_mesh, vertex_normals
from puppet.render.skin_weights import check_weights

SKINNING_MODES = ("gpu", "cpu")
#: Where the character is lit: "vertex" (in the skinning pass, each vertex once; the colours are
#: interpolated: on the critter's ~1.5 px triangles the same look for a third less raster work
#: on llvmpipe), "pixel" (normals interpolated, lit per fragment; open surfaces seen from both
#: sides need it), or "auto" (vertex with GPU skinning and back faces culled, else pixel).
SHADING_MODES = ("auto", "vertex", "pixel")


class Renderer:
    """Draws a character skinned by T into RGB images.

    V: (n, 3) rest positions [scene units]; F: (f, 3) int triangles (counter-clockwise seen from
    outside); W: (n, m) weights of all m handles (skeleton bones, then extra weights).
    width, height: image size [px]; samples: MSAA samples (0 or 1: none; clamped to the
    driver's maximum); fxaa: antialias with one cheap full-screen filter pass instead (needs
    samples=0; on llvmpipe it costs a fraction of MSAA); camera: a Camera, or None to frame the rest pose automatically;
    skinning: "gpu" (vertex shader) or "cpu" (M @ T in NumPy, uploaded; face normals);
    up: (3,) world up; ground: draw the ground plane with its contact shadow;
    cull_back_faces: skip triangles facing away (right for closed meshes, about 2x fewer
    triangles to rasterize; turn off for open surfaces seen from both sides);
    albedo: linear RGB in [0, 1]; background: display RGB in [0, 1] (the clear color);
    weight_layout: "auto" (dense for small m, else per-vertex pairs), "dense" or "pairs";
    context: a moderngl.Context to share (else an EGL context is created, owned and released
    with the renderer); weight_tolerance: drop weights with |w| <= this (0: only exact zeros,
    so the shader computes M @ T exactly); shadow_sphere_count, shadow_resolution: contact
    shadow detail (the shadow is soft: 64 texels, filtered, differ from 128 by at most 5
    levels in the critter's frames, at a quarter of the pass's cost); bone_width_px: skeleton
    overlay width [px]; fxaa_region: "character" (filter only the rectangle on screen around
    the skinned mesh and its bones, bounded from T on the CPU) or "frame";
    fxaa_passes: "mark_edges" or "one_pass" (see FXAA_PASSES); shading: see SHADING_MODES.
    triangle_budget: draw at most about this many triangles: a mesh with more (closed) is drawn
    as its simplified copy (puppet.render.lod: same vertices, skinned as usual; picking still
    uses every triangle); None: the mesh itself.

    Per-frame state lives in preallocated arrays: `image` (height, width, 3) uint8 is the frame
    buffer draw() returns; skinned_positions() returns an array of the skinning pass's output
    (in V's vertex order) that its next call overwrites.
    """

    def __init__(
        self,
        V,
        F,
        W,
        *,
        width: int = 640,
        height: int = 480,
        samples: int = 4,
        camera: Camera | None = None,
        skinning: str = "gpu",
        up=(0.0, 1.0, 0.0),
        ground: bool = True,
        cull_back_faces: bool = True,
        fxaa: bool = False,
        albedo=(0.78, 0.52, 0.36),
        background=(0.16, 0.17, 0.2),
        context: moderngl.Context | None = None,
        weight_tolerance: float = 0.0,
        weight_layout: str = "auto",
        shadow_sphere_count: int = 24,
        shadow_resolution: int = 64,
        bone_width_px: float = 5.0,
        fxaa_region: str = "character",
        fxaa_passes: str = "mark_edges",
        shading: str = "auto",
        triangle_budget: int | None = None,
    ):
        if skinning not in SKINNING_MODES:
            raise RenderInputError(f"skinning: expected one of {SKINNING_MODES}, got {skinning!r}")
        if int(width) < 1 or int(height) < 1:
            raise RenderInputError(f"width, height: must be positive, got {width} x {height}")
        if shading not in SHADING_MODES:
            raise RenderInputError(f"shading: expected one of {SHADING_MODES}, got {shading!r}")
        if shading == "vertex" and (skinning != "gpu" or not cull_back_faces):
            raise RenderInputError("shading: 'vertex' needs skinning='gpu' and cull_back_faces=True "
                                   "(back faces lit per vertex would show the front's light)")
        if shading == "auto":
            shading = "vertex" if skinning == "gpu" and cull_back_faces else "pixel"
        self.shading = shading
        V, F, W = check_mesh(V, F, W)
        W = check_weights(W)
        normals = vertex_normals(V, F.astype(np.int64))
        spheres = shadow_spheres(V, W, count=shadow_sphere_count) if ground else None  # caller's order
        # The triangles drawn (all, or a simplified copy on the caller's vertices), and the
        # vertices in the renderer's own order: those drawn first, so that a frame skins only
        # them (``_skin_count``); picking and skinned_positions() skin them all.
        drawn = F
        if triangle_budget is not None and len(F) > int(triangle_budget):
            simplified = simplified_triangles(V, F, int(triangle_budget))
            drawn = F if len(simplified) == len(F) else simplified.astype(np.uint32)  # open: all
        self.drawn_triangles = len(drawn)
        self._rank = None  # caller's vertex -> renderer's (None: the same order)
        self._skin_count = len(V)
        if len(drawn) < len(F):
            used = np.zeros(len(V), bool)
            used[drawn.ravel()] = True
            order = np.concatenate([np.flatnonzero(used), np.flatnonzero(~used)])
            self._rank = np.empty(len(V), np.int64)
            self._rank[order] = np.arange(len(V))
            V, W, normals = V[order], W[order], normals[order]
            F, drawn = self._rank[F].astype(np.uint32), self._rank[drawn].astype(np.uint32)
            self._skin_count = int(used.sum())
        self.width, self.height = int(width), int(height)
        self.skinning = skinning
        self.n, self.m = W.shape
        self.ground = bool(ground)
        self.cull_back_faces = bool(cull_back_faces)
        self.bone_width_px = float(bone_width_px)
        self.fxaa = bool(fxaa)
        self.fxaa_region = fxaa_region
        self.fxaa_passes = fxaa_passes
        self._up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
        self._background = tuple(float(c) for c in background)
        # Scene extent, for framing, clip planes and the ground.
        lo, hi = V.min(axis=0), V.max(axis=0)
        self._center = (lo + hi) / 2
        self._radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
        # FXAA over the character's rectangle: the drawn vertices' box, bounded from T alone.
        self._bounds = (SkinnedBounds(V[: self._skin_count], W[: self._skin_count])
                        if self.fxaa and fxaa_region == "character" else None)

        # Per-frame buffers (allocated once).
        self.image = np.zeros((self.height, self.width, 3), dtype=np.uint8)
        self._captured = np.zeros((self.n, SKINNED_FLOATS), dtype=np.float32)
        self._in_caller_order = None if self._rank is None else np.zeros((self.n, SKINNED_FLOATS), np.float32)
        self._captured_positions = np.zeros((self.n, 3), dtype=np.float32)
        self._captured_normals = np.zeros((self.n, 3), dtype=np.float32)

        self._owns_ctx = context is None
        self.ctx = create_context() if context is None else context
        ctx = self.ctx
        self._released = False
        self._passes = []  # built so far: released newest first, also when a later one fails
        self.samples = 0 if samples <= 1 else min(int(samples), int(ctx.max_samples))
        try:
            self.mesh = self._add(MeshPass(
                ctx, V, F, drawn, W, normals, skin_count=self._skin_count, skinning=skinning, shading=shading,
                weight_tolerance=weight_tolerance, weight_layout=weight_layout, albedo=albedo))
            self.ground_pass = None if spheres is None else self._add(GroundPass(
                ctx, V, spheres, center=self._center, radius=self._radius, up=self._up,
                background=self._background, shadow_resolution=shadow_resolution,
                width=self.width, height=self.height))
            self.bones = self._add(BonesPass(ctx, m=self.m, width_px=self.bone_width_px,
                                             width=self.width, height=self.height))
            self.antialias = self._add(AntialiasPass(
                ctx, width=self.width, height=self.height, samples=self.samples, fxaa=self.fxaa,
                fxaa_region=fxaa_region, fxaa_passes=fxaa_passes))
            self.camera = camera if camera is not None else Camera.framing(V, aspect=self.width / self.height,
                                                                           up=self._up)
        except BaseException:
            self.release()
            raise

    @property
    def weight_layout(self) -> str:
        """"dense" or "pairs": how the weights reach the skinning shader."""
        return self.mesh.weight_layout

    @property
    def max_weights_per_vertex(self) -> int:
        return self.mesh.max_weights_per_vertex

    @property
    def dropped_weight_abs_max(self) -> float:
        return self.mesh.dropped_weight_abs_max

    def _add(self, render_pass):
        self._passes.append(render_pass)
        return render_pass

    # -- camera ----------------------------------------------------------------------------------

    def view_proj(self, camera: Camera) -> np.ndarray:
        """(4, 4) float32 world to clip of ``camera`` as this renderer draws (rows flipped, so
        that read-back rows come top row first)."""
        flip = np.diag([1.0, -1.0, 1.0, 1.0]).astype(np.float32)
        return flip @ camera.projection_matrix(self.width / self.height, self._radius) @ camera.view_matrix()

    @property
    def camera(self) -> Camera:
        """The camera; assign a Camera (again, after changing its fields) to apply it."""
        return self._camera

    @camera.setter
    def camera(self, camera: Camera) -> None:
        if not isinstance(camera, Camera):
            raise RenderInputError(f"camera: expected a Camera, got {type(camera).__name__}")
        self._camera = camera
        self._view_proj_gl = np.ascontiguousarray(self.view_proj(camera).T, dtype=np.float32)  # column-major
        right, up, back = camera.basis()
        key = 0.55 * right + 0.75 * up + 0.6 * back  # above, right of and in front of the character
        fill = -0.7 * right + 0.1 * up + 0.5 * back
        lights = {
            "u_view_dir": back,
            "u_up": self._up,
            "u_key_dir": key / np.linalg.norm(key),
            "u_fill_dir": fill / np.linalg.norm(fill),
            "u_sky": np.array([0.62, 0.68, 0.8]),
            "u_ground_bounce": np.array([0.32, 0.28, 0.25]),
        }
        lights = {name: tuple(float(x) for x in value) for name, value in lights.items()}
        self._camera_key = self._view_proj_gl.tobytes()  # the backdrop drawn for this camera
        self.mesh.set_camera(self._view_proj_gl, lights)
        if self.ground_pass is not None:
            self.ground_pass.set_camera(self._view_proj_gl, lights)
        self.bones.set_camera(self._view_proj_gl)

    # -- per frame -------------------------------------------------------------------------------

    def skin_every_vertex(self, T: np.ndarray) -> None:
        """Upload T (4m, 3) and skin every vertex into the mesh pass's ``skinned`` buffer (what
        picking and the read-backs below use)."""
        self.mesh.upload(T)
        self.mesh.skin(self.antialias.resolved, every_vertex=True)

    def _captured_in_caller_order(self) -> np.ndarray:
        """(n, SKINNED_FLOATS) of every vertex skinned (``skin_every_vertex``), in the caller's order."""
        self.mesh.skinned.read_into(self._captured)
        if self._rank is None:
            return self._captured
        np.take(self._captured, self._rank, axis=0, out=self._in_caller_order)
        return self._in_caller_order

    def skinned_positions(self, T: np.ndarray) -> np.ndarray:
        """Positions (n, 3) float32 that the skinning vertex shader writes and draw() renders
        (read back from its transform feedback buffer).

        Returns a C-contiguous array that the next call overwrites; copy it to keep it.
        """
        self.skin_every_vertex(T)
        np.copyto(self._captured_positions, self._captured_in_caller_order()[:, :3])
        return self._captured_positions

    def skinned_normals(self, T: np.ndarray) -> np.ndarray:
        """Unnormalized normals (n, 3) float32 of the skinning pass (cofactor of the blended
        linear part times the rest normal), reused like skinned_positions()'s."""
        self.skin_every_vertex(T)
        np.copyto(self._captured_normals, self._captured_in_caller_order()[:, 3:6])
        return self._captured_normals

    def draw(self, T: np.ndarray, *, bones=None, bone_states=None, out: np.ndarray | None = None) -> np.ndarray:
        """Render the character skinned by T and read it back: ``render`` then ``read``.

        T: (4m, 3) float32, rows 4j..4j+3 are handle j's 3x4 affine transform transposed
        (v' = [v 1] @ T[4j:4j+4]). bones: optional (b, 2, 3) rest heads and tails, bone i moves
        with handle i, drawn over the character; bone_states: b states ("sensed", "relative",
        "free", "fault") or None. out: optional (height, width, 3) uint8 C-contiguous array.
        Returns (height, width, 3) uint8 RGB, top row first: `out`, or the renderer's own
        `image` array, which the next draw overwrites.
        """
        self.render(T, bones=bones, bone_states=bone_states)
        return self.read(out)

    def render(self, T: np.ndarray, *, bones=None, bone_states=None) -> None:
        """Issue every pass of one frame (skinning, shadow, ground, mesh, bones, antialias) without
        waiting for it: on llvmpipe this is the vertex work and triangle binning on the calling
        thread; the rasterizer threads then fill the tiles while ``read`` waits. Arguments as draw's."""
        ctx = self.ctx
        target = self.antialias.target
        blocks = self.mesh.upload(T)
        self.mesh.prepare(T, self.antialias.resolved)
        ctx.disable(moderngl.CULL_FACE)
        ctx.disable(moderngl.DEPTH_TEST)
        if self.ground_pass is not None:
            self.ground_pass.occlude(T)
            self.ground_pass.lay_backdrop(target, self._camera_key, multisampled=bool(self.samples))
        else:
            target.use()
            target.clear(*self._background, 1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        self.mesh.draw(self.cull_back_faces)
        if self.ground_pass is not None:
            self.ground_pass.draw_shadow()
        if bones is not None:
            ctx.disable(moderngl.DEPTH_TEST)
            self.bones.draw(bones, bone_states, blocks)
        ctx.front_face = "ccw"
        ctx.disable(moderngl.DEPTH_TEST)
        box = None if self._bounds is None else self._character_box(T, with_bones=bones is not None)
        margin = self.bone_width_px if bones is not None else 0.0
        self.antialias.finish(box, self._view_proj_gl, margin)

    def _character_box(self, T: np.ndarray, with_bones: bool) -> np.ndarray:
        """(2, 3) world [min, max] holding every drawn vertex skinned by T and the drawn bones."""
        box = self._bounds.box(T)
        if with_bones and self.bones.posed is not None:
            ends = self.bones.posed[:, :6].reshape(-1, 3)
            np.minimum(box[0], ends.min(axis=0), out=box[0])
            np.maximum(box[1], ends.max(axis=0), out=box[1])
        return box

    def read(self, out: np.ndarray | None = None) -> np.ndarray:
        """Wait for the frame ``render`` issued and read it back as (height, width, 3) uint8 RGB,
        top row first, into ``out`` or the renderer's own ``image`` array."""
        image = self.image if out is None else out
        if image.shape != self.image.shape or image.dtype != np.uint8 or not image.flags.c_contiguous:
            raise RenderInputError(
                f"out: expected C-contiguous uint8 {self.image.shape}, got {image.dtype} {image.shape}"
            )
        self.antialias.resolved.read_into(image, components=3, alignment=1)
        return image

    # -- lifetime --------------------------------------------------------------------------------

    @property
    def gl_renderer(self) -> str:
        """GL_RENDERER of the context, e.g. 'llvmpipe (LLVM 15.0.6, 256 bits)'."""
        return str(self.ctx.info["GL_RENDERER"])

    def release(self) -> None:
        """Free every pass's GL objects, newest pass first (and the context when it owns it)."""
        if self._released:
            return
        self._released = True
        for render_pass in reversed(self._passes):
            render_pass.release()
        self._passes.clear()
        if self._owns_ctx:
            self.ctx.release()

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.release()
