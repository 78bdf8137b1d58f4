// Array types crossing the Python/C++ boundary, fixed once for every binding.
//
// All per-frame arrays are float32, C-contiguous, and bound without conversion
// (`.noconvert()` on the argument): a wrong dtype or layout is a TypeError in
// Python, never a silent copy.
#pragma once

#include <cstdint>
#include <nanobind/ndarray.h>

namespace puppet {

namespace nb = nanobind;

// (r, 3, 3) float32: a stack of 3x3 matrices, row-major per matrix.
using Mat3Stack = nb::ndarray<float, nb::shape<-1, 3, 3>, nb::c_contig, nb::device::cpu>;
using ConstMat3Stack = nb::ndarray<const float, nb::shape<-1, 3, 3>, nb::c_contig, nb::device::cpu>;

}  // namespace puppet

namespace puppet {

// (4m, 3) float32 transforms T, handle j's transform transposed in rows 4j..4j+3.
using TransformsF = nb::ndarray<float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu>;
// (kf, 4, 3) full-transform targets and (kp, 3) positional targets.
using FullValues = nb::ndarray<const float, nb::shape<-1, 4, 3>, nb::c_contig, nb::device::cpu>;
using PosValues = nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu>;
// Precompute matrices (constructor only, converted freely).
using ConstMatrixF = nb::ndarray<const float, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using ConstMatrixD = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using ConstIndexVec = nb::ndarray<const int32_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using ConstMatrixI = nb::ndarray<const int32_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

}  // namespace puppet

namespace puppet {

// Forward kinematics (float64, model units, radians): (b, 3, 3) joint rotations, (b, 3, 4) bone
// poses [A | t], (n,) vectors (joint angles), (k, 3) rows (axes, heads).
using RotationsD = nb::ndarray<double, nb::shape<-1, 3, 3>, nb::c_contig, nb::device::cpu>;
using ConstRotationsD = nb::ndarray<const double, nb::shape<-1, 3, 3>, nb::c_contig, nb::device::cpu>;
using PosesD = nb::ndarray<double, nb::shape<-1, 3, 4>, nb::c_contig, nb::device::cpu>;
using ConstPosesD = nb::ndarray<const double, nb::shape<-1, 3, 4>, nb::c_contig, nb::device::cpu>;
using ConstVecD = nb::ndarray<const double, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using ConstRows3D = nb::ndarray<const double, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu>;
// Constraint values written by the caller's pass (puppet.fast.Values.full / .relative).
using FullValuesOut = nb::ndarray<float, nb::shape<-1, 4, 3>, nb::c_contig, nb::device::cpu>;

}  // namespace puppet
