#include "servo_angles.h"

#include <algorithm>
#include <cmath>

namespace puppet {

void servo_angles(const double* ticks, std::size_t n, const int64_t* zero, const double* table, std::size_t k,
                  bool clamp, double* out) {
  const double two_pi = 2.0 * M_PI;
  const double *per_tick = table, *top = table + k, *wrap = table + 2 * k, *lo = table + 3 * k, *hi = table + 4 * k;
  for (std::size_t r = 0; r < n; ++r) {
    const double* t = ticks + r * k;
    double* a = out + r * k;
    for (std::size_t c = 0; c < k; ++c) {
      double x = (t[c] - static_cast<double>(zero[c])) * per_tick[c];
      if (wrap[c] != 0.0) {
        double w = std::fmod(top[c] - x, two_pi);  // NumPy's remainder: the divisor's sign
        if (w < 0.0) w += two_pi;
        else if (w == 0.0) w = 0.0;  // +0, as NumPy gives
        x = top[c] - w;
      }
      a[c] = clamp ? std::min(std::max(x, lo[c]), hi[c]) : x;
    }
  }
}

}  // namespace puppet
