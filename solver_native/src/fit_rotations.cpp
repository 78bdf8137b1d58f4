#include "fit_rotations.h"

#include "kernels.h"

namespace puppet {

void fit_rotations_soa(const float* S, float* R, std::ptrdiff_t count, std::ptrdiff_t stride, float* Vwarm,
                       int interleave) {
  kernels().fit_rotations_soa(S, R, count, stride, Vwarm, interleave);
}

void fit_rotations(const float* S, float* R, std::ptrdiff_t count, int interleave) {
  // Gathered into structure-of-arrays blocks of 8 kRotationInterleave (zero padding: identity).
  constexpr std::ptrdiff_t kLanes = 8 * kRotationInterleave;
  float s[9 * kLanes], r[9 * kLanes];
  const Kernels& k = kernels();
  for (std::ptrdiff_t k0 = 0; k0 < count; k0 += kLanes) {
    const std::ptrdiff_t n = count - k0 < kLanes ? count - k0 : kLanes;
    const std::ptrdiff_t padded = (n + 7) / 8 * 8;
    for (std::ptrdiff_t l = 0; l < padded; ++l)
      for (int e = 0; e < 9; ++e) s[e * kLanes + l] = l < n ? S[9 * (k0 + l) + e] : 0.0f;
    k.fit_rotations_soa(s, r, padded, kLanes, nullptr, interleave);
    for (std::ptrdiff_t l = 0; l < n; ++l)
      for (int e = 0; e < 9; ++e) R[9 * (k0 + l) + e] = r[e * kLanes + l];
  }
}

}  // namespace puppet
