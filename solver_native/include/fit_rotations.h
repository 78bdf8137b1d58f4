// Batched closest-rotation fit (the FAST local step).
//
//   S: r covariances, 3x3 row-major each
//   R: r proper rotations, R_k = argmin_{R in SO(3)} ||R - S_k||_F,
//      i.e. R_k = U diag(1, 1, det(U V^T)) V^T for S_k = U Sigma V^T.
//
// Degenerate covariances (rank < 3, zero, non-finite) still give a proper
// rotation: zero or non-finite S gives the identity.
#pragma once

#include <cstddef>

namespace puppet {

void fit_rotations(const float* S, float* R, std::ptrdiff_t count);

}  // namespace puppet
