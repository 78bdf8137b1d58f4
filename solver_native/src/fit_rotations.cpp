#include "fit_rotations.h"

#include <cmath>

namespace puppet {

namespace {

constexpr int kJacobiSweeps = 5;
constexpr std::ptrdiff_t kLanes = 8;

// One exact Jacobi rotation zeroing b_pq of the symmetric matrix
// (b_pp, b_qq, b_pq, b_rp, b_rq), accumulating V's columns p and q.
inline void jacobi(float& bpp, float& bqq, float& bpq, float& brp, float& brq, float* vp, float* vq) {
  const bool tiny = std::fabs(bpq) < 1e-30f;
  const float denom = tiny ? 1.0f : 2.0f * bpq;
  const float theta = (bqq - bpp) / denom;
  const float at = std::fabs(theta);
  // For huge theta, theta^2 overflows to inf and t -> 0, as it should.
  float t = 1.0f / (at + std::sqrt(theta * theta + 1.0f));
  t = theta < 0.0f ? -t : t;
  t = tiny ? 0.0f : t;
  const float c = 1.0f / std::sqrt(t * t + 1.0f);
  const float s = t * c;
  bpp -= t * bpq;
  bqq += t * bpq;
  bpq = 0.0f;
  const float rp = brp, rq = brq;
  brp = c * rp - s * rq;
  brq = s * rp + c * rq;
  for (int k = 0; k < 3; ++k) {
    const float a = vp[k], b = vq[k];
    vp[k] = c * a - s * b;
    vq[k] = s * a + c * b;
  }
}

// Swap columns i and j of B and V (negating the new column j) when |B_i| < |B_j|.
inline void sort_pair(float (&B)[3][3], float (&V)[3][3], float* rho, int i, int j) {
  const bool sw = rho[i] < rho[j];
  for (int k = 0; k < 3; ++k) {
    const float bi = B[k][i], bj = B[k][j], vi = V[k][i], vj = V[k][j];
    B[k][i] = sw ? bj : bi;
    B[k][j] = sw ? -bi : bj;
    V[k][i] = sw ? vj : vi;
    V[k][j] = sw ? -vi : vj;
  }
  const float ri = rho[i], rj = rho[j];
  rho[i] = sw ? rj : ri;
  rho[j] = sw ? ri : rj;
}

// Givens rotation on rows p, q of B zeroing B[q][col]; U <- U G^T.
inline void givens(float (&B)[3][3], float (&U)[3][3], int p, int q, int col) {
  const float a = B[p][col], b = B[q][col];
  const float rr = a * a + b * b;
  const bool tiny = rr < 1e-30f;
  const float inv = 1.0f / std::sqrt(tiny ? 1.0f : rr);
  const float c = tiny ? 1.0f : a * inv;
  const float s = tiny ? 0.0f : b * inv;
  for (int k = 0; k < 3; ++k) {
    const float x = B[p][k], y = B[q][k];
    B[p][k] = c * x + s * y;
    B[q][k] = -s * x + c * y;
    const float u = U[k][p], w = U[k][q];
    U[k][p] = c * u + s * w;
    U[k][q] = -s * u + c * w;
  }
}

// Closest rotation of one 3x3 matrix A (row-major, in registers). Branch-free.
inline void polar_one(const float (&Ain)[3][3], float (&R)[3][3]) {
  float A[3][3];
  float m = 0.0f, poison = 0.0f;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      const float x = std::fabs(Ain[i][j]);
      m = x > m ? x : m;
      poison += Ain[i][j] * 0.0f;  // NaN if any entry is NaN or inf
    }
  const bool ok = (poison == 0.0f) & (m > 0.0f);
  const float inv = 1.0f / (ok ? m : 1.0f);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) A[i][j] = ok ? Ain[i][j] * inv : 0.0f;

  // Symmetric B = A^T A.
  float b00 = 0, b11 = 0, b22 = 0, b01 = 0, b02 = 0, b12 = 0;
  for (int k = 0; k < 3; ++k) {
    b00 += A[k][0] * A[k][0];
    b11 += A[k][1] * A[k][1];
    b22 += A[k][2] * A[k][2];
    b01 += A[k][0] * A[k][1];
    b02 += A[k][0] * A[k][2];
    b12 += A[k][1] * A[k][2];
  }
  // V stored by columns: v[col][row].
  float v[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  for (int sweep = 0; sweep < kJacobiSweeps; ++sweep) {
    jacobi(b00, b11, b01, b02, b12, v[0], v[1]);
    jacobi(b00, b22, b02, b01, b12, v[0], v[2]);
    jacobi(b11, b22, b12, b01, b02, v[1], v[2]);
  }
  float V[3][3], B[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) V[i][j] = v[j][i];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) B[i][j] = A[i][0] * V[0][j] + A[i][1] * V[1][j] + A[i][2] * V[2][j];
  float rho[3];
  for (int j = 0; j < 3; ++j) rho[j] = B[0][j] * B[0][j] + B[1][j] * B[1][j] + B[2][j] * B[2][j];
  sort_pair(B, V, rho, 0, 1);
  sort_pair(B, V, rho, 0, 2);
  sort_pair(B, V, rho, 1, 2);

  float U[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  givens(B, U, 0, 1, 0);
  givens(B, U, 0, 2, 0);
  givens(B, U, 1, 2, 1);

  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) R[i][j] = U[i][0] * V[j][0] + U[i][1] * V[j][1] + U[i][2] * V[j][2];
}

}  // namespace

void fit_rotations_soa(const float* S, float* R, std::ptrdiff_t count, std::ptrdiff_t stride) {
  for (std::ptrdiff_t g0 = 0; g0 < count; g0 += kLanes) {
#pragma GCC ivdep
    for (std::ptrdiff_t l = 0; l < kLanes; ++l) {
      const std::ptrdiff_t g = g0 + l;
      float A[3][3], Rg[3][3];
      for (int e = 0; e < 9; ++e) A[e / 3][e % 3] = S[e * stride + g];
      polar_one(A, Rg);
      for (int e = 0; e < 9; ++e) R[e * stride + g] = Rg[e / 3][e % 3];
    }
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
