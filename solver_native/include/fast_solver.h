// FAST per-frame iterations (Jacobson et al. 2012): reduced ARAP in the skinning subspace.
//
// Paper / puppet.fast symbol -> member (m handles, r clusters; mp = roundup(4m, 8),
// rp = roundup(r, 8); cluster-row index rho(g, i) = i * rp + g so that entry i of the 8
// clusters g..g+7 is contiguous, which makes the rotation fit SIMD over clusters for free):
//
//   T      (4m x 3)   handle transforms, transposed         x_: 3 columns of mp floats
//   K~^T   (3r x 4m)  covariance gather, S = K~^T T         csm_: column-major, rows rho
//   S_g    (3 x 3)    S_g^T = sum w e'_ab e_ab^T            s_: 9 planes of rp floats
//   R_g    (3 x 3)    polar(S_g^T), closest rotation        rot_: 9 planes of rp floats
//   Pi_1 K~ (4m x 3r) global solve of the rotation term     g_: column-major, columns rho
//   Pi_2   (4m x c)   global solve of the fixed values      p2_: column-major
//   L~     (4m x 4m)  reduced Laplacian M^T L M (energy)    q_: column-major
//   Pi_1   (4m x 4m)  H: inverse Hessian on the null space  h_ (double): relative rows per frame
//
// Energy: E(T) = tr(T^T L~ T) - 2 sum_g tr(R_g^T S_g^T) + c0, R_g optimal for T; float32 data,
// double accumulation (resolution ~1e-6 of c0, the rest-edge scale).
// One iteration = global step T = Pi_1 K~ R + Pi_2 b (+ relative correction), then local step
// S = K~^T T, R = polar(S^T): 144 r m flops plus r rotation fits (warm-started Jacobi).
// Relative joints (child c, parent p, rotation R): rows T[4c+i] - sum_k R[k,i] T[4p+k] = 0,
// i = 0..2, added per frame by a Schur complement on the fixed-row factorisation:
//   T = Tf - Z (A_R Tf),   Z = H A_R^T (A_R H A_R^T)^{-1}   (Tf: solution with fixed rows only).
// Contacts (per-axis positional rows, e.g. a foot vertex at height 0 with x and z free): row
// M_v T[:, c] = value for the axes c listed. The rows differ between the columns x, y, z, so each
// column gets its own Schur complement (the relative rows plus that column's contact rows):
//   T[:, c] = Tf[:, c] + Z_c (b_c - A_c Tf[:, c]),   Z_c = H A_c^T (A_c H A_c^T)^{-1};
// rebuilt per frame with relative joints (their rows move), once otherwise.
// Joint limits on free handles (child c, parent p; swing cone about the bone axis d and a twist
// range about it): after each global step, the relative rotation R = polar(A_p^{-1} A_c) (A the
// linear parts) is split into swing * twist about d; where either is out of range, the step is
// projected onto the limit: the rows A_c = A_p R_lim (R_lim: R with both angles clamped) are
// added by a second Schur complement on the relative-constrained factor H_1 (made per frame):
//   T += H_1 A_L^T (A_L H_1 A_L^T)^{-1} (-A_L T),   H_1 = H - W_1 S_1^{-1} W_1^T.
// Inside the limits nothing is added (the solve is unchanged). The last iteration is always a
// plain step, so the returned T is within the limits. Not combined with contacts.
// Anderson acceleration (window 5 by default) on T -> G(T); an accelerated point whose energy is above
// the last accepted one by more than the energy's float32 resolution (1e-6 c0) is rejected for the
// plain step and the history restarts. (Rejecting on any rise, the tail of every solve rejected
// about half its steps on rounding noise alone and crawled at the plain rate.)
// Tolerance stop (tol > 0): tol is a distance in vertex space, a fraction of the rest mesh's
// bounding-box diagonal. Each iteration (before the accelerated mix), the plain step d = G(T) - T
// is measured at a few probe vertices (rows M_v of the LBS matrix, V' = M T, chosen by set_probes):
// r = max_v |M_v d|. With q the observed contraction rate (the largest of the last 5: secant
// |dG| / |dX| of the Anderson pairs, or the ratio of successive plain steps; at least the previous
// solve's), the plain step's point G(T) is within r q / (1 - q) of the fixed point (a contraction's
// a-posteriori bound). The solve stops when 1.75 times that (the margin for probe and rate noise,
// measured on the built-in character) is within tol * diagonal, and returns G(T) itself (a plain
// step, so also inside the joint limits).
//
// Everything is preallocated by the constructor; solve() allocates nothing and copies only T in
// and out of its padded layout. The relative rows' Schur complement is rebuilt only when the
// relative rotations change (a held pose keeps it).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "kernels.h"

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
  // on non-finite input. iterations >= 0 (the cap); tol <= 0 means a fixed count, tol > 0 stops once
  // the vertices are estimated within tol * diagonal of the converged result (needs set_probes).
  void solve(const float* full, const float* rel, const float* pos, const float* contact, float* T,
             int iterations, double tol, bool accelerate, bool record_history);

  // Optional dynamics (secondary motion): the energy gains (1/h^2) |T - Tp|^2_{M~} - 2 tr(T^T F)
  // with the inertial prediction Tp = T1 + damping (T1 - T2) from the last two returned T.
  // mass_h2: M~/h^2 (4m, 4m) row-major; with H the factor made with Q + M~/h^2:
  // hm = H M~/h^2 (4m, 4m), hforce = H F (4m, 3); force: F (4m, 3) (gravity: M^T mass g^T).
  // The constructor's g, p2, h come from that factor; its q stays the static Q.
  void set_dynamics(const float* mass_h2, const float* hm, const float* hforce, const float* force,
                    float damping);
  // Contacts: rows (kc, 4m) double, the vertex's LBS row M_v; axes (kc, 3) 0/1 per column.
  // Call once before solving; solve() then takes contact values (kc, 3) (unused axes ignored).
  void set_contacts(int kc, const double* rows, const int32_t* axes);
  // Limits: child, parent (nl); axis (nl, 3) unit bone direction (model space, rest);
  // bounds (nl, 3): swing max, twist min, twist max (radians).
  void set_limits(int nl, const int32_t* child, const int32_t* parent, const double* axis, const double* bounds);
  int active_limits() const { return active_; }  // limits projected in the last global step
  // Tolerance stop: rows (p, 4m) double, the LBS rows M_v of the probe vertices; diag: the rest
  // mesh's bounding-box diagonal (tol's unit); reach: the largest |v| of the rest mesh (a step
  // below float32 rounding of the vertices, kStepFloor * reach, stops at once).
  void set_probes(int p, const double* rows, double diag, double reach);
  void reset_history() { have_prev_ = false; }

  const SolveStats& stats() const { return stats_; }
  const double* history() const { return history_.data(); }
  int history_capacity() const { return static_cast<int>(history_.size()); }
  int m() const { return m_; }
  int r() const { return r_; }
  size_t kf() const { return static_cast<size_t>(kf_); }
  size_t kp() const { return static_cast<size_t>(kp_); }
  size_t kr() const { return static_cast<size_t>(kr_); }
  size_t kc() const { return static_cast<size_t>(kc_); }

 private:
  void set_values(const float* full, const float* rel, const float* pos);
  void relative_columns(const float* rel, double* w);  // W = H A_R^T (4m x 3kr, column-major)
  double local_step(const float* x, bool energy);  // S = K~^T x, R = polar; E(x) if energy
  double local_energy(const float* x);             // E(x), the local step just made at x
  void global_step(float* out);       // out = G R + Tb, then relative correction
  void column_schur();                // per-column Z_c with contacts (see above)
  void base_global_step(float* out);  // G R + Tb with the fixed, relative and contact rows
  void project_limits(float* out);    // joint limits (see above)
  double quad_energy(const float* x);
  bool converged(const float* step, double tol);  // tolerance stop for the plain step `step`
  void note_rate(double q);                       // one more observed contraction rate
  double window_rate() const;                     // the largest of the last kRateWindow rates

  int m_, r_, kf_, kp_, kr_, mp_, rp_, window_;
  std::vector<float> csm_, g_, p2_, q_;
  std::vector<int32_t> tile_off_, tile_k_;  // per gather row tile: the columns of csm_ not zero there
  std::vector<int32_t> gtile_off_, gtile_k_;  // per row tile of g_: its columns not zero there (not the
                                              // padding clusters'), visited by the global product
  std::vector<double> h_;
  double c0_;
  const Kernels* k_;  // SIMD kernels for this CPU
  std::vector<int32_t> child_, parent_;
  // per-frame
  std::vector<float> tb_, z_;           // Tb (3 x mp), Z (3kr x mp)
  std::vector<double> w_, schur_;       // W (4m x 3kr), S (3kr x 3kr)
  std::vector<double> zd_;              // Z^T = S^{-1} W^T in double (3kr or more x 4m), scratch
  std::vector<float> relR_;             // (kr, 3, 3) of the last solve
  bool schur_ready_ = false;            // z_ (and h1_) made for relR_ (no contacts)
  // contacts
  int kc_ = 0, ncmax_ = 0;
  bool contacts_ready_ = false;
  std::vector<double> crow64_, wc_, schurc_;  // rows (kc x 4m), W_c, S_c
  std::vector<float> crow_, cval_, zc_, yc_;          // rows (kc x mp), values (kc x 3), Z_c, y
  std::vector<int32_t> cidx_[3];                      // contacts constraining column c
  // joint limits
  int nl_ = 0, active_ = 0;
  std::vector<int32_t> lchild_, lparent_, lact_;
  std::vector<double> laxis_, lbound_, lrot_;          // (nl, 3), (nl, 3), active R_lim (nl, 9)
  std::vector<double> wl_, h1_, sl_, yl_;               // W_L1, H_1 (4m x 4m), S_L, y
  // per-iteration
  std::vector<float> s_, rot_, vwarm_, qx_, y_;  // vwarm_: per-cluster Jacobi warm start
  double lin_ = 0.0;                    // sum_g tr(R_g^T C_g) from the last local step
  // Anderson
  std::vector<float> x_, gx_, f_, gprev_, fprev_, xacc_, dG_, dF_;
  double energy_noise_ = 0.0;         // float32 resolution of E (1e-6 c0): the safeguard's slack
  // Tolerance stop: probe rows (4m x pp column-major, pp = roundup(p, 8)), their displacements
  // for one step (3 x pp), the last kRateWindow rates observed in this solve (a ring).
  static constexpr int kRateWindow = 5;
  int np_ = 0, pp_ = 0;
  double diag_ = 0.0, reach_ = 0.0;
  std::vector<float> probe_, pv_;
  std::vector<float> xold_;            // T before a plain iteration (its step, tol stop)
  double rates_[kRateWindow] = {};
  int nrates_ = 0, rhead_ = 0;
  double rate_floor_ = 0.0;            // the previous tol solve's window rate (below kMaxRate)
  double step2_prev_ = 0.0;            // plain path: |previous step|^2 (ratio of successive steps)
  std::vector<double> gram_, gram_full_, rhs_, gamma_;  // gram_full_: by buffer slot
  std::vector<double> history_;
  SolveStats stats_;
  // The T returned by the last solve, whose local step (s_, rot_, energy) is still current.
  std::vector<float> last_T_;
  double cached_energy_ = 0.0;
  bool cache_valid_ = false;
  // Dynamics: M~/h^2 and H M~/h^2 (column-major, mp x 4m), F, H F, inertia history, scratch.
  bool dynamics_ = false, have_prev_ = false;
  float damping_ = 0.0f;
  std::vector<float> mh_, hf_, force_, hforce_, tprev_, tprev2_, tp_, bd_, td_;
};

}  // namespace puppet
