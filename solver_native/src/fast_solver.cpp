#include "fast_solver.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>

#include "kernels.h"

namespace puppet {

namespace {

constexpr int kPad = 8;
constexpr double kStepFloor = 4e-7;  // relative to the mesh's reach: a step at float32 rounding of the vertices
constexpr double kMaxRate = 0.995;   // observed rates above this are not a contraction (yet)
constexpr double kStopMargin = 1.75;  // tol stop: estimate x this <= tol (probe and rate noise; see converged)
constexpr double kEnergyResolution = 1e-6;  // of c0: float32 data, double sums (the safeguard's slack)
inline int round_up(int x) { return (x + kPad - 1) / kPad * kPad; }

// A matrix entry for the per-iteration float32 kernels: below float32's normal range it is 0.
// (Far tails of smooth weights leave entries ~1e-40 in K~; every product with such a subnormal
// takes a microcode assist, which made a 24-bone rig's iterations ten times slower. What they
// contribute is below float32 rounding of any sum they enter.)
inline float normal_or_zero(double x) {
  const float f = static_cast<float>(x);
  return std::fabs(f) < std::numeric_limits<float>::min() ? 0.0f : f;
}

bool all_finite(const float* p, std::ptrdiff_t n) {
  float poison = 0.0f;
  for (std::ptrdiff_t i = 0; i < n; ++i) poison += p[i] * 0.0f;
  return poison == 0.0f;
}

// In-place Cholesky of an n x n SPD matrix (column-major, lower). False if not SPD.
bool cholesky(double* a, int n) {
  for (int j = 0; j < n; ++j) {
    double d = a[j * n + j];
    for (int k = 0; k < j; ++k) d -= a[k * n + j] * a[k * n + j];
    if (!(d > 0.0) || !std::isfinite(d)) return false;
    d = std::sqrt(d);
    a[j * n + j] = d;
    for (int i = j + 1; i < n; ++i) {
      double s = a[j * n + i];
      for (int k = 0; k < j; ++k) s -= a[k * n + i] * a[k * n + j];
      a[j * n + i] = s / d;
    }
  }
  return true;
}

// Solve L L^T x = b in place with the factor from cholesky().
void cholesky_solve(const double* l, int n, double* b) {
  for (int i = 0; i < n; ++i) {
    double s = b[i];
    for (int k = 0; k < i; ++k) s -= l[k * n + i] * b[k];
    b[i] = s / l[i * n + i];
  }
  for (int i = n - 1; i >= 0; --i) {
    double s = b[i];
    for (int k = i + 1; k < n; ++k) s -= l[i * n + k] * b[k];
    b[i] = s / l[i * n + i];
  }
}

// Per row tile of A (see for_each_tile; column k of A at a[k * lda]): the columns k < K not zero on
// that tile, listed in ks, tile t's from off[t] to off[t + 1] (gemm3_sparse visits only those).
void nonzero_columns(const float* a, std::ptrdiff_t lda, int rows, int K, std::vector<int32_t>& off,
                     std::vector<int32_t>& ks) {
  off.assign(1, 0);
  ks.clear();
  for_each_tile(rows, [&](int i, int size) {
    for (int k = 0; k < K; ++k) {
      bool nonzero = false;
      for (int t = 0; t < size; ++t) nonzero |= a[k * lda + i + t] != 0.0f;
      if (nonzero) ks.push_back(k);
    }
    off.push_back(static_cast<int32_t>(ks.size()));
  });
}

}  // namespace

FastSolver::FastSolver(int m, int r, int kf, int kp, int kr, const float* csm, const float* g,
                       const float* p2, const float* q, const double* h, double c0,
                       const int32_t* rel_child, const int32_t* rel_parent, int anderson_window,
                       int history_capacity)
    : m_(m), r_(r), kf_(kf), kp_(kp), kr_(kr), mp_(round_up(4 * m)), rp_(round_up(r)),
      window_(std::max(1, anderson_window)), c0_(c0), k_(&kernels()) {
  const int n4 = 4 * m, rr = 3 * rp_, nb = 4 * kf + kp, nR = 3 * kr;
  csm_.assign(static_cast<size_t>(n4) * rr, 0.0f);
  g_.assign(static_cast<size_t>(rr) * mp_, 0.0f);
  for (int k = 0; k < n4; ++k)
    for (int gg = 0; gg < r; ++gg)
      for (int i = 0; i < 3; ++i) {
        const int rho = i * rp_ + gg;
        csm_[static_cast<size_t>(k) * rr + rho] = normal_or_zero(csm[static_cast<size_t>(k) * 3 * r + 3 * gg + i]);
        g_[static_cast<size_t>(rho) * mp_ + k] = normal_or_zero(g[static_cast<size_t>(k) * 3 * r + 3 * gg + i]);
      }
  nonzero_columns(csm_.data(), rr, rr, n4, tile_off_, tile_k_);
  nonzero_columns(g_.data(), mp_, mp_, rr, gtile_off_, gtile_k_);
  p2_.assign(static_cast<size_t>(std::max(nb, 1)) * mp_, 0.0f);
  for (int k = 0; k < n4; ++k)
    for (int j = 0; j < nb; ++j) p2_[static_cast<size_t>(j) * mp_ + k] = normal_or_zero(p2[static_cast<size_t>(k) * nb + j]);
  q_.assign(static_cast<size_t>(n4) * mp_, 0.0f);
  for (int k = 0; k < n4; ++k)
    for (int j = 0; j < n4; ++j) q_[static_cast<size_t>(j) * mp_ + k] = normal_or_zero(q[static_cast<size_t>(k) * n4 + j]);
  h_.assign(h, h + static_cast<size_t>(n4) * n4);
  child_.assign(rel_child, rel_child + kr);
  parent_.assign(rel_parent, rel_parent + kr);

  tb_.assign(3 * static_cast<size_t>(mp_), 0.0f);
  z_.assign(static_cast<size_t>(std::max(nR, 1)) * mp_, 0.0f);
  w_.assign(static_cast<size_t>(std::max(nR, 1)) * n4, 0.0);
  zd_.assign(static_cast<size_t>(std::max(nR, 1)) * n4, 0.0);
  schur_.assign(static_cast<size_t>(std::max(nR * nR, 1)), 0.0);
  relR_.assign(static_cast<size_t>(std::max(kr, 1)) * 9, 0.0f);
  s_.assign(3 * static_cast<size_t>(rr), 0.0f);
  rot_.assign(3 * static_cast<size_t>(rr), 0.0f);
  vwarm_.assign(3 * static_cast<size_t>(rr), 0.0f);
  for (int e = 0; e < 9; e += 4)
    for (int gg = 0; gg < rp_; ++gg) vwarm_[static_cast<size_t>(e) * rp_ + gg] = 1.0f;
  qx_.assign(3 * static_cast<size_t>(mp_), 0.0f);
  y_.assign(static_cast<size_t>(std::max(nR, 1)) * 3, 0.0f);
  const size_t D = 3 * static_cast<size_t>(mp_);
  for (auto* v : {&x_, &gx_, &f_, &gprev_, &fprev_, &xacc_, &xold_}) v->assign(D, 0.0f);
  dG_.assign(D * window_, 0.0f);
  dF_.assign(D * window_, 0.0f);
  gram_.assign(static_cast<size_t>(window_) * window_, 0.0);
  gram_full_.assign(static_cast<size_t>(window_) * window_, 0.0);
  rhs_.assign(window_, 0.0);
  gamma_.assign(window_, 0.0);
  history_.assign(std::max(history_capacity, 1), 0.0);
  last_T_.assign(12 * static_cast<size_t>(m), 0.0f);
  energy_noise_ = kEnergyResolution * std::fabs(c0);
}

void FastSolver::set_probes(int p, const double* rows, double diag, double reach) {
  const int n4 = 4 * m_;
  np_ = p;
  pp_ = round_up(std::max(p, 1));
  probe_.assign(static_cast<size_t>(n4) * pp_, 0.0f);
  for (int i = 0; i < p; ++i)
    for (int k = 0; k < n4; ++k) probe_[static_cast<size_t>(k) * pp_ + i] = normal_or_zero(rows[static_cast<size_t>(i) * n4 + k]);
  pv_.assign(3 * static_cast<size_t>(pp_), 0.0f);
  diag_ = diag;
  reach_ = reach;
}

void FastSolver::set_contacts(int kc, const double* rows, const int32_t* axes) {
  const int n4 = 4 * m_;
  kc_ = kc;
  crow64_.assign(rows, rows + static_cast<size_t>(kc) * n4);
  crow_.assign(static_cast<size_t>(std::max(kc, 1)) * mp_, 0.0f);
  for (int q = 0; q < kc; ++q)
    for (int k = 0; k < n4; ++k) crow_[static_cast<size_t>(q) * mp_ + k] = normal_or_zero(rows[q * n4 + k]);
  int most = 0;
  for (int c = 0; c < 3; ++c) {
    cidx_[c].clear();
    for (int q = 0; q < kc; ++q)
      if (axes[3 * q + c]) cidx_[c].push_back(q);
    most = std::max(most, static_cast<int>(cidx_[c].size()));
  }
  ncmax_ = 3 * kr_ + most;
  const size_t nm = static_cast<size_t>(std::max(ncmax_, 1));
  wc_.assign(nm * n4, 0.0);
  zd_.assign(std::max(zd_.size(), nm * n4), 0.0);
  schurc_.assign(nm * nm, 0.0);
  zc_.assign(3 * nm * mp_, 0.0f);
  yc_.assign(nm, 0.0f);
  cval_.assign(static_cast<size_t>(std::max(kc, 1)) * 3, 0.0f);
  contacts_ready_ = false;
  cache_valid_ = false;
}

void FastSolver::column_schur() {
  const int n4 = 4 * m_, nR = 3 * kr_;
  contacts_ready_ = false;  // until every column is complete
  for (int c = 0; c < 3; ++c) {
    const int nc = nR + static_cast<int>(cidx_[c].size());
    float* zc = zc_.data() + static_cast<size_t>(c) * ncmax_ * mp_;
    if (nc == 0) continue;
    // W_c = H A_c^T: relative columns as in set_values, contact columns H M_v^T (H symmetric).
    relative_columns(relR_.data(), wc_.data());
    for (int j = nR; j < nc; ++j) {
      const double* a = crow64_.data() + static_cast<size_t>(cidx_[c][j - nR]) * n4;
      double* wcol = wc_.data() + static_cast<size_t>(j) * n4;
      for (int row = 0; row < n4; ++row) wcol[row] = 0.0;
      for (int k = 0; k < n4; ++k) {
        const double* hk = h_.data() + static_cast<size_t>(k) * n4;
        for (int row = 0; row < n4; ++row) wcol[row] += a[k] * hk[row];
      }
    }
    // S_c = A_c W_c.
    for (int col = 0; col < nc; ++col) {
      const double* wcol = wc_.data() + static_cast<size_t>(col) * n4;
      for (int qq = 0; qq < kr_; ++qq) {
        const float* R = relR_.data() + 9 * qq;
        for (int i = 0; i < 3; ++i) {
          double v = wcol[4 * child_[qq] + i];
          for (int k = 0; k < 3; ++k) v -= static_cast<double>(R[3 * k + i]) * wcol[4 * parent_[qq] + k];
          schurc_[static_cast<size_t>(col) * nc + 3 * qq + i] = v;
        }
      }
      for (int j = nR; j < nc; ++j) {
        const double* a = crow64_.data() + static_cast<size_t>(cidx_[c][j - nR]) * n4;
        double v = 0.0;
        for (int k = 0; k < n4; ++k) v += a[k] * wcol[k];
        schurc_[static_cast<size_t>(col) * nc + j] = v;
      }
    }
    if (!cholesky(schurc_.data(), nc))
      throw std::invalid_argument(
          "solve: the contacts and the other constraints are dependent (Schur complement not positive definite)");
    // Z_c = W_c S_c^{-1}: all rows of W_c at once (W_c^T's rows are W_c's columns, contiguous).
    std::copy(wc_.begin(), wc_.begin() + static_cast<size_t>(nc) * n4, zd_.begin());
    k_->cholesky_solve_rows(schurc_.data(), nc, zd_.data(), n4);
    for (int j = 0; j < nc; ++j)
      for (int row = 0; row < n4; ++row)
        zc[static_cast<size_t>(j) * mp_ + row] = static_cast<float>(zd_[static_cast<size_t>(j) * n4 + row]);
  }
  contacts_ready_ = true;
}

// W = H A_R^T for the relative rows at rotations rel (kr, 3, 3): column (q, i) of w (4m rows,
// column-major) = H[:, 4c+i] - sum_k R[k][i] H[:, 4p+k] (c, p: joint q's child and parent).
void FastSolver::relative_columns(const float* rel, double* w) {
  const int n4 = 4 * m_;
  for (int qq = 0; qq < kr_; ++qq) {
    const float* R = rel + 9 * qq;
    const double* hp[3];
    for (int k = 0; k < 3; ++k) hp[k] = h_.data() + static_cast<size_t>(4 * parent_[qq] + k) * n4;
    for (int i = 0; i < 3; ++i) {
      double* wcol = w + static_cast<size_t>(3 * qq + i) * n4;
      const double* hc = h_.data() + static_cast<size_t>(4 * child_[qq] + i) * n4;
      std::copy(hc, hc + n4, wcol);
      const double coef[3] = {R[i], R[3 + i], R[6 + i]};
      k_->subtract_rows(wcol, hp, coef, 3, n4);
    }
  }
}

void FastSolver::set_values(const float* full, const float* rel, const float* pos) {
  if (!all_finite(full, 12 * kf_)) throw std::invalid_argument("solve: values.full contains NaN or inf");
  if (!all_finite(rel, 9 * kr_)) throw std::invalid_argument("solve: values.relative contains NaN or inf");
  if (!all_finite(pos, 3 * kp_)) throw std::invalid_argument("solve: values.positional contains NaN or inf");
  // Tb = Pi_2 b, b = [full rows; positional rows].
  std::fill(tb_.begin(), tb_.end(), 0.0f);
  if (kf_ > 0) k_->gemm3(p2_.data(), mp_, mp_, 4 * kf_, full, 3, 1, tb_.data(), mp_, true);
  if (kp_ > 0) k_->gemm3(p2_.data() + static_cast<size_t>(4 * kf_) * mp_, mp_, mp_, kp_, pos, 3, 1, tb_.data(), mp_, true);
  // The relative rows' Schur complement (Z, H_1; the contacts' Z_c) depends on rel alone: a held
  // pose (the same rotations, bit for bit) keeps the last one.
  const bool same_rel = kr_ > 0 && std::memcmp(relR_.data(), rel, sizeof(float) * 9 * kr_) == 0;
  if (kr_ > 0) std::memcpy(relR_.data(), rel, sizeof(float) * 9 * kr_);
  if (kc_ > 0) {
    if (!contacts_ready_ || (kr_ > 0 && !same_rel)) column_schur();
    return;
  }
  if (kr_ == 0 || (same_rel && schur_ready_)) return;
  schur_ready_ = false;  // until this one is complete
  const int n4 = 4 * m_, nR = 3 * kr_;
  relative_columns(rel, w_.data());  // W = H A_R^T
  // S = A_R W (nR x nR, column-major).
  for (int col = 0; col < nR; ++col) {
    const double* wcol = w_.data() + static_cast<size_t>(col) * n4;
    for (int qq = 0; qq < kr_; ++qq) {
      const float* R = rel + 9 * qq;
      for (int i = 0; i < 3; ++i) {
        double v = wcol[4 * child_[qq] + i];
        for (int k = 0; k < 3; ++k) v -= static_cast<double>(R[3 * k + i]) * wcol[4 * parent_[qq] + k];
        schur_[static_cast<size_t>(col) * nR + 3 * qq + i] = v;
      }
    }
  }
  if (!cholesky(schur_.data(), nR))
    throw std::invalid_argument(
        "solve: values.relative makes the relative constraints dependent (Schur complement not positive definite)");
  // Z = W S^{-1}, all rows of W at once: Z^T = S^{-1} W^T (zd_: nR x n4, W^T's rows contiguous).
  std::copy(w_.begin(), w_.begin() + static_cast<size_t>(nR) * n4, zd_.begin());
  k_->cholesky_solve_rows(schur_.data(), nR, zd_.data(), n4);
  for (int j = 0; j < nR; ++j)
    for (int row = 0; row < n4; ++row)
      z_[static_cast<size_t>(j) * mp_ + row] = static_cast<float>(zd_[static_cast<size_t>(j) * n4 + row]);
  if (nl_ > 0) {  // H_1 = H - Z W^T (symmetric; Z = W S^{-1} in double)
    for (int row = 0; row < n4; ++row) {
      double* h1 = h1_.data() + static_cast<size_t>(row) * n4;
      const double* h = h_.data() + static_cast<size_t>(row) * n4;
      for (int col = 0; col < n4; ++col) h1[col] = h[col];
      for (int j = 0; j < nR; ++j) {
        const double bj = zd_[static_cast<size_t>(j) * n4 + row];
        const double* wj = w_.data() + static_cast<size_t>(j) * n4;
        for (int col = 0; col < n4; ++col) h1[col] -= bj * wj[col];
      }
    }
  }
  schur_ready_ = true;
}

double FastSolver::quad_energy(const float* x) {
  k_->gemm3(q_.data(), mp_, mp_, 4 * m_, x, 1, mp_, qx_.data(), mp_, false);
  double e = k_->dot_f64(x, qx_.data(), 3 * static_cast<size_t>(mp_));
  if (dynamics_) {
    // (T - Tp)^T M~/h^2 (T - Tp) - 2 tr(T^T F), evaluated on the difference (no cancellation).
    for (int i = 0; i < 3 * mp_; ++i) bd_[i] = x[i] - tp_[i];
    k_->gemm3(mh_.data(), mp_, mp_, 4 * m_, bd_.data(), 1, mp_, qx_.data(), mp_, false);
    double d = 0.0, f = 0.0;
    for (int i = 0; i < 3 * mp_; ++i) {
      d += static_cast<double>(bd_[i]) * qx_[i];
      f += static_cast<double>(x[i]) * force_[i];
    }
    e += d - 2.0 * f;
  }
  return e;
}

void FastSolver::set_dynamics(const float* mass_h2, const float* hm, const float* hforce, const float* force,
                              float damping) {
  const int n4 = 4 * m_;
  const size_t D = 3 * static_cast<size_t>(mp_);
  mh_.assign(static_cast<size_t>(n4) * mp_, 0.0f);
  hf_.assign(static_cast<size_t>(n4) * mp_, 0.0f);
  for (int k = 0; k < n4; ++k)
    for (int j = 0; j < n4; ++j) {
      mh_[static_cast<size_t>(j) * mp_ + k] = normal_or_zero(mass_h2[static_cast<size_t>(k) * n4 + j]);
      hf_[static_cast<size_t>(j) * mp_ + k] = normal_or_zero(hm[static_cast<size_t>(k) * n4 + j]);
    }
  force_.assign(D, 0.0f);
  hforce_.assign(D, 0.0f);
  for (int k = 0; k < n4; ++k)
    for (int c = 0; c < 3; ++c) {
      force_[c * mp_ + k] = force[3 * k + c];
      hforce_[c * mp_ + k] = hforce[3 * k + c];
    }
  for (auto* v : {&tprev_, &tprev2_, &tp_, &bd_, &td_}) v->assign(D, 0.0f);
  damping_ = damping;
  dynamics_ = true;
  have_prev_ = false;
  cache_valid_ = false;
}

// Tolerance stop for the plain step `step` = G(T) - T (3 x mp, T's layout) about to be taken: its
// size in vertex space r = max over the probes |M_v step| (float32 products of a small vector,
// no cancellation), the contraction rate q = the largest of the last kRateWindow rates observed in
// this solve, and at least the previous solve's (the slow rate is the rig's and the pattern's:
// early in a solve the secants see the fast modes and underestimate it). For a map contracting at
// rate q, G(T) is within r q / (1 - q) of the fixed point. kStopMargin covers the probes missing
// the farthest vertex (they see 80-100 % of the true maximum) and the secant rates running below
// the plain map's (0.95-0.975 against 0.977 on the built-in character). Measured there (30
// warm-started demo frames, accelerated, tol 1e-3 and 1e-4): every frame within 0.85 tol.
// A step at the float32 rounding floor of the vertices stops at once (already there); a rate >=
// kMaxRate (a rise, the first iterations after the targets move) never stops it.
bool FastSolver::converged(const float* step, double tol) {
  k_->gemm3(probe_.data(), pp_, pp_, 4 * m_, step, 1, mp_, pv_.data(), pp_, false);
  float best = 0.0f;
  for (int i = 0; i < np_; ++i) {
    const float a = pv_[i], b = pv_[pp_ + i], c = pv_[2 * pp_ + i];
    best = std::max(best, a * a + b * b + c * c);
  }
  const double r = std::sqrt(static_cast<double>(best));
  if (r <= kStepFloor * reach_) return true;
  if (nrates_ == 0) return false;
  const double q = std::max(window_rate(), rate_floor_);
  if (q >= kMaxRate) return false;
  return kStopMargin * r * q / (1.0 - q) <= tol * diag_;
}

double FastSolver::window_rate() const {
  double q = 0.0;
  for (int i = 0; i < nrates_; ++i) q = std::max(q, rates_[i]);
  return q;
}

void FastSolver::note_rate(double q) {
  rates_[rhead_] = q;
  rhead_ = (rhead_ + 1) % kRateWindow;
  nrates_ = std::min(nrates_ + 1, kRateWindow);
}

double FastSolver::local_step(const float* x, bool energy) {
  const int rr = 3 * rp_;
  k_->gemm3_sparse(csm_.data(), rr, rr, tile_off_.data(), tile_k_.data(), x, 1, mp_, s_.data(), rr);
  k_->fit_rotations_soa(s_.data(), rot_.data(), rp_, rp_, vwarm_.data(), kRotationInterleave);
  return energy ? local_energy(x) : 0.0;
}

double FastSolver::local_energy(const float* x) {
  const double lin = k_->dot_f64(s_.data(), rot_.data(), 9 * static_cast<size_t>(rp_));
  return quad_energy(x) - 2.0 * lin + c0_;
}

namespace {

using Mat3 = double[3][3];

bool inverse3(const Mat3& a, Mat3& inv) {
  const double c00 = a[1][1] * a[2][2] - a[1][2] * a[2][1], c01 = a[1][2] * a[2][0] - a[1][0] * a[2][2],
               c02 = a[1][0] * a[2][1] - a[1][1] * a[2][0];
  const double det = a[0][0] * c00 + a[0][1] * c01 + a[0][2] * c02;
  if (!(std::fabs(det) > 1e-300) || !std::isfinite(det)) return false;
  const double id = 1.0 / det;
  inv[0][0] = c00 * id;
  inv[1][0] = c01 * id;
  inv[2][0] = c02 * id;
  inv[0][1] = (a[0][2] * a[2][1] - a[0][1] * a[2][2]) * id;
  inv[1][1] = (a[0][0] * a[2][2] - a[0][2] * a[2][0]) * id;
  inv[2][1] = (a[0][1] * a[2][0] - a[0][0] * a[2][1]) * id;
  inv[0][2] = (a[0][1] * a[1][2] - a[0][2] * a[1][1]) * id;
  inv[1][2] = (a[0][2] * a[1][0] - a[0][0] * a[1][2]) * id;
  inv[2][2] = (a[0][0] * a[1][1] - a[0][1] * a[1][0]) * id;
  return det > 0.0;
}

// Closest rotation by Higham's iteration X <- (X + X^{-T}) / 2 (det X > 0, near a rotation).
bool polar3(Mat3& x) {
  for (int it = 0; it < 12; ++it) {
    Mat3 inv;
    if (!inverse3(x, inv)) return false;
    double change = 0.0;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        const double v = 0.5 * (x[i][j] + inv[j][i]);
        change = std::max(change, std::fabs(v - x[i][j]));
        x[i][j] = v;
      }
    if (change < 1e-12) break;
  }
  return true;
}

void quat_from(const Mat3& r, double q[4]) {  // q = (w, x, y, z)
  const double tr = r[0][0] + r[1][1] + r[2][2];
  if (tr > 0.0) {
    const double s = 2.0 * std::sqrt(tr + 1.0);
    q[0] = 0.25 * s;
    q[1] = (r[2][1] - r[1][2]) / s;
    q[2] = (r[0][2] - r[2][0]) / s;
    q[3] = (r[1][0] - r[0][1]) / s;
  } else if (r[0][0] > r[1][1] && r[0][0] > r[2][2]) {
    const double s = 2.0 * std::sqrt(1.0 + r[0][0] - r[1][1] - r[2][2]);
    q[0] = (r[2][1] - r[1][2]) / s;
    q[1] = 0.25 * s;
    q[2] = (r[0][1] + r[1][0]) / s;
    q[3] = (r[0][2] + r[2][0]) / s;
  } else if (r[1][1] > r[2][2]) {
    const double s = 2.0 * std::sqrt(1.0 + r[1][1] - r[0][0] - r[2][2]);
    q[0] = (r[0][2] - r[2][0]) / s;
    q[1] = (r[0][1] + r[1][0]) / s;
    q[2] = 0.25 * s;
    q[3] = (r[1][2] + r[2][1]) / s;
  } else {
    const double s = 2.0 * std::sqrt(1.0 + r[2][2] - r[0][0] - r[1][1]);
    q[0] = (r[1][0] - r[0][1]) / s;
    q[1] = (r[0][2] + r[2][0]) / s;
    q[2] = (r[1][2] + r[2][1]) / s;
    q[3] = 0.25 * s;
  }
}

void quat_mul(const double a[4], const double b[4], double out[4]) {
  out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
  out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
  out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
  out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
}

void matrix_from(const double q[4], double* r) {  // row-major 3x3
  const double w = q[0], x = q[1], y = q[2], z = q[3];
  r[0] = 1 - 2 * (y * y + z * z); r[1] = 2 * (x * y - z * w);     r[2] = 2 * (x * z + y * w);
  r[3] = 2 * (x * y + z * w);     r[4] = 1 - 2 * (x * x + z * z); r[5] = 2 * (y * z - x * w);
  r[6] = 2 * (x * z - y * w);     r[7] = 2 * (y * z + x * w);     r[8] = 1 - 2 * (x * x + y * y);
}

// Clamp rotation r to swing <= smax about axis d and twist in [tlo, thi]; false if inside.
bool clamp_swing_twist(const Mat3& r, const double* d, double smax, double tlo, double thi, double* out) {
  double q[4];
  quat_from(r, q);
  if (q[0] < 0.0)
    for (double& v : q) v = -v;
  const double s = q[1] * d[0] + q[2] * d[1] + q[3] * d[2];
  const double tn = std::sqrt(q[0] * q[0] + s * s);
  double twist = 0.0, qt[4] = {1.0, 0.0, 0.0, 0.0};
  if (tn > 1e-12) {
    qt[0] = q[0] / tn;
    for (int i = 0; i < 3; ++i) qt[1 + i] = s * d[i] / tn;
    twist = 2.0 * std::atan2(s / tn, qt[0]);
  }
  const double qt_conj[4] = {qt[0], -qt[1], -qt[2], -qt[3]};
  double qs[4];
  quat_mul(q, qt_conj, qs);
  if (qs[0] < 0.0)
    for (double& v : qs) v = -v;
  const double sv = std::sqrt(qs[1] * qs[1] + qs[2] * qs[2] + qs[3] * qs[3]);
  const double swing = 2.0 * std::atan2(sv, qs[0]);
  const double twist_c = std::min(std::max(twist, tlo), thi), swing_c = std::min(swing, smax);
  if (twist_c == twist && swing_c == swing) return false;
  const double ct[4] = {std::cos(0.5 * twist_c), std::sin(0.5 * twist_c) * d[0], std::sin(0.5 * twist_c) * d[1],
                        std::sin(0.5 * twist_c) * d[2]};
  double cs[4] = {1.0, 0.0, 0.0, 0.0};
  if (sv > 1e-12) {
    const double k = std::sin(0.5 * swing_c) / sv;
    cs[0] = std::cos(0.5 * swing_c);
    cs[1] = qs[1] * k;
    cs[2] = qs[2] * k;
    cs[3] = qs[3] * k;
  }
  double qc[4];
  quat_mul(cs, ct, qc);
  matrix_from(qc, out);
  return true;
}

}  // namespace

void FastSolver::set_limits(int nl, const int32_t* child, const int32_t* parent, const double* axis,
                            const double* bounds) {
  nl_ = nl;
  lchild_.assign(child, child + nl);
  lparent_.assign(parent, parent + nl);
  laxis_.assign(axis, axis + 3 * static_cast<size_t>(nl));
  lbound_.assign(bounds, bounds + 3 * static_cast<size_t>(nl));
  lact_.assign(std::max(nl, 1), 0);
  lrot_.assign(9 * static_cast<size_t>(std::max(nl, 1)), 0.0);
  const size_t nL = 3 * static_cast<size_t>(std::max(nl, 1)), n4 = 4 * static_cast<size_t>(m_);
  wl_.assign(nL * n4, 0.0);
  h1_.assign(kr_ > 0 ? n4 * n4 : 1, 0.0);
  sl_.assign(nL * nL, 0.0);
  yl_.assign(nL * 3, 0.0);
  schur_ready_ = false;  // H_1 is made with the relative rows' Schur complement
}

void FastSolver::project_limits(float* out) {
  const int n4 = 4 * m_;
  int a = 0;
  for (int l = 0; l < nl_; ++l) {
    Mat3 ap, ac, inv, x;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {  // A[i][j] = T[4h + j, i]
        ap[i][j] = out[i * mp_ + 4 * lparent_[l] + j];
        ac[i][j] = out[i * mp_ + 4 * lchild_[l] + j];
      }
    if (!inverse3(ap, inv)) continue;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) x[i][j] = inv[i][0] * ac[0][j] + inv[i][1] * ac[1][j] + inv[i][2] * ac[2][j];
    if (!polar3(x)) continue;
    const double* b = lbound_.data() + 3 * l;
    if (clamp_swing_twist(x, laxis_.data() + 3 * l, b[0], b[1], b[2], lrot_.data() + 9 * a)) lact_[a++] = l;
  }
  active_ = a;
  if (a == 0) return;
  const int nL = 3 * a;
  // W_L1 = H_1 A_L^T: column (q, i) = H_1[:, 4c+i] - sum_k R[k][i] H_1[:, 4p+k], with H_1 the
  // factor after this frame's relative rows (H itself without them).
  const double* h1 = kr_ > 0 ? h1_.data() : h_.data();
  for (int q = 0; q < a; ++q) {
    const int l = lact_[q];
    const double* R = lrot_.data() + 9 * q;
    for (int i = 0; i < 3; ++i) {
      double* wcol = wl_.data() + static_cast<size_t>(3 * q + i) * n4;
      const double* hc = h1 + static_cast<size_t>(4 * lchild_[l] + i) * n4;
      for (int row = 0; row < n4; ++row) wcol[row] = hc[row];
      for (int k = 0; k < 3; ++k) {
        const double coef = R[3 * k + i];
        const double* hp = h1 + static_cast<size_t>(4 * lparent_[l] + k) * n4;
        for (int row = 0; row < n4; ++row) wcol[row] -= coef * hp[row];
      }
    }
  }
  // S_L = A_L W_L1, y = -(A_L out) per column; out += W_L1 S_L^{-1} y.
  for (int col = 0; col < nL; ++col) {
    const double* wcol = wl_.data() + static_cast<size_t>(col) * n4;
    for (int q = 0; q < a; ++q) {
      const int l = lact_[q];
      const double* R = lrot_.data() + 9 * q;
      for (int i = 0; i < 3; ++i) {
        double v = wcol[4 * lchild_[l] + i];
        for (int k = 0; k < 3; ++k) v -= R[3 * k + i] * wcol[4 * lparent_[l] + k];
        sl_[static_cast<size_t>(col) * nL + 3 * q + i] = v;
      }
    }
  }
  if (!cholesky(sl_.data(), nL)) {
    active_ = 0;  // limits that the constraints already fix: nothing to project
    return;
  }
  for (int c = 0; c < 3; ++c) {
    float* oc = out + c * mp_;
    double* y = yl_.data() + static_cast<size_t>(c) * nL;
    for (int q = 0; q < a; ++q) {
      const int l = lact_[q];
      const double* R = lrot_.data() + 9 * q;
      for (int i = 0; i < 3; ++i) {
        double v = oc[4 * lchild_[l] + i];
        for (int k = 0; k < 3; ++k) v -= R[3 * k + i] * oc[4 * lparent_[l] + k];
        y[3 * q + i] = -v;
      }
    }
    cholesky_solve(sl_.data(), nL, y);
    for (int j = 0; j < nL; ++j) {
      const double* wcol = wl_.data() + static_cast<size_t>(j) * n4;
      for (int row = 0; row < n4; ++row) oc[row] += static_cast<float>(wcol[row] * y[j]);
    }
  }
}

void FastSolver::global_step(float* out) {
  base_global_step(out);
  if (nl_ > 0) project_limits(out);
}

void FastSolver::base_global_step(float* out) {
  const int rr = 3 * rp_;
  k_->gemm3_sparse(g_.data(), mp_, mp_, gtile_off_.data(), gtile_k_.data(), rot_.data(), 1, rr, out, mp_);
  for (int i = 0; i < 3 * mp_; ++i) out[i] += tb_[i];
  if (kc_ > 0) {
    const int nR = 3 * kr_, n4 = 4 * m_;
    for (int c = 0; c < 3; ++c) {
      float* oc = out + c * mp_;
      const int nc = nR + static_cast<int>(cidx_[c].size());
      for (int qq = 0; qq < kr_; ++qq) {
        const float* R = relR_.data() + 9 * qq;
        for (int i = 0; i < 3; ++i) {
          float v = oc[4 * child_[qq] + i];
          for (int k = 0; k < 3; ++k) v -= R[3 * k + i] * oc[4 * parent_[qq] + k];
          yc_[3 * qq + i] = -v;
        }
      }
      for (int j = nR; j < nc; ++j) {
        const int q = cidx_[c][j - nR];
        const float* a = crow_.data() + static_cast<size_t>(q) * mp_;
        double v = 0.0;
        for (int k = 0; k < n4; ++k) v += static_cast<double>(a[k]) * oc[k];
        yc_[j] = static_cast<float>(cval_[3 * q + c] - v);
      }
      const float* zc = zc_.data() + static_cast<size_t>(c) * ncmax_ * mp_;
      for (int j = 0; j < nc; ++j) {
        const float y = yc_[j];
        const float* zj = zc + static_cast<size_t>(j) * mp_;
        for (int row = 0; row < mp_; ++row) oc[row] += zj[row] * y;
      }
    }
    return;
  }
  if (kr_ == 0) return;
  // y = -(A_R out), then out += Z y.
  for (int qq = 0; qq < kr_; ++qq) {
    const float* R = relR_.data() + 9 * qq;
    for (int i = 0; i < 3; ++i)
      for (int c = 0; c < 3; ++c) {
        const float* oc = out + c * mp_;
        float v = oc[4 * child_[qq] + i];
        for (int k = 0; k < 3; ++k) v -= R[3 * k + i] * oc[4 * parent_[qq] + k];
        y_[3 * (3 * qq + i) + c] = -v;
      }
  }
  k_->gemm3(z_.data(), mp_, mp_, 3 * kr_, y_.data(), 3, 1, out, mp_, true);
}

void FastSolver::solve(const float* full, const float* rel, const float* pos, const float* contact, float* T,
                       int iterations, double tol, bool accelerate, bool record_history) {
  if (iterations < 0) throw std::invalid_argument("solve: iterations must be >= 0");
  if (tol > 0.0 && np_ == 0)
    throw std::invalid_argument("solve: tol > 0 needs set_probes() first (puppet.fast.Solver does it)");
  if (!all_finite(T, 12 * m_))
    throw std::invalid_argument("solve: T contains NaN or inf (warm start from model.rest_T() instead)");
  if (kc_ > 0 && nl_ > 0) throw std::invalid_argument("solve: joint limits are not supported together with contacts");
  if (kc_ > 0) {
    if (!all_finite(contact, 3 * kc_)) throw std::invalid_argument("solve: values.contact contains NaN or inf");
    std::memcpy(cval_.data(), contact, sizeof(float) * 3 * kc_);
  }
  set_values(full, rel, pos);
  const int n4 = 4 * m_;
  const size_t D = 3 * static_cast<size_t>(mp_);
  for (int k = 0; k < n4; ++k)
    for (int c = 0; c < 3; ++c) x_[c * mp_ + k] = T[3 * k + c];

  if (dynamics_) {
    // Inertial prediction from the last two returned poses, and the solve's extra particular
    // part H (M~/h^2 Tp + F) = (H M~/h^2) Tp + H F (both products precomputed in double).
    if (!have_prev_) {
      tprev_ = x_;
      tprev2_ = x_;
      have_prev_ = true;
    }
    for (size_t i = 0; i < D; ++i) tp_[i] = tprev_[i] + damping_ * (tprev_[i] - tprev2_[i]);
    k_->gemm3(hf_.data(), mp_, mp_, n4, tp_.data(), 1, mp_, td_.data(), mp_, false);
    for (size_t i = 0; i < D; ++i) tb_[i] += td_[i] + hforce_[i];
    cache_valid_ = false;  // the energy depends on the prediction
  }

  const bool use_tol = tol > 0.0;
  const bool need_energy = accelerate || record_history;
  const int cap = static_cast<int>(history_.size());
  stats_ = SolveStats{};
  step2_prev_ = 0.0;
  if (use_tol && nrates_ > 0) {  // the last solve's tail rate: this one's floor (the slow rate persists)
    const double q = window_rate();
    if (q < kMaxRate) rate_floor_ = q;
    nrates_ = rhead_ = 0;
  }
  // Warm start from the T this solver returned last: its covariances, rotations and energy are
  // still valid (they do not depend on the constraint values), so the first local step is free.
  double E;
  if (cache_valid_ && std::memcmp(T, last_T_.data(), sizeof(float) * 12 * m_) == 0) {
    E = cached_energy_;
  } else {
    E = local_step(x_.data(), true);
  }
  cache_valid_ = false;
  if (record_history && cap > 0) history_[stats_.history_size++] = E;
  int nh = 0, head = 0;
  bool have_prev = false;

  int it = 0;
  for (; it < iterations; ++it) {
    const double E_old = E;
    const bool last = it + 1 == iterations;
    bool stop = false;
    if (!accelerate || (nl_ > 0 && last)) {  // with limits the returned T comes from a plain step
      if (use_tol) std::memcpy(xold_.data(), x_.data(), D * sizeof(float));
      global_step(x_.data());
      E = local_step(x_.data(), need_energy || last);
      if (use_tol) {
        double ss = 0.0;  // |step|^2: the ratio of successive plain steps is the map's rate
        for (size_t i = 0; i < D; ++i) {
          f_[i] = x_[i] - xold_[i];
          ss += static_cast<double>(f_[i]) * f_[i];
        }
        if (step2_prev_ > 0.0) note_rate(std::sqrt(ss / step2_prev_));
        step2_prev_ = ss;
        stop = converged(f_.data(), tol);
        if (stop && !(need_energy || last)) E = local_energy(x_.data());  // the returned T's energy
      }
    } else {
      global_step(gx_.data());
      for (size_t i = 0; i < D; ++i) f_[i] = gx_[i] - x_[i];
      if (have_prev) {
        float* dg = dG_.data() + head * D;
        float* df = dF_.data() + head * D;
        double gg = 0.0, xx = 0.0;  // |dG|^2 and |dX|^2 (dX = dG - dF): the plain map's rate
        for (size_t i = 0; i < D; ++i) {
          dg[i] = gx_[i] - gprev_[i];
          df[i] = f_[i] - fprev_[i];
          const double dx = static_cast<double>(dg[i]) - df[i];
          gg += static_cast<double>(dg[i]) * dg[i];
          xx += dx * dx;
        }
        // Accelerated steps shrink faster than the map contracts: the rate comes from the
        // secant pair, |dG| / |dX| along the last step.
        if (use_tol) note_rate(xx > 0.0 ? std::sqrt(gg / xx) : 2.0);
        head = (head + 1) % window_;
        nh = std::min(nh + 1, window_);
      }
      if (use_tol && converged(f_.data(), tol)) {
        // Within tol: return the plain step's point, the one the estimate is about.
        std::memcpy(x_.data(), gx_.data(), D * sizeof(float));
        E = local_step(x_.data(), true);
        stop = true;
      } else {
        std::memcpy(gprev_.data(), gx_.data(), D * sizeof(float));
        std::memcpy(fprev_.data(), f_.data(), D * sizeof(float));
        have_prev = true;
        bool accel = false;
        if (nh > 0) {
          // Gram matrix of the secant differences, kept across iterations: only the newest
          // column (just written at head - 1) needs new dot products.
          const int newest = (head + window_ - 1) % window_;
          const float* fn = dF_.data() + newest * D;
          for (int b = 0; b < nh; ++b) {
            const double v = k_->dot(fn, dF_.data() + b * D, D);
            gram_full_[newest * window_ + b] = gram_full_[b * window_ + newest] = v;
          }
          double dmax = 0.0;
          for (int a = 0; a < nh; ++a) {
            rhs_[a] = k_->dot(dF_.data() + a * D, f_.data(), D);
            for (int b = 0; b < nh; ++b) gram_[a * nh + b] = gram_full_[a * window_ + b];
            dmax = std::max(dmax, gram_[a * nh + a]);
          }
          for (int a = 0; a < nh; ++a) gram_[a * nh + a] += 1e-10 * dmax + 1e-300;
          if (dmax > 0.0 && cholesky(gram_.data(), nh)) {
            for (int a = 0; a < nh; ++a) gamma_[a] = rhs_[a];
            cholesky_solve(gram_.data(), nh, gamma_.data());
            std::memcpy(xacc_.data(), gx_.data(), D * sizeof(float));
            for (int a = 0; a < nh; ++a) {
              const float ga = static_cast<float>(gamma_[a]);
              const float* dg = dG_.data() + a * D;
              for (size_t i = 0; i < D; ++i) xacc_[i] -= ga * dg[i];
            }
            accel = all_finite(xacc_.data(), static_cast<std::ptrdiff_t>(D));
          }
        }
        if (accel) {
          const double Ea = local_step(xacc_.data(), true);
          if (Ea <= E_old + energy_noise_) {
            std::swap(x_, xacc_);
            E = Ea;
          } else {
            ++stats_.rejected;
            nh = 0;
            head = 0;
            std::memcpy(x_.data(), gx_.data(), D * sizeof(float));
            E = local_step(x_.data(), true);
          }
        } else {
          std::memcpy(x_.data(), gx_.data(), D * sizeof(float));
          E = local_step(x_.data(), true);
        }
      }
    }
    if (record_history && stats_.history_size < cap) history_[stats_.history_size++] = E;
    if (stop) {
      ++it;
      break;
    }
  }
  stats_.iterations = it;
  stats_.energy = E;
  for (int k = 0; k < n4; ++k)
    for (int c = 0; c < 3; ++c) T[3 * k + c] = x_[c * mp_ + k];
  std::memcpy(last_T_.data(), T, sizeof(float) * 12 * m_);
  cached_energy_ = E;
  cache_valid_ = !dynamics_;
  if (dynamics_) {
    tprev2_ = tprev_;
    tprev_ = x_;
  }
}

}  // namespace puppet
