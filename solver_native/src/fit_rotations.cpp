#include "fit_rotations.h"
#include "simd8.h"

#include <cmath>
#include <immintrin.h>

namespace puppet {

namespace {

constexpr int kJacobiSweeps = 6;  // upper bound; sweeps stop at convergence
constexpr std::ptrdiff_t kLanes = 8;

// Every operation below is lane-wise over eight matrices; branches are selects.
using simd::f8;
using simd::f8u;
using simd::i8;
using simd::splat;
PUPPET_INLINE f8 sel(i8 m, f8 a, f8 b) { return m ? a : b; }
PUPPET_INLINE f8 vabs(f8 x) { return sel(x < 0.0f, -x, x); }
// 1/sqrt(x), x > 0: hardware estimate refined by one Newton step (~23 bits).
PUPPET_INLINE f8 vrsqrt(f8 x) {
  f8 y;
#if defined(__AVX512F__) && defined(__AVX512VL__)
  y = reinterpret_cast<f8>(_mm256_rsqrt14_ps(reinterpret_cast<__m256>(x)));
#elif defined(__AVX__)
  y = reinterpret_cast<f8>(_mm256_rsqrt_ps(reinterpret_cast<__m256>(x)));
#elif defined(__SSE__)
  typedef float f4 __attribute__((vector_size(16)));
  const f4 lo = {x[0], x[1], x[2], x[3]}, hi = {x[4], x[5], x[6], x[7]};
  const f4 rl = reinterpret_cast<f4>(_mm_rsqrt_ps(reinterpret_cast<__m128>(lo)));
  const f4 rh = reinterpret_cast<f4>(_mm_rsqrt_ps(reinterpret_cast<__m128>(hi)));
  y = f8{rl[0], rl[1], rl[2], rl[3], rh[0], rh[1], rh[2], rh[3]};
#else
  for (int i = 0; i < 8; ++i) y[i] = 1.0f / __builtin_sqrtf(x[i]);
#endif
  return y * (1.5f - 0.5f * x * y * y);
}

// One exact Jacobi rotation zeroing b_pq of the symmetric matrix
// (b_pp, b_qq, b_pq, b_rp, b_rq), accumulating V's columns p and q.
// With x = b_qq - b_pp, y = 2 b_pq, d = |x| + hypot(x, y): c = d / hypot(d, y),
// s = sign(x) y / hypot(d, y) (NR's t = tan(phi) without divisions or sqrt latency).
PUPPET_INLINE void jacobi(f8& bpp, f8& bqq, f8& bpq, f8& brp, f8& brq, f8* vp, f8* vq) {
  const f8 x = bqq - bpp, y = 2.0f * bpq;
  const f8 q = x * x + y * y;
  const i8 live = q > 1e-30f;
  const f8 r = sel(live, q * vrsqrt(sel(live, q, splat(1.0f))), splat(0.0f));
  const f8 d = vabs(x) + r;
  const f8 h = d * d + y * y;
  const i8 ok = h > 1e-30f;
  const f8 w = vrsqrt(sel(ok, h, splat(1.0f)));
  const f8 c = sel(ok, d * w, splat(1.0f));
  const f8 s0 = y * w;
  const f8 s = sel(ok, sel(x < 0.0f, -s0, s0), splat(0.0f));
  const f8 cc = c * c, ss = s * s, cs2 = 2.0f * c * s;
  const f8 pp = bpp, qq = bqq, pq = bpq;
  bpp = cc * pp - cs2 * pq + ss * qq;
  bqq = ss * pp + cs2 * pq + cc * qq;
  bpq = splat(0.0f);
  const f8 rp = brp, rq = brq;
  brp = c * rp - s * rq;
  brq = s * rp + c * rq;
  for (int k = 0; k < 3; ++k) {
    const f8 a = vp[k], b = vq[k];
    vp[k] = c * a - s * b;
    vq[k] = s * a + c * b;
  }
}

// Swap columns i and j of B and V (negating the new column j) where |B_i| < |B_j|.
PUPPET_INLINE void sort_pair(f8 (&B)[3][3], f8 (&V)[3][3], f8* rho, int i, int j) {
  const i8 sw = rho[i] < rho[j];
  for (int k = 0; k < 3; ++k) {
    const f8 bi = B[k][i], bj = B[k][j], vi = V[k][i], vj = V[k][j];
    B[k][i] = sel(sw, bj, bi);
    B[k][j] = sel(sw, -bi, bj);
    V[k][i] = sel(sw, vj, vi);
    V[k][j] = sel(sw, -vi, vj);
  }
  const f8 ri = rho[i], rj = rho[j];
  rho[i] = sel(sw, rj, ri);
  rho[j] = sel(sw, ri, rj);
}

// Givens rotation on rows p, q of B zeroing B[q][col]; U <- U G^T.
PUPPET_INLINE void givens(f8 (&B)[3][3], f8 (&U)[3][3], int p, int q, int col) {
  const f8 a = B[p][col], b = B[q][col];
  const f8 rr = a * a + b * b;
  const i8 tiny = rr < 1e-30f;
  const f8 inv = vrsqrt(sel(tiny, splat(1.0f), rr));
  const f8 c = sel(tiny, splat(1.0f), a * inv);
  const f8 s = sel(tiny, splat(0.0f), b * inv);
  for (int k = 0; k < 3; ++k) {
    const f8 x = B[p][k], y = B[q][k];
    B[p][k] = c * x + s * y;
    B[q][k] = c * y - s * x;
    const f8 u = U[k][p], w = U[k][q];
    U[k][p] = c * u + s * w;
    U[k][q] = c * w - s * u;
  }
}

PUPPET_INLINE bool all_lanes(i8 m) {
  int all = -1;
  for (int i = 0; i < 8; ++i) all &= m[i];
  return all != 0;
}

// Closest rotation of eight 3x3 matrices A (row-major, lanes = matrices). Branch-free per
// lane; Jacobi sweeps stop early once every lane's off-diagonal is below float resolution.
// Vw (row-major, in/out) is the starting eigenbasis of A^T A (a proper rotation, e.g. the
// previous call's) and receives the new one.
PUPPET_INLINE void polar8(const f8 (&Ain)[3][3], f8 (&R)[3][3], f8 (&Vw)[3][3]) {
  f8 A[3][3];
  f8 m = splat(0.0f), poison = splat(0.0f);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      const f8 x = vabs(Ain[i][j]);
      m = sel(x > m, x, m);
      poison += Ain[i][j] * 0.0f;  // NaN if any entry is NaN or inf
    }
  const i8 ok = (poison == 0.0f) & (m > 0.0f);
  const f8 inv = 1.0f / sel(ok, m, splat(1.0f));
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) A[i][j] = sel(ok, Ain[i][j] * inv, splat(0.0f));

  // Re-orthonormalise the warm start (Gram-Schmidt, third column = cross product: det +1).
  const f8 one = splat(1.0f), zero = splat(0.0f);
  f8 v[3][3];  // v[col][row]
  {
    f8 a[3] = {Vw[0][0], Vw[1][0], Vw[2][0]}, b[3] = {Vw[0][1], Vw[1][1], Vw[2][1]};
    f8 na = a[0] * a[0] + a[1] * a[1] + a[2] * a[2];
    const i8 oka = (na > 0.25f) & (na < 4.0f);  // also false for NaN
    f8 ia = vrsqrt(sel(oka, na, one));
    for (int k = 0; k < 3; ++k) a[k] = sel(oka, a[k] * ia, k == 0 ? one : zero);
    const f8 d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    for (int k = 0; k < 3; ++k) b[k] -= d * a[k];
    f8 nb = b[0] * b[0] + b[1] * b[1] + b[2] * b[2];
    const i8 okb = oka & (nb > 0.25f) & (nb < 4.0f);
    f8 ib = vrsqrt(sel(okb, nb, one));
    for (int k = 0; k < 3; ++k) {
      v[0][k] = sel(okb, a[k], k == 0 ? one : zero);
      v[1][k] = sel(okb, b[k] * ib, k == 1 ? one : zero);
    }
    v[2][0] = v[0][1] * v[1][2] - v[0][2] * v[1][1];
    v[2][1] = v[0][2] * v[1][0] - v[0][0] * v[1][2];
    v[2][2] = v[0][0] * v[1][1] - v[0][1] * v[1][0];
  }
  // Symmetric B = (A V)^T (A V).
  f8 AV[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) AV[i][j] = A[i][0] * v[j][0] + A[i][1] * v[j][1] + A[i][2] * v[j][2];
  f8 b00 = AV[0][0] * AV[0][0] + AV[1][0] * AV[1][0] + AV[2][0] * AV[2][0];
  f8 b11 = AV[0][1] * AV[0][1] + AV[1][1] * AV[1][1] + AV[2][1] * AV[2][1];
  f8 b22 = AV[0][2] * AV[0][2] + AV[1][2] * AV[1][2] + AV[2][2] * AV[2][2];
  f8 b01 = AV[0][0] * AV[0][1] + AV[1][0] * AV[1][1] + AV[2][0] * AV[2][1];
  f8 b02 = AV[0][0] * AV[0][2] + AV[1][0] * AV[1][2] + AV[2][0] * AV[2][2];
  f8 b12 = AV[0][1] * AV[0][2] + AV[1][1] * AV[1][2] + AV[2][1] * AV[2][2];
  for (int sweep = 0; sweep < kJacobiSweeps; ++sweep) {
    const f8 off = b01 * b01 + b02 * b02 + b12 * b12;
    const f8 diag = b00 * b00 + b11 * b11 + b22 * b22;
    if (all_lanes(off <= 1e-15f * diag)) break;
    jacobi(b00, b11, b01, b02, b12, v[0], v[1]);
    jacobi(b00, b22, b02, b01, b12, v[0], v[2]);
    jacobi(b11, b22, b12, b01, b02, v[1], v[2]);
  }
  f8 V[3][3], B[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) V[i][j] = v[j][i];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) B[i][j] = A[i][0] * V[0][j] + A[i][1] * V[1][j] + A[i][2] * V[2][j];
  f8 rho[3];
  for (int j = 0; j < 3; ++j) rho[j] = B[0][j] * B[0][j] + B[1][j] * B[1][j] + B[2][j] * B[2][j];
  sort_pair(B, V, rho, 0, 1);
  sort_pair(B, V, rho, 0, 2);
  sort_pair(B, V, rho, 1, 2);

  // Keep the eigenbasis (before sorting: sorting would make the next call's start jump).
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) Vw[i][j] = v[j][i];
  f8 U[3][3] = {{one, zero, zero}, {zero, one, zero}, {zero, zero, one}};
  givens(B, U, 0, 1, 0);
  givens(B, U, 0, 2, 0);
  givens(B, U, 1, 2, 1);

  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) R[i][j] = U[i][0] * V[j][0] + U[i][1] * V[j][1] + U[i][2] * V[j][2];
}

// Flush-to-zero and denormals-are-zero while in scope: the Jacobi off-diagonals shrink
// quadratically into the denormal range, where x86 arithmetic is ~100x slower.
class FlushDenormals {
 public:
  FlushDenormals() : saved_(_mm_getcsr()) { _mm_setcsr(saved_ | 0x8040); }
  ~FlushDenormals() { _mm_setcsr(saved_); }

 private:
  unsigned saved_;
};

}  // namespace

void fit_rotations_soa(const float* S, float* R, std::ptrdiff_t count, std::ptrdiff_t stride, float* Vwarm) {
  FlushDenormals ftz;
  const f8 one = splat(1.0f), zero = splat(0.0f);
  for (std::ptrdiff_t g = 0; g < count; g += kLanes) {
    f8 A[3][3], Rg[3][3], Vw[3][3];
    for (int e = 0; e < 9; ++e) A[e / 3][e % 3] = *reinterpret_cast<const f8u*>(S + e * stride + g);
    for (int e = 0; e < 9; ++e)
      Vw[e / 3][e % 3] = Vwarm ? *reinterpret_cast<const f8u*>(Vwarm + e * stride + g) : (e % 4 == 0 ? one : zero);
    polar8(A, Rg, Vw);
    for (int e = 0; e < 9; ++e) *reinterpret_cast<f8u*>(R + e * stride + g) = Rg[e / 3][e % 3];
    if (Vwarm)
      for (int e = 0; e < 9; ++e) *reinterpret_cast<f8u*>(Vwarm + e * stride + g) = Vw[e / 3][e % 3];
  }
}

void fit_rotations(const float* S, float* R, std::ptrdiff_t count) {
  float s[9 * kLanes], r[9 * kLanes];
  for (std::ptrdiff_t k0 = 0; k0 < count; k0 += kLanes) {
    const std::ptrdiff_t n = count - k0 < kLanes ? count - k0 : kLanes;
    for (std::ptrdiff_t l = 0; l < kLanes; ++l)
      for (int e = 0; e < 9; ++e) s[e * kLanes + l] = l < n ? S[9 * (k0 + l) + e] : 0.0f;
    fit_rotations_soa(s, r, kLanes, kLanes);
    for (std::ptrdiff_t l = 0; l < n; ++l)
      for (int e = 0; e < 9; ++e) R[9 * (k0 + l) + e] = r[e * kLanes + l];
  }
}

}  // namespace puppet
