"""Packing of a dense weight matrix W (n, m) into per-vertex lists of (weight, handle) pairs.

The vertex shader sums, for vertex i, w_ij * (handle j's affine transform) over the pairs of
vertex i only. Pairs are dropped only where |w_ij| <= tolerance; with tolerance 0 (the default)
only exact zeros are dropped, so the blended transform equals row i of W times the handles
exactly (up to float32 rounding) whatever the sparsity: M @ T is reproduced for any m.

Each vertex's first `slots` pairs (largest weights first) travel as vertex attributes, read
by an unrolled loop (fast on llvmpipe); pairs beyond that (vertices with more than `slots`
nonzero weights) spill into a texture read by a loop over the vertex's span. Padding slots hold
weight 0 for handle 0 and add exactly nothing.
"""

from dataclasses import dataclass

import numpy as np

from puppet.render.errors import RenderInputError

#: Width of the 2D texture that holds the pairs (texel k sits at (k % width, k // width)).
TEXTURE_WIDTH = 4096
#: Most pairs per vertex carried in attributes: 8 vec4 of weights + 4 uvec4 of packed indices
#: (two 16-bit handle indices per uint), which with position, normal and span fills 15 of the
#: 16 vertex attributes OpenGL guarantees.
MAX_SLOTS = 32


@dataclass(frozen=True)
class PackedWeights:
    """W as per-vertex (weight, handle) pairs.

    slots: pairs per vertex in attributes (a multiple of 8, <= MAX_SLOTS);
    slot_weights: (n, slots) float32; slot_handles: (n, slots // 2) uint32, two 16-bit handle
    indices per uint (low half first); spans: (n, 2) uint32, the spilled pairs of vertex i are
    entries[spans[i,0] : spans[i,0] + spans[i,1]]; entries: (rows, TEXTURE_WIDTH, 2) float32,
    texel k = (weight, handle index as float), zero padded; spilled: number of spilled pairs;
    count: number of pairs kept; max_per_vertex: most pairs of one vertex; dropped_abs_max:
    largest |w_ij| dropped (0 when nothing was dropped).
    """

    slots: int
    slot_weights: np.ndarray
    slot_handles: np.ndarray
    spilled: int
    spans: np.ndarray
    entries: np.ndarray
    count: int
    max_per_vertex: int
    dropped_abs_max: float


def check_weights(W) -> np.ndarray:
    """W as an array after checking it is a finite (n, m) matrix of numbers (RenderInputError)."""
    W = np.asarray(W)
    if W.ndim != 2 or W.shape[0] == 0 or W.shape[1] == 0:
        raise RenderInputError(f"W: expected a (n, m) weight matrix, got shape {W.shape}")
    if not np.issubdtype(W.dtype, np.floating) and not np.issubdtype(W.dtype, np.integer):
        raise RenderInputError(f"W: expected floats, got dtype {W.dtype}")
    if not np.all(np.isfinite(W)):
        bad = np.argwhere(~np.isfinite(W))[0]
        raise RenderInputError(f"W: non-finite weight at vertex {bad[0]}, handle {bad[1]}")
    return W


def attribute_slots(max_per_vertex: int) -> int:
    """Pairs per vertex carried in attributes for rows of at most max_per_vertex nonzeros: whole
    uvec4s of handle indices (multiples of 8), at least 8, at most MAX_SLOTS."""
    return min(MAX_SLOTS, max(8, -(-int(max_per_vertex) // 8) * 8))


def pack_weights(W: np.ndarray, *, tolerance: float = 0.0) -> PackedWeights:
    """Pack W (n, m) float: keep every w_ij with |w_ij| > tolerance, in row order."""
    W = check_weights(W)
    n, m = W.shape
    if m > 2**16:
        raise RenderInputError(f"W: {m} handles, at most 65536 are supported")
    keep = np.abs(W) > tolerance
    counts = keep.sum(axis=1)
    max_per_vertex = int(counts.max())
    slots = attribute_slots(max_per_vertex)
    # Each row's kept pairs, largest |w| first; rank r of vertex i goes to slot r or spills.
    order = np.argsort(np.where(keep, -np.abs(W), np.inf), axis=1, kind="stable")
    ranked_w = np.take_along_axis(np.where(keep, W, 0.0), order, axis=1)
    ranked_keep = np.take_along_axis(keep, order, axis=1)
    width = min(slots, m)
    slot_weights = np.zeros((n, slots), dtype=np.float32)
    slot_ids = np.zeros((n, slots), dtype=np.uint32)
    slot_weights[:, :width] = ranked_w[:, :width]
    slot_ids[:, :width] = np.where(ranked_keep[:, :width], order[:, :width], 0)
    slot_handles = slot_ids[:, 0::2] | (slot_ids[:, 1::2] << 16)
    # Spilled pairs (rank >= slots) in compressed rows, row-major.
    rows, ranks = np.nonzero(ranked_keep[:, slots:]) if m > slots else (np.zeros(0, int), np.zeros(0, int))
    spill_counts = np.bincount(rows, minlength=n).astype(np.uint32)
    starts = np.zeros(n, dtype=np.uint32)
    np.cumsum(spill_counts[:-1], out=starts[1:])
    spilled = len(rows)
    n_rows = max(1, -(-spilled // TEXTURE_WIDTH))
    entries = np.zeros((n_rows * TEXTURE_WIDTH, 2), dtype=np.float32)
    entries[:spilled, 0] = ranked_w[rows, ranks + slots]
    entries[:spilled, 1] = order[rows, ranks + slots]
    dropped = np.abs(W[~keep])
    return PackedWeights(
        slots=slots,
        slot_weights=slot_weights,
        slot_handles=np.ascontiguousarray(slot_handles),
        spilled=spilled,
        spans=np.ascontiguousarray(np.stack([starts, spill_counts], axis=1)),
        entries=entries.reshape(n_rows, TEXTURE_WIDTH, 2),
        count=int(counts.sum()),
        max_per_vertex=max_per_vertex,
        dropped_abs_max=float(dropped.max()) if dropped.size else 0.0,
    )


def unpack_weights(packed: PackedWeights, m: int) -> np.ndarray:
    """W (n, m) float32 rebuilt from packed (for tests: the packing loses nothing it keeps)."""
    n = len(packed.slot_weights)
    W = np.zeros((n, m), dtype=np.float32)
    ids = np.empty((n, packed.slots), dtype=np.int64)
    ids[:, 0::2] = packed.slot_handles & 0xFFFF
    ids[:, 1::2] = packed.slot_handles >> 16
    np.add.at(W, (np.repeat(np.arange(n), packed.slots), ids.reshape(-1)), packed.slot_weights.reshape(-1))
    entries = packed.entries.reshape(-1, 2)
    for i in np.nonzero(packed.spans[:, 1])[0]:
        start, count = packed.spans[i]
        pairs = entries[start : start + count]
        np.add.at(W[i], pairs[:, 1].astype(np.int64), pairs[:, 0])
    return W


def lbs_matrix(V: np.ndarray, W: np.ndarray) -> np.ndarray:
    """M (n, 4m) float32 with M[i, 4j:4j+4] = w_ij * [v_i 1], so that positions = M @ T."""
    V = np.asarray(V, dtype=np.float32)
    Vh = np.concatenate([V, np.ones((len(V), 1), np.float32)], axis=1)
    return (np.asarray(W, dtype=np.float32)[:, :, None] * Vh[:, None, :]).reshape(len(V), -1)
