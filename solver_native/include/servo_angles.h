// Joint angles from raw servo ticks: the per-frame conversion of puppet.servo_models.ServoUnits
// (one pass in native code instead of seven NumPy calls).
#pragma once

#include <cstddef>
#include <cstdint>

namespace puppet {

// n readings of k servos (ticks row-major (n, k), float64 counts; out the same shape, radians):
//   a = (ticks - zero) * radians_per_tick;
//   where wrap: a = top - ((top - a) mod 2 pi), mod as NumPy's remainder (result in [0, 2 pi));
//   if clamp: a = min(max(a, lo), hi).
// zero: (k,) int64 ticks at the rest pose; table: (5, k) float64, rows radians_per_tick, top,
// wrap (0 or 1), lo, hi.
void servo_angles(const double* ticks, std::size_t n, const int64_t* zero, const double* table, std::size_t k,
                  bool clamp, double* out);

}  // namespace puppet
