// The per-frame constraint values of sensed bones, gathered from forward kinematics into the
// solver's float32 value arrays (puppet.fast.Values) in one pass: no per-bone Python loop.
//
//   full[q]     = pose[full_bones[q]]^T       (4 x 3: rows 0..2 the linear part transposed,
//                                               row 3 the translation; T's layout)
//   relative[q] = rot[relative_bones[q]]      (3 x 3: the joint rotation in model space)
#pragma once

#include <cstdint>

namespace puppet {

// rot: (b, 3, 3) float64; pose: (b, 3, 4) float64; full_bones: (nf,), full: (nf, 4, 3) float32 out;
// relative_bones: (nr,), relative: (nr, 3, 3) float32 out. Bone indices must be in [0, b).
void constraint_values(const double* rot, const double* pose, const int32_t* full_bones, int nf, float* full,
                       const int32_t* relative_bones, int nr, float* relative);

}  // namespace puppet
