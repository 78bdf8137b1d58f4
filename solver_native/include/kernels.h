// The per-frame numeric kernels, compiled three times: for the baseline instruction set of the
// build, for AVX2+FMA and for AVX-512 on 8-lane vectors (x86-64), chosen once at run time from the
// CPU. A wheel built without -march=native therefore still runs the 8-wide FMA kernels where the
// CPU has them.
#pragma once

#include <cstddef>
#include <cstdint>

namespace puppet {

// Declarations of one kernel set (defined in kernels_impl.inc).
#define PUPPET_DECLARE_KERNELS(NS)                                                                      \
  namespace NS {                                                                                        \
  void fit_rotations_soa(const float* S, float* R, std::ptrdiff_t count, std::ptrdiff_t stride,          \
                         float* Vwarm, int interleave);                                                 \
  void gemm3(const float* A, std::ptrdiff_t lda, int rows, int K, const float* B, std::ptrdiff_t bk,    \
             std::ptrdiff_t bc, float* out, std::ptrdiff_t ldo, bool accumulate);                      \
  void gemm3_sparse(const float* A, std::ptrdiff_t lda, int rows, const int32_t* off, const int32_t* ks, \
                    const float* B, std::ptrdiff_t bk, std::ptrdiff_t bc, float* out, std::ptrdiff_t ldo); \
  double dot(const float* a, const float* b, size_t n);                                                 \
  double dot_f64(const float* a, const float* b, size_t n);                                             \
  void subtract_rows(double* y, const double* const* x, const double* c, int count, std::ptrdiff_t len);  \
  void cholesky_solve_rows(const double* l, int n, double* b, std::ptrdiff_t len);                      \
  const char* isa();                                                                                    \
  }
PUPPET_DECLARE_KERNELS(generic)
PUPPET_DECLARE_KERNELS(avx2)
PUPPET_DECLARE_KERNELS(avx512)
#undef PUPPET_DECLARE_KERNELS

// Batches of eight matrices the rotation fit runs interleaved (at most): three batches' dependency
// chains in flight at once hide each other's latency; 1 is the plain schedule, one batch at a time.
// (At 3 the AVX-512 set runs its batches sixteen lanes wide while 48 matrices remain.)
constexpr int kRotationInterleave = 3;

// One kernel set. fit_rotations_soa: see fit_rotations.h; gemm3: out[c*ldo + i] (+)= sum_k A[k*lda + i] B[k*bk + c*bc], c < 3, i < rows
// (rows a multiple of 8); gemm3_sparse: the same, visiting per row tile only the columns listed
// (see for_each_tile); dot: float dot product summed in double (n a multiple of 8);
// subtract_rows: y[r] = ((y[r] - c[0] x[0][r]) - c[1] x[1][r]) - ..., count (1..4) terms, r < len;
// cholesky_solve_rows: L L^T X = B in place, L the n x n column-major Cholesky factor (lower), B
// n x len row-major (entry i of all len right-hand sides contiguous), vectorised over the len
// columns (the per-frame Schur complements' Z = W S^{-1}).
struct Kernels {
  const char* isa;
  decltype(&generic::fit_rotations_soa) fit_rotations_soa;
  decltype(&generic::gemm3) gemm3;
  decltype(&generic::gemm3_sparse) gemm3_sparse;
  decltype(&generic::dot) dot;
  decltype(&generic::dot_f64) dot_f64;
  decltype(&generic::subtract_rows) subtract_rows;
  decltype(&generic::cholesky_solve_rows) cholesky_solve_rows;
};

// The best kernel set for this CPU (chosen on first use).
const Kernels& kernels();

// Row tiles used by gemm3/gemm3_sparse: (start, size), sizes 32 then one of 24/16/8.
template <class F>
void for_each_tile(int rows, F&& f) {
  int i = 0;
  for (; i + 32 <= rows; i += 32) f(i, 32);
  if (rows > i) f(i, rows - i);
}

}  // namespace puppet
