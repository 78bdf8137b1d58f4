// Kernels compiled with -mavx2 -mfma (see CMakeLists.txt); only called where the CPU has both.
#if defined(__x86_64__)
#define PUPPET_KERNEL_NS avx2
#include "kernels_impl.inc"
#else
#include "kernels.h"
namespace puppet::avx2 {  // never selected off x86-64
void fit_rotations_soa(const float* S, float* R, std::ptrdiff_t c, std::ptrdiff_t s, float* V, int n) {
  generic::fit_rotations_soa(S, R, c, s, V, n);
}
void gemm3(const float* A, std::ptrdiff_t lda, int rows, int K, const float* B, std::ptrdiff_t bk,
           std::ptrdiff_t bc, float* out, std::ptrdiff_t ldo, bool acc) {
  generic::gemm3(A, lda, rows, K, B, bk, bc, out, ldo, acc);
}
void gemm3_sparse(const float* A, std::ptrdiff_t lda, int rows, const int32_t* off, const int32_t* ks,
                  const float* B, std::ptrdiff_t bk, std::ptrdiff_t bc, float* out, std::ptrdiff_t ldo) {
  generic::gemm3_sparse(A, lda, rows, off, ks, B, bk, bc, out, ldo);
}
double dot(const float* a, const float* b, size_t n) { return generic::dot(a, b, n); }
double dot_f64(const float* a, const float* b, size_t n) { return generic::dot_f64(a, b, n); }
void subtract_rows(double* y, const double* const* x, const double* c, int count, std::ptrdiff_t len) {
  generic::subtract_rows(y, x, c, count, len);
}
void cholesky_solve_rows(const double* l, int n, double* b, std::ptrdiff_t len) {
  generic::cholesky_solve_rows(l, n, b, len);
}
const char* isa() { return generic::isa(); }
}  // namespace puppet::avx2
#endif
