#include "kernels.h"

#include <cstdlib>
#include <cstring>

namespace puppet {

namespace {

// PUPPET_SIMD=generic or =avx2 caps the choice at that kernel set (tests compare the sets).
Kernels choose() {
  const char* force = std::getenv("PUPPET_SIMD");
  const bool generic_only = force != nullptr && std::strcmp(force, "generic") == 0;
  const bool avx2_at_most = force != nullptr && std::strcmp(force, "avx2") == 0;
#if defined(__x86_64__)
  __builtin_cpu_init();
  const bool avx2 = !generic_only && __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  if (avx2 && !avx2_at_most && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
      __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512bw"))
    return Kernels{avx512::isa(),           avx512::fit_rotations_soa, avx512::gemm3, avx512::gemm3_sparse,
                   avx512::dot,             avx512::dot_f64,           avx512::subtract_rows,
                   avx512::cholesky_solve_rows};
  if (avx2)
    return Kernels{avx2::isa(),           avx2::fit_rotations_soa, avx2::gemm3, avx2::gemm3_sparse, avx2::dot,
                   avx2::dot_f64,         avx2::subtract_rows,     avx2::cholesky_solve_rows};
#else
  (void)generic_only;
  (void)avx2_at_most;
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
