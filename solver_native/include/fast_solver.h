// FAST per-frame iterations (Jacobson et al. 2012), reduced ARAP in the skinning subspace.
//
// Paper notation -> members (m handles, r clusters, padded sizes mp = roundup(4m, 8),
// rp = roundup(r, 8); "SoA" row index rho = 3 * rp ... see below):
//
//   T   (4m x 3)  handle transforms transposed            x_ (3 columns of mp floats, SoA)
//   K~^T (3r x 4m) covariance gather, S = K~^T T          csm_ : column-major, rows rho(g,i) = i*rp + g
//   Pi_1 K~ (4m x 3r) global solve of the rotation term   g_   : column-major, cols rho(g,i)
//   Pi_2 (4m x c)   global solve of the fixed values      p2_  : column-major, one column per value row
//   L~ (4m x 4m)   reduced Laplacian, for the energy      q_   : column-major
//   H  (4m x 4m)   Pi_1 (inverse Hessian on the fixed-constraint null space), per-frame relative rows
//
// Energy: E(T) = tr(T^T L~ T) - 2 sum_g tr(R_g^T C_g) + c0 with R_g = polar(C_g) (C_g = S_g^T).
// Relative joints (child c, parent p, rotation R): rows T[4c+i] - sum_k R[k,i] T[4p+k] = 0,
// i = 0..2, added per frame by a Schur complement on top of the fixed-row factorisation:
//   T = Tf - Z (A_R Tf),   Z = H A_R^T (A_R H A_R^T)^{-1}   (Tf: solution with fixed rows only).
//
// Everything is preallocated by the constructor; solve() allocates nothing.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace puppet {

struct SolveStats {
  int iterations = 0;       // global steps run
  double energy = 0.0;      // E(T) of the returned T
  int rejected = 0;         // accelerated steps rejected by the energy safeguard
  int history_size = 0;     // entries of history() filled (<= capacity)
};

class FastSolver {
 public:
  // Sizes: m handles, r clusters, kf full handles, kp positional rows, kr relative joints.
  // csm: (4m, 3r) row-major K~ (column 3g+i);  g: (4m, 3r) row-major Pi_1 K~;
  // p2: (4m, 4kf + kp) row-major;  q: (4m, 4m);  h: (4m, 4m) double;  c0: rest energy constant.
  FastSolver(int m, int r, int kf, int kp, int kr, const float* csm, const float* g, const float* p2,
             const float* q, const double* h, double c0, const int32_t* rel_child,
             const int32_t* rel_parent, int anderson_window, int history_capacity);

  // full (kf,4,3), rel (kr,3,3), pos (kp,3), T (4m,3) in/out. Throws std::invalid_argument
  // on non-finite input. iterations >= 0; tol <= 0 means a fixed count.
  void solve(const float* full, const float* rel, const float* pos, float* T, int iterations,
             double tol, bool accelerate, bool record_history);

  const SolveStats& stats() const { return stats_; }
  const double* history() const { return history_.data(); }
  int history_capacity() const { return static_cast<int>(history_.size()); }
  int m() const { return m_; }
  int r() const { return r_; }
  size_t kf() const { return static_cast<size_t>(kf_); }
  size_t kp() const { return static_cast<size_t>(kp_); }
  size_t kr() const { return static_cast<size_t>(kr_); }

 private:
  void set_values(const float* full, const float* rel, const float* pos);
  double local_step(const float* x, bool energy);  // S = K~^T x, R = polar; E(x) if energy
  void global_step(float* out);       // out = G R + Tb, then relative correction
  double quad_energy(const float* x);

  int m_, r_, kf_, kp_, kr_, mp_, rp_, window_;
  std::vector<float> csm_, g_, p2_, q_;
  std::vector<double> h_;
  double c0_;
  std::vector<int32_t> child_, parent_;
  // per-frame
  std::vector<float> tb_, z_;           // Tb (3 x mp), Z (3kr x mp)
  std::vector<double> w_, schur_;       // W (4m x 3kr), S (3kr x 3kr)
  std::vector<float> relR_;             // (kr, 3, 3)
  // per-iteration
  std::vector<float> s_, rot_, vwarm_, qx_, y_;  // vwarm_: per-cluster Jacobi warm start
  double lin_ = 0.0;                    // sum_g tr(R_g^T C_g) from the last local step
  // Anderson
  std::vector<float> x_, gx_, f_, gprev_, fprev_, xacc_, dG_, dF_;
  std::vector<double> gram_, rhs_, gamma_;
  std::vector<double> history_;
  SolveStats stats_;
  // The T returned by the last solve, whose local step (s_, rot_, energy) is still current.
  std::vector<float> last_T_;
  double cached_energy_ = 0.0;
  bool cache_valid_ = false;
};

}  // namespace puppet
