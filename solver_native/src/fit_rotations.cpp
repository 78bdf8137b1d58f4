#include "fit_rotations.h"

#include "kernels.h"

namespace puppet {

void fit_rotations_soa(const float* S, float* R, std::ptrdiff_t count, std::ptrdiff_t stride, float* Vwarm) {
  kernels().fit_rotations_soa(S, R, count, stride, Vwarm);
}

void fit_rotations(const float* S, float* R, std::ptrdiff_t count) {
  constexpr std::ptrdiff_t kLanes = 8;
  float s[9 * kLanes], r[9 * kLanes];
  const Kernels& k = kernels();
  for (std::ptrdiff_t k0 = 0; k0 < count; k0 += kLanes) {
    const std::ptrdiff_t n = count - k0 < kLanes ? count - k0 : kLanes;
    for (std::ptrdiff_t l = 0; l < kLanes; ++l)
      for (int e = 0; e < 9; ++e) s[e * kLanes + l] = l < n ? S[9 * (k0 + l) + e] : 0.0f;
    k.fit_rotations_soa(s, r, kLanes, kLanes, nullptr);
    for (std::ptrdiff_t l = 0; l < n; ++l)
      for (int e = 0; e < 9; ++e) R[9 * (k0 + l) + e] = r[e * kLanes + l];
  }
}

}  // namespace puppet
