#include "kernels.h"

#include <cstdlib>
#include <cstring>

namespace puppet {

namespace {

// PUPPET_SIMD=generic forces the baseline kernels (tests compare both sets).
Kernels choose() {
  const char* force = std::getenv("PUPPET_SIMD");
  const bool generic_only = force != nullptr && std::strcmp(force, "generic") == 0;
#if defined(__x86_64__)
  __builtin_cpu_init();
  if (!generic_only && __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"))
    return Kernels{avx2::isa(),           avx2::fit_rotations_soa, avx2::gemm3, avx2::gemm3_sparse, avx2::dot,
                   avx2::dot_f64,         avx2::subtract_rows,     avx2::cholesky_solve_rows};
#else
  (void)generic_only;
#endif
  return Kernels{generic::isa(),   generic::fit_rotations_soa, generic::gemm3, generic::gemm3_sparse, generic::dot,
                 generic::dot_f64, generic::subtract_rows,     generic::cholesky_solve_rows};
}

}  // namespace

const Kernels& kernels() {
  static const Kernels chosen = choose();
  return chosen;
}

}  // namespace puppet
