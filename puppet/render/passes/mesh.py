"""Mesh pass: the character skinned in a vertex shader (transform feedback) and drawn lit.

The skinning pass writes (position, normal, colour) of each vertex drawn, once, into a buffer
that the mesh draw, picking and ``skinned`` read-backs use; with skinning "cpu", M @ T is
computed in NumPy and uploaded instead (face normals in the fragment shader).
"""

from __future__ import annotations

import moderngl
import numpy as np

from puppet.render import shaders
from puppet.render.errors import RenderError, RenderInputError
from puppet.render.passes.base import GLPass
from puppet.render.skin_weights import TEXTURE_WIDTH, attribute_slots, lbs_matrix, pack_weights

#: Floats per vertex in the skinning pass's output: position, normal, colour.
SKINNED_FLOATS = 9
WEIGHT_LAYOUTS = ("auto", "dense", "pairs")
#: Up to this many handles the weights go to the shader densely (13 vec4 attributes at most).
DENSE_MAX_HANDLES = 52


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (n, 3) float32 of the rest mesh (zero for lone vertices)."""
    face_normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    normals = np.zeros_like(V)
    for corner in range(3):
        np.add.at(normals, F[:, corner], face_normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return (normals / np.maximum(length, 1e-20)).astype(np.float32)


def check_mesh(V, F, W) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """V (n, 3) float64, F (f, 3) uint32, W (n, m) as arrays, or RenderInputError naming the field."""
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


class MeshPass(GLPass):
    """Skinning and the lit mesh of V (n, 3) float64, W (n, m), normals (n, 3) float32, in the
    renderer's vertex order: the first ``skin_count`` vertices are those of the ``drawn``
    triangles (f', 3) uint32; F (f, 3) uint32 holds every triangle (picking).

    skinning "gpu" or "cpu", shading "vertex" or "pixel", weight_tolerance, weight_layout,
    albedo: see Renderer. Attributes: ``skinned`` (the transform-feedback buffer, n x
    SKINNED_FLOATS float32), ``ibo`` (every triangle), ``weight_layout``,
    ``max_weights_per_vertex``, ``dropped_weight_abs_max``.
    """

    def __init__(self, ctx, V, F, drawn, W, normals, *, skin_count: int, skinning: str, shading: str,
                 weight_tolerance: float, weight_layout: str, albedo):
        super().__init__(ctx)
        self.n, self.m = W.shape
        self.skinning = skinning
        self.skin_count = skin_count
        max_block = int(ctx.info["GL_MAX_UNIFORM_BLOCK_SIZE"])
        if 48 * self.m > max_block:
            raise RenderError(
                f"W: {self.m} handles need {48 * self.m} bytes of uniforms, the driver allows {max_block}"
            )
        if weight_layout not in WEIGHT_LAYOUTS:
            raise RenderInputError(f"weight_layout: expected one of {WEIGHT_LAYOUTS}, got {weight_layout!r}")
        if weight_layout == "dense" and self.m > DENSE_MAX_HANDLES:
            raise RenderInputError(f"weight_layout: dense takes at most {DENSE_MAX_HANDLES} handles, W has {self.m}")
        self._rows = np.zeros((self.m, 3, 4), dtype=np.float32)  # A_j = T block j transposed
        with self.building():
            self._build(V, F, drawn, W, normals, shading, weight_tolerance, weight_layout, albedo)

    def _build(self, V, F, drawn, W, normals, shading, weight_tolerance, weight_layout, albedo) -> None:
        ctx = self.ctx
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
        vbo_rest = self.own(ctx.buffer(V.astype(np.float32)))
        vbo_normal = self.own(ctx.buffer(normals))
        if weight_layout == "auto":  # a dense term costs about a third of a pair's (no gathers)
            slots = attribute_slots(self.max_weights_per_vertex)
            weight_layout = "dense" if self.m <= min(DENSE_MAX_HANDLES, 3 * slots) else "pairs"
        self.weight_layout = weight_layout
        dense = weight_layout == "dense"
        # Packing the pairs sorts every row (about 0.1 s for the critter): only when used.
        packed = None if dense else pack_weights(W, tolerance=weight_tolerance)
        self._spill = not dense and packed.spilled > 0
        if dense:
            groups = -(-self.m // 4)
            dense_weights = np.zeros((self.n, 4 * groups), dtype=np.float32)
            dense_weights[:, : self.m] = np.where(keep, W, 0.0)
            skin_content = [
                (self.own(ctx.buffer(dense_weights)), " ".join(["4f"] * groups),
                 *[f"in_dense{g}" for g in range(groups)])
            ]
            skin = shaders.dense_skin_chunk(self.m)
        else:
            groups = packed.slots // 4
            handle_groups = packed.slot_handles.shape[1] // 4
            skin_content = [
                (self.own(ctx.buffer(packed.slot_weights)), " ".join(["4f"] * groups),
                 *[f"in_weight{g}" for g in range(groups)]),
                (self.own(ctx.buffer(packed.slot_handles)), " ".join(["4u"] * handle_groups),
                 *[f"in_handles{h}" for h in range(handle_groups)]),
            ]
            if self._spill:
                skin_content.append((self.own(ctx.buffer(packed.spans)), "2u", "in_span"))
            skin = shaders.skin_chunk(packed.slots, self._spill)
        self.ibo = self.own(ctx.buffer(F))  # every triangle: picking
        draw_ibo = self.ibo if drawn is F else self.own(ctx.buffer(drawn))
        entries = np.zeros((1, TEXTURE_WIDTH, 2), np.float32) if packed is None else packed.entries
        self._weights = self.own(ctx.texture((TEXTURE_WIDTH, entries.shape[0]), 2, entries, dtype="f4"))
        self._weights.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._ubo = self.own(ctx.buffer(reserve=self._rows.nbytes))
        defines = dict(HANDLES=self.m, WEIGHTS_WIDTH=TEXTURE_WIDTH, WEIGHTS_SHIFT=TEXTURE_WIDTH.bit_length() - 1,
                       VERTEX_LIGHTING=int(shading == "vertex"))

        self._skin_prog = self.own(ctx.program(
            vertex_shader=shaders.source(shaders.LIGHTING, skin, shaders.SKIN_VERTEX, **defines),
            varyings=["out_position", "out_normal", "out_color"],
        ))
        self._skin_prog["Handles"].binding = 0
        if self._spill:
            self._skin_prog["u_weights"].value = 0
        self._skin_vao = self.own(ctx.vertex_array(
            self._skin_prog,
            [(vbo_rest, "3f", "in_position"), (vbo_normal, "3f", "in_normal"), *skin_content],
        ))
        self.skinned = self.own(ctx.buffer(reserve=self.n * 4 * SKINNED_FLOATS))  # (position, normal, colour)

        if shading == "vertex":
            self._mesh_prog = self.own(ctx.program(
                vertex_shader=shaders.source(shaders.MESH_LIT_VERTEX),
                fragment_shader=shaders.source(shaders.LIGHTING, shaders.MESH_LIT_FRAGMENT),
            ))
            content = [(self.skinned, "3f 12x 3f", "in_position", "in_color")]
        elif self.skinning == "gpu":
            self._mesh_prog = self.own(ctx.program(
                vertex_shader=shaders.source(shaders.MESH_VERTEX),
                fragment_shader=shaders.source(shaders.LIGHTING, shaders.MESH_FRAGMENT, FACE_NORMALS=0),
            ))
            content = [(self.skinned, "3f 3f 12x", "in_position", "in_normal")]
        else:
            self._M = lbs_matrix(V, W)
            self._positions = np.zeros((self.n, 3), dtype=np.float32)
            self._vbo_positions = self.own(ctx.buffer(reserve=self._positions.nbytes, dynamic=True))
            self._mesh_prog = self.own(ctx.program(
                vertex_shader=shaders.source(shaders.MESH_CPU_VERTEX),
                fragment_shader=shaders.source(shaders.LIGHTING, shaders.MESH_FRAGMENT, FACE_NORMALS=1),
            ))
            content = [(self._vbo_positions, "3f", "in_position")]
        self._mesh_vao = self.own(ctx.vertex_array(self._mesh_prog, content, index_buffer=draw_ibo,
                                                   index_element_size=4))
        self._lit_prog = self._skin_prog if shading == "vertex" else self._mesh_prog  # has the lights
        self._lit_prog["u_albedo"].value = tuple(float(c) for c in albedo)

    def set_camera(self, view_proj_gl: np.ndarray, lights: dict) -> None:
        """Apply the (4, 4) column-major projection and the lights (uniform name -> value)."""
        self._mesh_prog["u_view_proj"].write(view_proj_gl)
        for name, value in lights.items():
            uniform = self._lit_prog.get(name, None)  # None where the shader does not use it
            if uniform is not None:
                uniform.value = value

    def upload(self, T: np.ndarray) -> np.ndarray:
        """Check T (4m, 3) and upload it once; returns T viewed as (m, 4, 3)."""
        if not isinstance(T, np.ndarray) or T.shape != (4 * self.m, 3):
            shape = getattr(T, "shape", None)
            raise RenderInputError(f"T: expected shape ({4 * self.m}, 3) for {self.m} handles, got {shape}")
        blocks = T.reshape(self.m, 4, 3)
        np.copyto(self._rows, blocks.transpose(0, 2, 1), casting="same_kind")
        self._ubo.write(self._rows)
        return blocks

    def skin(self, framebuffer, every_vertex: bool = False) -> None:
        """Skinning pass of the uploaded T: the vertex shader writes (position, normal, colour)
        of each vertex drawn (every vertex: ``every_vertex``, as picking and read-backs need)
        once. framebuffer: one to bind (EGL without a surface has no default to fall back to)."""
        self._ubo.bind_to_uniform_block(0)
        self._weights.use(location=0)
        framebuffer.use()
        count = self.n if every_vertex else self.skin_count
        self._skin_vao.transform(self.skinned, mode=moderngl.POINTS, vertices=count)

    def prepare(self, T: np.ndarray, framebuffer) -> None:
        """The frame's vertices: skinned on the GPU, or M @ T computed here and uploaded."""
        if self.skinning == "cpu":
            np.matmul(self._M, T, out=self._positions, casting="same_kind")
            self._vbo_positions.write(self._positions)
        else:
            self.skin(framebuffer)

    def draw(self, cull_back_faces: bool) -> None:
        """Draw the prepared mesh into the bound framebuffer (depth test on)."""
        ctx = self.ctx
        ctx.front_face = "cw"  # the vertical flip in the projection mirrors the winding
        if cull_back_faces:
            ctx.enable(moderngl.CULL_FACE)
        self._mesh_vao.render(moderngl.TRIANGLES)
        ctx.disable(moderngl.CULL_FACE)
