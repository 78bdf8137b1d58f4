#include "constraint_values.h"

#include <cstddef>

namespace puppet {

void constraint_values(const double* rot, const double* pose, const int32_t* full_bones, int nf, float* full,
                       const int32_t* relative_bones, int nr, float* relative) {
  for (int q = 0; q < nf; ++q) {
    const double* p = pose + 12 * static_cast<std::ptrdiff_t>(full_bones[q]);
    float* out = full + 12 * q;
    for (int j = 0; j < 4; ++j)
      for (int k = 0; k < 3; ++k) out[3 * j + k] = static_cast<float>(p[4 * k + j]);
  }
  for (int q = 0; q < nr; ++q) {
    const double* r = rot + 9 * static_cast<std::ptrdiff_t>(relative_bones[q]);
    float* out = relative + 9 * q;
    for (int e = 0; e < 9; ++e) out[e] = static_cast<float>(r[e]);
  }
}

}  // namespace puppet
