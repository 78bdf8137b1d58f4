"""Offscreen renderer of a skinned character: skinning in the vertex shader, one shaded pass.

Per frame (draw):
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
5. MSAA resolve or FXAA filter, and read back as RGB into a preallocated array.
The projection is flipped vertically so that the read-back rows are already in image order
(top row first): no copy, no flip.
"""

import moderngl
import numpy as np

from puppet.render import shaders
from puppet.render.camera import Camera
from puppet.render.contact_shadow import shadow_spheres
from puppet.render.context import create_context
from puppet.render.errors import RenderError, RenderInputError
from puppet.render.lod import simplified_triangles
from puppet.render.overlay import BONE_CORNERS, rest_segments, state_color
from puppet.render.skin_weights import (TEXTURE_WIDTH, attribute_slots, check_weights, lbs_matrix,
                                        pack_weights)

SKINNING_MODES = ("gpu", "cpu")
#: Where the character is lit: "vertex" (in the skinning pass, each vertex once; the colours are
#: interpolated: on the critter's ~1.5 px triangles the same look for a third less raster work
#: on llvmpipe), "pixel" (normals interpolated, lit per fragment; open surfaces seen from both
#: sides need it), or "auto" (vertex with GPU skinning and back faces culled, else pixel).
SHADING_MODES = ("auto", "vertex", "pixel")
#: Floats per vertex in the skinning pass's output: position, normal, colour.
SKINNED_FLOATS = 9
WEIGHT_LAYOUTS = ("auto", "dense", "pairs")
#: Rows per block in the bounding box reduction of the skinned positions.
BOX_BLOCK = 64
#: Where FXAA filters: the character's rectangle on screen (the rest of the frame, ground and
#: background, has no hard edge), or the whole frame.
FXAA_REGIONS = ("character", "frame")
#: How FXAA runs: "mark_edges" (edge pixels marked in the depth buffer, then the blur only
#: there: on llvmpipe half the cost of one pass) or "one_pass" (every pixel tests and blurs).
FXAA_PASSES = ("mark_edges", "one_pass")
#: Backdrops (background and unshadowed ground) kept, one per camera: the loop's and a viewer's.
BACKDROPS = 2
#: Up to this many handles the weights go to the shader densely (13 vec4 attributes at most).
DENSE_MAX_HANDLES = 52


def _vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (n, 3) float32 of the rest mesh (zero for lone vertices)."""
    face_normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    normals = np.zeros_like(V)
    for corner in range(3):
        np.add.at(normals, F[:, corner], face_normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return (normals / np.maximum(length, 1e-20)).astype(np.float32)


def _check_mesh(V, F, W) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    V = np.asarray(V)
    F = np.asarray(F)
    W = np.asarray(W)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
        raise RenderInputError(f"V: expected (n, 3) rest positions, got shape {V.shape}")
    if not np.all(np.isfinite(V)):
        raise RenderInputError(f"V: non-finite position at vertex {int(np.argwhere(~np.isfinite(V))[0, 0])}")
    if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0 or not np.issubdtype(F.dtype, np.integer):
        raise RenderInputError(f"F: expected (f, 3) integer triangles, got shape {F.shape}, dtype {F.dtype}")
    if F.min() < 0 or F.max() >= len(V):
        raise RenderInputError(f"F: vertex index out of range [0, {len(V)}): min {F.min()}, max {F.max()}")
    if W.ndim != 2 or W.shape[0] != len(V):
        raise RenderInputError(f"W: expected ({len(V)}, m) weights for {len(V)} vertices, got shape {W.shape}")
    return V.astype(np.float64), F.astype(np.uint32), W


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
    the skinned mesh and its bones) or "frame";
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
        V, F, W = _check_mesh(V, F, W)
        W = check_weights(W)
        spheres = shadow_spheres(V, W, count=shadow_sphere_count)  # in the caller's vertex order
        normals = _vertex_normals(V, F.astype(np.int64))
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
        self._up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
        self._owns_ctx = context is None
        self.ctx = create_context() if context is None else context
        ctx = self.ctx
        self._released = False

        max_block = int(ctx.info["GL_MAX_UNIFORM_BLOCK_SIZE"])
        if 48 * self.m > max_block:
            raise RenderError(
                f"W: {self.m} handles need {48 * self.m} bytes of uniforms, the driver allows {max_block}"
            )

        # Scene extent, for framing, clip planes and the ground.
        lo, hi = V.min(axis=0), V.max(axis=0)
        self._center = (lo + hi) / 2
        self._radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
        floor = float((V @ self._up).min())
        self._ground_center = self._center + self._up * (floor - self._center @ self._up - 1e-3 * self._radius)
        self._ground_extent = 2.2 * self._radius

        # Per-frame buffers (allocated once).
        self._rows = np.zeros((self.m, 3, 4), dtype=np.float32)  # A_j = T block j transposed
        self.image = np.zeros((self.height, self.width, 3), dtype=np.uint8)

        # Skinning data: rest positions and normals, and the weights in one of two layouts.
        # "dense": every w_ij as attributes, the shader sums over all handles (uniform reads,
        # about 3x faster per term on llvmpipe than per-vertex handle lookups); "pairs": each
        # vertex's nonzero (weight, handle) pairs in attribute slots, those that do not fit
        # spilled into a texture with per-vertex spans. Both are exact (only zeros are skipped).
        # Measured on the critter (26 handles, 8.3 weights above 1e-6 per vertex, 18 at most):
        # dense 1.5 ms of the loop thread's CPU per frame, pairs above 1e-6 3.0 ms; a per-vec4
        # "skip zero weights" branch is 4x slower (llvmpipe runs both sides); splitting the
        # vertices into ranges with few handles each needs 70+ draws for 0.6x the work.
        keep = np.abs(W) > weight_tolerance
        self.max_weights_per_vertex = int(keep.sum(axis=1).max())
        self.dropped_weight_abs_max = float(np.abs(W[~keep]).max()) if not keep.all() else 0.0
        self._vbo_rest = ctx.buffer(V.astype(np.float32))
        self._vbo_normal = ctx.buffer(normals)
        if weight_layout not in WEIGHT_LAYOUTS:
            raise RenderInputError(f"weight_layout: expected one of {WEIGHT_LAYOUTS}, got {weight_layout!r}")
        if weight_layout == "dense" and self.m > DENSE_MAX_HANDLES:
            raise RenderInputError(f"weight_layout: dense takes at most {DENSE_MAX_HANDLES} handles, W has {self.m}")
        if weight_layout == "auto":  # a dense term costs about a third of a pair's (no gathers)
            slots = attribute_slots(self.max_weights_per_vertex)
            weight_layout = "dense" if self.m <= min(DENSE_MAX_HANDLES, 3 * slots) else "pairs"
        self.weight_layout = weight_layout
        dense = weight_layout == "dense"
        # Packing the pairs sorts every row (about 0.1 s for the critter): only when used.
        packed = None if dense else pack_weights(W, tolerance=weight_tolerance)
        self._spill = not dense and packed.spilled > 0
        self._weight_buffers = []
        if dense:
            groups = -(-self.m // 4)
            dense_weights = np.zeros((self.n, 4 * groups), dtype=np.float32)
            dense_weights[:, : self.m] = np.where(keep, W, 0.0)
            self._weight_buffers.append(ctx.buffer(dense_weights))
            skin_content = [
                (self._weight_buffers[0], " ".join(["4f"] * groups), *[f"in_dense{g}" for g in range(groups)])
            ]
            skin = shaders.dense_skin_chunk(self.m)
        else:
            groups = packed.slots // 4
            handle_groups = packed.slot_handles.shape[1] // 4
            self._weight_buffers += [ctx.buffer(packed.slot_weights), ctx.buffer(packed.slot_handles)]
            skin_content = [
                (self._weight_buffers[0], " ".join(["4f"] * groups), *[f"in_weight{g}" for g in range(groups)]),
                (
                    self._weight_buffers[1],
                    " ".join(["4u"] * handle_groups),
                    *[f"in_handles{h}" for h in range(handle_groups)],
                ),
            ]
            if self._spill:
                self._weight_buffers.append(ctx.buffer(packed.spans))
                skin_content.append((self._weight_buffers[-1], "2u", "in_span"))
            skin = shaders.skin_chunk(packed.slots, self._spill)
        self._ibo = ctx.buffer(F)  # every triangle: picking
        self._draw_ibo = self._ibo if drawn is F else ctx.buffer(drawn)
        entries = np.zeros((1, TEXTURE_WIDTH, 2), np.float32) if packed is None else packed.entries
        self._weights = ctx.texture((TEXTURE_WIDTH, entries.shape[0]), 2, entries, dtype="f4")
        self._weights.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._ubo = ctx.buffer(reserve=self._rows.nbytes)
        defines = dict(HANDLES=self.m, WEIGHTS_WIDTH=TEXTURE_WIDTH, WEIGHTS_SHIFT=TEXTURE_WIDTH.bit_length() - 1,
                       VERTEX_LIGHTING=int(shading == "vertex"))

        self._skin_prog = ctx.program(
            vertex_shader=shaders.source(shaders.LIGHTING, skin, shaders.SKIN_VERTEX, **defines),
            varyings=["out_position", "out_normal", "out_color"],
        )
        self._bind_skin(self._skin_prog)
        self._skin_vao = ctx.vertex_array(
            self._skin_prog,
            [(self._vbo_rest, "3f", "in_position"), (self._vbo_normal, "3f", "in_normal"), *skin_content],
        )
        self._skinned = ctx.buffer(reserve=self.n * 4 * SKINNED_FLOATS)  # (position, normal, colour)
        # Read-back of the skinning pass, padded to whole blocks of BOX_BLOCK rows (copies of row
        # 0) so that the bounding box reduces along long contiguous rows (numpy reduces (n, 3)
        # along axis 0 about 50x slower than along rows).
        padded_rows = -(-self.n // BOX_BLOCK) * BOX_BLOCK
        self._captured_padded = np.zeros((padded_rows, SKINNED_FLOATS), dtype=np.float32)
        self._captured = self._captured_padded[: self.n]
        self._drawn_rows = -(-self._skin_count // BOX_BLOCK) * BOX_BLOCK  # the drawn vertices, padded
        self._in_caller_order = None if self._rank is None else np.zeros((self.n, SKINNED_FLOATS), np.float32)
        self._box_lanes = np.zeros((2, BOX_BLOCK * SKINNED_FLOATS), dtype=np.float32)
        self._captured_positions = np.zeros((self.n, 3), dtype=np.float32)
        self._captured_normals = np.zeros((self.n, 3), dtype=np.float32)

        if shading == "vertex":
            self._mesh_prog = ctx.program(
                vertex_shader=shaders.source(shaders.MESH_LIT_VERTEX),
                fragment_shader=shaders.source(shaders.LIGHTING, shaders.MESH_LIT_FRAGMENT),
            )
            content = [(self._skinned, "3f 12x 3f", "in_position", "in_color")]
        elif skinning == "gpu":
            self._mesh_prog = ctx.program(
                vertex_shader=shaders.source(shaders.MESH_VERTEX),
                fragment_shader=shaders.source(shaders.LIGHTING, shaders.MESH_FRAGMENT, FACE_NORMALS=0),
            )
            content = [(self._skinned, "3f 3f 12x", "in_position", "in_normal")]
        else:
            self._M = lbs_matrix(V, W)
            self._positions = np.zeros((self.n, 3), dtype=np.float32)
            self._vbo_positions = ctx.buffer(reserve=self._positions.nbytes, dynamic=True)
            self._mesh_prog = ctx.program(
                vertex_shader=shaders.source(shaders.MESH_CPU_VERTEX),
                fragment_shader=shaders.source(shaders.LIGHTING, shaders.MESH_FRAGMENT, FACE_NORMALS=1),
            )
            content = [(self._vbo_positions, "3f", "in_position")]
        self._mesh_vao = ctx.vertex_array(self._mesh_prog, content, index_buffer=self._draw_ibo, index_element_size=4)
        self._lit_prog = self._skin_prog if shading == "vertex" else self._mesh_prog  # has the lights
        self._lit_prog["u_albedo"].value = tuple(float(c) for c in albedo)
        self._background = tuple(float(c) for c in background)

        # Ground plane with contact shadow spheres, their occlusion drawn into a small texture.
        self._shadow_Q = spheres.Q
        self._spheres = np.zeros((len(spheres.radii), 4), dtype=np.float32)
        self._spheres[:, 3] = spheres.radii * 1.5  # a wider, softer shadow than the bare clusters
        axis_a, axis_b = self._ground_axes()
        # The shadow texture covers the character's footprint plus a penumbra margin, and
        # follows the character: its center is the mean of the sphere centers, on the ground.
        footprint = np.abs((V - self._center) @ np.stack([axis_a, axis_b], axis=1)).max()
        self._shadow_half = float(footprint + 0.3 * self._radius)
        self._shadow_center = np.zeros(3, dtype=np.float32)
        self._shadow_mean = np.zeros(3, dtype=np.float32)
        self._floor_offset = ((self._ground_center @ self._up) * self._up).astype(np.float32)
        self._flatten = (np.eye(3) - np.outer(self._up, self._up)).astype(np.float32)
        ground_uniforms = {
            "u_center": tuple(self._ground_center),
            "u_extent": self._ground_extent,
            "u_shadow_a": tuple(axis_a * self._shadow_half),
            "u_shadow_b": tuple(axis_b * self._shadow_half),
            "u_shadow_half": self._shadow_half,
            "u_ground_color": (0.5, 0.5, 0.48),
            "u_background": self._background,
            "u_up": tuple(self._up),
        }
        self._occlusion_prog = ctx.program(
            vertex_shader=shaders.source(shaders.OCCLUSION_VERTEX),
            fragment_shader=shaders.source(shaders.OCCLUSION_FRAGMENT, SPHERES=len(self._spheres)),
        )
        self._occlusion_quad = ctx.buffer(np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]], dtype=np.float32))
        self._occlusion_vao = ctx.vertex_array(self._occlusion_prog, [(self._occlusion_quad, "2f", "in_corner")])
        self._occlusion_texture = ctx.texture((shadow_resolution, shadow_resolution), 1, dtype="f1")
        self._occlusion_texture.repeat_x = self._occlusion_texture.repeat_y = False
        self._occlusion_fbo = ctx.framebuffer(self._occlusion_texture)
        # The ground without its shadow is the backdrop of every frame (drawn once per camera and
        # copied in, when not multisampled); each frame draws only the shadow square over it.
        self._ground_prog = ctx.program(
            vertex_shader=shaders.source(shaders.GROUND_VERTEX),
            fragment_shader=shaders.source(shaders.LIGHTING, shaders.GROUND_FRAGMENT, SHADOWED=0),
        )
        self._ground_vbo = ctx.buffer(self._ground_quad(axis_a, axis_b))
        self._ground_vao = ctx.vertex_array(self._ground_prog, [(self._ground_vbo, "3f", "in_position")])
        self._shadow_prog = ctx.program(
            vertex_shader=shaders.source(shaders.SHADOW_SQUARE_VERTEX),
            fragment_shader=shaders.source(shaders.LIGHTING, shaders.GROUND_FRAGMENT, SHADOWED=1),
        )
        self._shadow_vao = ctx.vertex_array(self._shadow_prog, [(self._occlusion_quad, "2f", "in_corner")])
        for prog in (self._occlusion_prog, self._ground_prog, self._shadow_prog):
            for name, value in ground_uniforms.items():
                uniform = prog.get(name, None)
                if uniform is not None:
                    uniform.value = value
        self._shadow_prog["u_visibility"].value = 1
        self._backdrops: dict[bytes, moderngl.Framebuffer] = {}  # camera key -> backdrop

        # Skeleton overlay (instance data grows on demand).
        self._bone_prog = ctx.program(
            vertex_shader=shaders.source(shaders.BONE_VERTEX), fragment_shader=shaders.source(shaders.BONE_FRAGMENT)
        )
        self._bone_corners = ctx.buffer(BONE_CORNERS)
        self._bone_vbo = None
        self._bone_vao = None
        self._bone_source = None
        self._bone_rest = None
        self._bone_instances = None

        # Framebuffers: the scene is drawn into _target (multisampled with MSAA, a texture with
        # FXAA), then resolved (MSAA) or filtered (FXAA) into _resolved, which is read back.
        self.samples = 0 if samples <= 1 else min(int(samples), int(ctx.max_samples))
        self.fxaa = bool(fxaa)
        if fxaa_region not in FXAA_REGIONS:
            raise RenderInputError(f"fxaa_region: expected one of {FXAA_REGIONS}, got {fxaa_region!r}")
        self.fxaa_region = fxaa_region
        if fxaa_passes not in FXAA_PASSES:
            raise RenderInputError(f"fxaa_passes: expected one of {FXAA_PASSES}, got {fxaa_passes!r}")
        self.fxaa_passes = fxaa_passes
        self._fxaa_vaos = []
        self._fxaa_progs = []
        self._box = np.zeros((2, 3), dtype=np.float32)
        self._corners = np.ones((8, 4), dtype=np.float32)
        self._clip = np.zeros((8, 4), dtype=np.float32)
        if self.fxaa and self.samples:
            raise RenderInputError(f"fxaa: use it instead of MSAA (samples=0), got samples={samples}")
        size = (self.width, self.height)
        self._resolved = ctx.framebuffer(ctx.renderbuffer(size, 4), ctx.depth_renderbuffer(size))
        self._fxaa_vao = None
        if self.samples:
            self._target = ctx.framebuffer(
                ctx.renderbuffer(size, 4, samples=self.samples), ctx.depth_renderbuffer(size, samples=self.samples)
            )
        elif self.fxaa:
            self._aliased = ctx.texture(size, 4)
            self._aliased.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self._aliased.repeat_x = self._aliased.repeat_y = False
            self._target = ctx.framebuffer(self._aliased, ctx.depth_renderbuffer(size))
            fragments = {"one_pass": [shaders.FXAA_FRAGMENT],
                         "mark_edges": [shaders.FXAA_MARK_FRAGMENT, shaders.FXAA_BLUR_FRAGMENT]}[fxaa_passes]
            self._fxaa_progs = [ctx.program(vertex_shader=shaders.source(shaders.FXAA_VERTEX),
                                            fragment_shader=shaders.source(fragment)) for fragment in fragments]
            for prog in self._fxaa_progs:
                if "u_texel" in prog:  # the mark pass does not blur: no texel size
                    prog["u_texel"].value = (1.0 / self.width, 1.0 / self.height)
                prog["u_image"].value = 2
            self._fxaa_vaos = [ctx.vertex_array(prog, []) for prog in self._fxaa_progs]
            self._fxaa_vao = self._fxaa_vaos[-1]
        else:
            self._target = self._resolved

        self.camera = camera if camera is not None else Camera.framing(V, aspect=self.width / self.height, up=self._up)

    # -- setup helpers ---------------------------------------------------------------------------

    def _bind_skin(self, prog: moderngl.Program) -> None:
        prog["Handles"].binding = 0
        if self._spill:
            prog["u_weights"].value = 0

    def _ground_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Two unit axes (3,) spanning the ground plane (perpendicular to up)."""
        helper = np.array([1.0, 0.0, 0.0]) if abs(self._up[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
        a = np.cross(self._up, helper)
        a /= np.linalg.norm(a)
        return a, np.cross(self._up, a)

    def _ground_quad(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Two triangles (6, 3) float32 spanning the ground square, perpendicular to up."""
        e = self._ground_extent
        c = self._ground_center
        corners = [c + e * (sa * a + sb * b) for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        return np.array([corners[i] for i in (0, 1, 2, 0, 2, 3)], dtype=np.float32)

    @property
    def camera(self) -> Camera:
        """The camera; assign a Camera (again, after changing its fields) to apply it."""
        return self._camera

    @camera.setter
    def camera(self, camera: Camera) -> None:
        if not isinstance(camera, Camera):
            raise RenderInputError(f"camera: expected a Camera, got {type(camera).__name__}")
        self._camera = camera
        flip = np.diag([1.0, -1.0, 1.0, 1.0]).astype(np.float32)  # rows come back top row first
        view_proj = flip @ camera.projection_matrix(self.width / self.height, self._radius) @ camera.view_matrix()
        self._view_proj_gl = np.ascontiguousarray(view_proj.T, dtype=np.float32)  # column-major for GL
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
        for prog in (self._mesh_prog, self._ground_prog, self._shadow_prog):
            prog["u_view_proj"].write(self._view_proj_gl)
        self._camera_key = self._view_proj_gl.tobytes()  # the backdrop drawn for this camera
        for prog in (self._lit_prog, self._ground_prog, self._shadow_prog):
            for name, value in lights.items():
                uniform = prog.get(name, None)  # None where the shader does not use it
                if uniform is not None:
                    uniform.value = tuple(float(x) for x in value)
        self._bone_prog["u_view_proj"].write(self._view_proj_gl)
        self._bone_prog["u_viewport"].value = (float(self.width), float(self.height))

    # -- per frame -------------------------------------------------------------------------------

    def _upload(self, T: np.ndarray) -> np.ndarray:
        """Check T (4m, 3) and upload it once; returns T viewed as (m, 4, 3)."""
        if not isinstance(T, np.ndarray) or T.shape != (4 * self.m, 3):
            shape = getattr(T, "shape", None)
            raise RenderInputError(f"T: expected shape ({4 * self.m}, 3) for {self.m} handles, got {shape}")
        blocks = T.reshape(self.m, 4, 3)
        np.copyto(self._rows, blocks.transpose(0, 2, 1), casting="same_kind")
        self._ubo.write(self._rows)
        return blocks

    def _bind_frame_resources(self) -> None:
        self._ubo.bind_to_uniform_block(0)
        self._weights.use(location=0)

    def _skin(self, every_vertex: bool = False) -> None:
        """Skinning pass: the vertex shader writes (position, normal, colour) of each vertex drawn
        (every vertex: ``every_vertex``, as picking and skinned_positions() need) once."""
        self._bind_frame_resources()
        self._resolved.use()  # EGL without a surface has no default framebuffer to fall back to
        count = self.n if every_vertex else self._skin_count
        self._skin_vao.transform(self._skinned, mode=moderngl.POINTS, vertices=count)

    def _captured_in_caller_order(self) -> np.ndarray:
        """(n, SKINNED_FLOATS) of every vertex skinned (``_skin(True)``), in the caller's order."""
        self._skinned.read_into(self._captured)
        if self._rank is None:
            return self._captured
        np.take(self._captured, self._rank, axis=0, out=self._in_caller_order)
        return self._in_caller_order

    def skinned_positions(self, T: np.ndarray) -> np.ndarray:
        """Positions (n, 3) float32 that the skinning vertex shader writes and draw() renders
        (read back from its transform feedback buffer).

        Returns a C-contiguous array that the next call overwrites; copy it to keep it.
        """
        self._upload(T)
        self._skin(every_vertex=True)
        np.copyto(self._captured_positions, self._captured_in_caller_order()[:, :3])
        return self._captured_positions

    def skinned_normals(self, T: np.ndarray) -> np.ndarray:
        """Unnormalized normals (n, 3) float32 of the skinning pass (cofactor of the blended
        linear part times the rest normal), reused like skinned_positions()'s."""
        self._upload(T)
        self._skin(every_vertex=True)
        np.copyto(self._captured_normals, self._captured_in_caller_order()[:, 3:6])
        return self._captured_normals

    def draw(self, T: np.ndarray, *, bones=None, bone_states=None, out: np.ndarray | None = None) -> np.ndarray:
        """Render the character skinned by T and read it back: ``render`` then ``read``.

        T: (4m, 3) float32, rows 4j..4j+3 are handle j's 3x4 affine transform transposed
        (v' = [v 1] @ T[4j:4j+4]). bones: optional (b, 2, 3) rest heads and tails, bone i moves
        with handle i, drawn over the character; bone_states: b states ("sensed", "relative",
        "free", "faulted") or None. out: optional (height, width, 3) uint8 C-contiguous array.
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
        blocks = self._upload(T)
        if self.skinning == "cpu":
            np.matmul(self._M, T, out=self._positions, casting="same_kind")
            self._vbo_positions.write(self._positions)
        else:
            self._skin()
        ctx.disable(moderngl.CULL_FACE)
        ctx.disable(moderngl.DEPTH_TEST)
        if self.ground:
            np.matmul(self._shadow_Q, T, out=self._spheres[:, :3], casting="same_kind")
            np.mean(self._spheres[:, :3], axis=0, out=self._shadow_mean)
            np.matmul(self._flatten, self._shadow_mean, out=self._shadow_center)
            self._shadow_center += self._floor_offset
            self._occlusion_prog["u_spheres"].write(self._spheres)
            self._occlusion_prog["u_shadow_center"].write(self._shadow_center)
            self._shadow_prog["u_shadow_center"].write(self._shadow_center)
            self._occlusion_fbo.use()
            self._occlusion_vao.render(moderngl.TRIANGLE_STRIP)
            self._lay_backdrop()
        else:
            self._target.use()
            self._target.clear(*self._background, 1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.front_face = "cw"  # the vertical flip in the projection mirrors the winding
        if self.cull_back_faces:
            ctx.enable(moderngl.CULL_FACE)
        self._mesh_vao.render(moderngl.TRIANGLES)
        ctx.disable(moderngl.CULL_FACE)
        if self.ground:  # after the mesh: the early depth test skips the shadow it hides
            self._occlusion_texture.use(location=1)
            self._shadow_vao.render(moderngl.TRIANGLE_STRIP)
        if bones is not None:
            ctx.disable(moderngl.DEPTH_TEST)
            self._draw_bones(bones, bone_states, blocks)
        ctx.front_face = "ccw"
        ctx.disable(moderngl.DEPTH_TEST)
        if self.samples:
            ctx.copy_framebuffer(self._resolved, self._target)
        elif self.fxaa:
            self._antialias_fxaa(bones is not None)

    def _lay_backdrop(self) -> None:
        """Bind the target with the background and the unshadowed ground in it, depth cleared:
        a copy of this camera's backdrop (drawn on its first use; the BACKDROPS cameras used
        last are kept: the loop's stays while a viewer orbits), or, multisampled, drawn in place."""
        ctx = self.ctx
        if self.samples:  # a single-sampled backdrop cannot be copied into a multisampled target
            self._target.use()
            self._target.clear(*self._background, 1.0)
            self._ground_vao.render(moderngl.TRIANGLES)
            return
        backdrop = self._backdrops.pop(self._camera_key, None)  # put back last: the newest used
        if backdrop is None:
            if len(self._backdrops) < BACKDROPS:
                size = (self.width, self.height)
                backdrop = ctx.framebuffer(ctx.renderbuffer(size, 4), ctx.depth_renderbuffer(size))
            else:  # reuse the least recently used camera's
                backdrop = self._backdrops.pop(next(iter(self._backdrops)))
            backdrop.use()
            backdrop.clear(*self._background, 1.0)
            self._ground_vao.render(moderngl.TRIANGLES)  # depth test off: depth stays cleared
        self._backdrops[self._camera_key] = backdrop
        ctx.copy_framebuffer(self._target, backdrop)
        self._target.use()

    def _antialias_fxaa(self, with_bones: bool) -> None:
        """FXAA from the aliased texture into _resolved. With fxaa_region "character", only the
        character's rectangle is filtered (the ground fades out smoothly: no hard edge) over a
        copy of the frame; with fxaa_passes "mark_edges", a first pass marks edge pixels in the
        depth buffer and the blur runs only there (the copy holds every other pixel)."""
        ctx = self.ctx
        partial = self.fxaa_region == "character" or len(self._fxaa_vaos) > 1
        if partial:
            ctx.copy_framebuffer(self._resolved, self._target)
        if self.fxaa_region == "character":
            self._resolved.scissor = self._character_rect(with_bones)
        self._resolved.use()
        self._aliased.use(location=2)
        if len(self._fxaa_vaos) == 1:
            self._fxaa_vao.render(moderngl.TRIANGLES, vertices=3)
        else:
            mark, blur = self._fxaa_vaos
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.depth_func = "1"  # always: the mark pass writes 0 on edges, 1 elsewhere
            self._resolved.color_mask = (False, False, False, False)
            mark.render(moderngl.TRIANGLES, vertices=3)
            self._resolved.color_mask = (True, True, True, True)
            self._resolved.depth_mask = False
            ctx.depth_func = ">"  # the blur triangle at depth 0.5 passes over the marks only
            blur.render(moderngl.TRIANGLES, vertices=3)
            self._resolved.depth_mask = True
            ctx.depth_func = "<"
            ctx.disable(moderngl.DEPTH_TEST)
        self._resolved.scissor = None

    def _character_rect(self, with_bones: bool) -> tuple[int, int, int, int]:
        """(x, y, width, height) [px] of the framebuffer that holds every vertex drawn (their
        bounding box's corners, projected) and the drawn bones, plus a margin for the filter."""
        drawn = self._skin_count
        self._skinned.read_into(self._captured_padded, size=drawn * 4 * SKINNED_FLOATS)
        self._captured_padded[drawn:self._drawn_rows] = self._captured_padded[0]
        rows = self._captured_padded[: self._drawn_rows].reshape(-1, BOX_BLOCK * SKINNED_FLOATS)
        np.min(rows, axis=0, out=self._box_lanes[0])
        np.max(rows, axis=0, out=self._box_lanes[1])
        lanes = self._box_lanes.reshape(2, BOX_BLOCK, SKINNED_FLOATS)
        np.min(lanes[0, :, :3], axis=0, out=self._box[0])
        np.max(lanes[1, :, :3], axis=0, out=self._box[1])
        if with_bones and self._bone_instances is not None:
            ends = self._bone_instances[:, :6].reshape(-1, 3)
            np.minimum(self._box[0, :3], ends.min(axis=0), out=self._box[0, :3])
            np.maximum(self._box[1, :3], ends.max(axis=0), out=self._box[1, :3])
        corners = self._corners
        corners[:, 0] = self._box[[0, 1, 0, 1, 0, 1, 0, 1], 0]
        corners[:, 1] = self._box[[0, 0, 1, 1, 0, 0, 1, 1], 1]
        corners[:, 2] = self._box[[0, 0, 0, 0, 1, 1, 1, 1], 2]
        np.matmul(corners, self._view_proj_gl, out=self._clip)  # rows: clip coordinates
        w = self._clip[:, 3]
        if not np.all(w > 1e-6):  # a corner behind the camera: filter the whole frame
            return (0, 0, self.width, self.height)
        ndc = self._clip[:, :2] / w[:, None]
        margin = 2.0 + (self.bone_width_px if with_bones else 0.0)
        x0 = max(0, int(np.floor((ndc[:, 0].min() * 0.5 + 0.5) * self.width - margin)))
        x1 = min(self.width, int(np.ceil((ndc[:, 0].max() * 0.5 + 0.5) * self.width + margin)))
        y0 = max(0, int(np.floor((ndc[:, 1].min() * 0.5 + 0.5) * self.height - margin)))
        y1 = min(self.height, int(np.ceil((ndc[:, 1].max() * 0.5 + 0.5) * self.height + margin)))
        return (x0, y0, max(0, x1 - x0), max(0, y1 - y0))

    def read(self, out: np.ndarray | None = None) -> np.ndarray:
        """Wait for the frame ``render`` issued and read it back as (height, width, 3) uint8 RGB,
        top row first, into ``out`` or the renderer's own ``image`` array."""
        image = self.image if out is None else out
        if image.shape != self.image.shape or image.dtype != np.uint8 or not image.flags.c_contiguous:
            raise RenderInputError(
                f"out: expected C-contiguous uint8 {self.image.shape}, got {image.dtype} {image.shape}"
            )
        self._resolved.read_into(image, components=3, alignment=1)
        return image

    def _draw_bones(self, bones, bone_states, blocks: np.ndarray) -> None:
        if bones is not self._bone_source:
            rest = rest_segments(bones)
            if len(rest) > self.m:
                raise RenderInputError(f"bones: {len(rest)} bones but only {self.m} handles")
            if self._bone_rest is None or len(rest) != len(self._bone_rest):
                self._bone_instances = np.zeros((len(rest), 9), dtype=np.float32)
                if self._bone_vbo is not None:
                    self._bone_vao.release()
                    self._bone_vbo.release()
                self._bone_vbo = self.ctx.buffer(reserve=self._bone_instances.nbytes, dynamic=True)
                self._bone_vao = self.ctx.vertex_array(
                    self._bone_prog,
                    [
                        (self._bone_corners, "2f", "in_corner"),
                        (self._bone_vbo, "3f 3f 3f/i", "in_head", "in_tail", "in_color"),
                    ],
                )
            self._bone_rest = rest
            self._bone_source = bones
        rest = self._bone_rest
        count = len(rest)
        if bone_states is not None and len(bone_states) != count:
            raise RenderInputError(f"bone_states: {len(bone_states)} states for {count} bones")
        inst = self._bone_instances
        posed = inst[:, :6].reshape(count, 2, 3)
        np.matmul(rest, blocks[:count], out=posed, casting="same_kind")  # (b,2,4) @ (b,4,3)
        for i in range(count):
            inst[i, 6:9] = state_color(None if bone_states is None else bone_states[i], i)
        self._bone_vbo.write(inst)
        self._bone_prog["u_width_px"].value = self.bone_width_px
        self._bone_vao.render(moderngl.TRIANGLE_STRIP, instances=count)

    # -- lifetime --------------------------------------------------------------------------------

    @property
    def gl_renderer(self) -> str:
        """GL_RENDERER of the context, e.g. 'llvmpipe (LLVM 15.0.6, 256 bits)'."""
        return str(self.ctx.info["GL_RENDERER"])

    def release(self) -> None:
        """Free every GL object of this renderer (and its context when it owns it)."""
        if self._released:
            return
        self._released = True
        objects = [
            self._skin_vao, self._skin_prog, self._skinned, self._mesh_vao, self._mesh_prog,
            self._ground_vao, self._ground_prog, self._ground_vbo, self._shadow_vao, self._shadow_prog,
            self._bone_prog, self._bone_corners,
            self._occlusion_vao, self._occlusion_prog, self._occlusion_quad, self._occlusion_fbo,
            self._occlusion_texture,
            self._vbo_rest, self._vbo_normal, self._ibo, self._weights, self._ubo, *self._weight_buffers,
        ]
        if self._draw_ibo is not self._ibo:
            objects.append(self._draw_ibo)
        if self.skinning == "cpu":
            objects.append(self._vbo_positions)
        if self._bone_vao is not None:
            objects += [self._bone_vao, self._bone_vbo]
        objects += self._fxaa_vaos + self._fxaa_progs
        for backdrop in self._backdrops.values():
            objects += list(backdrop.color_attachments) + [backdrop.depth_attachment, backdrop]
        for fbo in {id(self._target): self._target, id(self._resolved): self._resolved}.values():
            objects += list(fbo.color_attachments) + [fbo.depth_attachment, fbo]
        # Bind framebuffer 0 first: moderngl rebinds the current framebuffer after creating one, and
        # rebinding a deleted framebuffer would raise GL_INVALID_OPERATION in a shared context.
        self.ctx.detect_framebuffer(0).use()
        for obj in objects:
            obj.release()
        if self._owns_ctx:
            self.ctx.release()

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.release()
