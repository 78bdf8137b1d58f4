// nanobind module puppet._native: the per-frame numeric core of puppet.
//
// Hot functions take fixed-dtype, C-contiguous arrays without conversion and
// release the GIL while they run.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <stdexcept>
#include <string>

#include "array_types.h"
#include "fit_rotations.h"

namespace nb = nanobind;
using namespace puppet;

namespace {

void fit_rotations_py(ConstMat3Stack S, Mat3Stack R) {
  if (S.shape(0) != R.shape(0))
    throw std::invalid_argument("fit_rotations: S has " + std::to_string(S.shape(0)) +
                                " matrices, R has " + std::to_string(R.shape(0)));
  fit_rotations(S.data(), R.data(), static_cast<std::ptrdiff_t>(S.shape(0)));
}

}  // namespace

NB_MODULE(_native, m) {
  m.doc() = "puppet's native core: FAST per-frame iterations (C++17, Eigen).";

  m.def("fit_rotations", &fit_rotations_py, nb::arg("S").noconvert(), nb::arg("R").noconvert(),
        nb::call_guard<nb::gil_scoped_release>(),
        "Closest proper rotation of each 3x3 matrix, written into R.\n\n"
        "S: (r, 3, 3) float32 C-contiguous covariances.\n"
        "R: (r, 3, 3) float32 C-contiguous output, R[k] in SO(3) minimising ||R[k] - S[k]||_F.\n"
        "Zero or non-finite S[k] gives the identity; reflections are corrected (det R = +1).");
}
