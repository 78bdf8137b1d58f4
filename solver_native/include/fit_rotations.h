// Batched closest-rotation fit (the FAST local step).
//
//   S: r covariances, 3x3 row-major each
//   R: r proper rotations, R_k = argmin_{R in SO(3)} ||R - S_k||_F,
//      i.e. R_k = U diag(1, 1, det(U V^T)) V^T for S_k = U Sigma V^T.
//
// Method (branch-free, vectorised over matrices, float32): normalise S by its
// largest entry, cyclic Jacobi eigen-decomposition of S^T S with exact Givens
// angles (sweeps until the off-diagonal is below float resolution) giving V, sort the columns of S V by norm
// (signed swaps keep det V = +1), Givens QR of S V = U R giving U with det +1;
// the result is U V^T. A negative smallest singular value lands in R's last
// diagonal entry, so reflections give the closest *proper* rotation.
//
// Degenerate covariances (rank < 3, zero, non-finite) still give a proper
// rotation: zero or non-finite S gives the identity. Eight matrices per SIMD
// register (sixteen in the AVX-512 set's interleaved schedule while 48 remain); the kernel set
// (baseline, AVX2+FMA or AVX-512) is chosen at run time (kernels.h).
#pragma once

#include <cstddef>

#include "kernels.h"

namespace puppet {

// Array-of-structures form: S and R are `count` row-major 3x3 matrices. `interleave` (1..3): the
// most batches of eight run at once (see kRotationInterleave); 1 gives the plain schedule.
void fit_rotations(const float* S, float* R, std::ptrdiff_t count, int interleave = kRotationInterleave);

// Structure-of-arrays form used by the solver: entry (i, j) of matrix g lives at
// S[(3 * i + j) * stride + g] (same for R); `count` must be a multiple of 8 and
// stride >= count. Lanes are independent; S and R may not alias. Vwarm (same layout, optional,
// in/out) holds each matrix's eigenbasis of S^T S from the previous call (start it at the
// identity): warm-started Jacobi needs one or two sweeps instead of four or five.
// Batches of eight run up to `interleave` at once; a group's sweeps stop when all its lanes
// have converged, so results depend on the grouping only within float32 rounding.
void fit_rotations_soa(const float* S, float* R, std::ptrdiff_t count, std::ptrdiff_t stride,
                       float* Vwarm = nullptr, int interleave = kRotationInterleave);

}  // namespace puppet
