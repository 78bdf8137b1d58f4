// nanobind module puppet._native: the per-frame numeric core of puppet.
//
// Hot functions take fixed-dtype, C-contiguous arrays without conversion and
// release the GIL while they run.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>

#include <cmath>
#include <stdexcept>
#include <string>

#include "array_types.h"
#include "fast_solver.h"
#include "fit_rotations.h"
#include "kernels.h"

namespace nb = nanobind;
using namespace puppet;

namespace {

void fit_rotations_py(ConstMat3Stack S, Mat3Stack R, int interleave) {
  if (S.shape(0) != R.shape(0))
    throw std::invalid_argument("fit_rotations: S has " + std::to_string(S.shape(0)) +
                                " matrices, R has " + std::to_string(R.shape(0)));
  if (interleave < 1 || interleave > kRotationInterleave)
    throw std::invalid_argument("fit_rotations: interleave is " + std::to_string(interleave) + ", must be 1.." +
                                std::to_string(kRotationInterleave));
  fit_rotations(S.data(), R.data(), static_cast<std::ptrdiff_t>(S.shape(0)), interleave);
}

std::string shape_msg(const char* name, size_t got, size_t want) {
  return std::string("solve: ") + name + " has " + std::to_string(got) + " rows, the pattern needs " +
         std::to_string(want);
}

FastSolver* make_solver(int m, int r, int kf, int kp, int kr, ConstMatrixF csm, ConstMatrixF g, ConstMatrixF p2,
                        ConstMatrixF q, ConstMatrixD h, double c0, ConstIndexVec rel_child,
                        ConstIndexVec rel_parent, int anderson_window, int history_capacity) {
  const size_t n4 = 4 * static_cast<size_t>(m), r3 = 3 * static_cast<size_t>(r);
  auto need = [](const char* name, size_t a, size_t b, size_t ea, size_t eb) {
    if (a != ea || b != eb)
      throw std::invalid_argument(std::string("FastSolver: ") + name + " is (" + std::to_string(a) + ", " +
                                  std::to_string(b) + "), expected (" + std::to_string(ea) + ", " +
                                  std::to_string(eb) + ")");
  };
  if (m <= 0 || r <= 0 || kf < 0 || kp < 0 || kr < 0) throw std::invalid_argument("FastSolver: bad sizes");
  need("csm", csm.shape(0), csm.shape(1), n4, r3);
  need("g", g.shape(0), g.shape(1), n4, r3);
  need("p2", p2.shape(0), p2.shape(1), n4, 4 * static_cast<size_t>(kf) + kp);
  need("q", q.shape(0), q.shape(1), n4, n4);
  need("h", h.shape(0), h.shape(1), n4, n4);
  if (rel_child.shape(0) != static_cast<size_t>(kr) || rel_parent.shape(0) != static_cast<size_t>(kr))
    throw std::invalid_argument("FastSolver: rel_child/rel_parent need kr entries");
  for (int i = 0; i < kr; ++i)
    if (rel_child.data()[i] < 0 || rel_child.data()[i] >= m || rel_parent.data()[i] < 0 ||
        rel_parent.data()[i] >= m)
      throw std::invalid_argument("FastSolver: relative handle index out of range");
  return new FastSolver(m, r, kf, kp, kr, csm.data(), g.data(), p2.data(), q.data(), h.data(), c0,
                        rel_child.data(), rel_parent.data(), anderson_window, history_capacity);
}

// FastSolver.solve as the per-frame loop calls it. nanobind's import of an ndarray argument costs
// ~0.3 us (measured: ~1.4 us of a 10-iteration m = 5 call's ~16 us went to its five arrays), so
// the call keeps the last five array objects it checked (a reference each) and a call handed the
// same five objects again (the loop's Values and T, every frame) reuses their pointers. A held
// array cannot be freed or resized (NumPy refuses while a reference is held), so its data pointer
// and size stay valid.
class SolveCall {
 public:
  explicit SolveCall(nb::handle solver) : owner_(nb::borrow(solver)), solver_(nb::cast<FastSolver*>(solver)) {}

  void operator()(nb::handle full, nb::handle rel, nb::handle pos, nb::handle contact, nb::handle T,
                  int iterations, double tol, bool accelerate, bool record_history) {
    const nb::handle args[kArrays] = {full, rel, pos, contact, T};
    bool same = true;
    for (int i = 0; i < kArrays; ++i) same = same && args[i].ptr() == held_[i].ptr();
    if (!same) check_and_hold(args);
    nb::gil_scoped_release release;
    solver_->solve(full_, rel_, pos_, contact_, t_, iterations, tol, accelerate, record_history);
  }

 private:
  static constexpr int kArrays = 5;

  // The array `what` as Array without conversion (a wrong dtype, layout or shape: TypeError).
  template <class Array>
  static Array take(nb::handle h, const char* what, const char* shape) {
    Array a;
    if (!nb::try_cast<Array>(h, a, false))
      throw nb::type_error(
          (std::string("solve: ") + what + " must be a C-contiguous float32 array of shape " + shape).c_str());
    return a;
  }

  // The checks of a first call with these arrays: dtype and layout (TypeError), counts (ValueError).
  void check_and_hold(const nb::handle (&args)[kArrays]) {
    const FastSolver& s = *solver_;
    FullValues full = take<FullValues>(args[0], "values.full", "(kf, 4, 3)");
    ConstMat3Stack rel = take<ConstMat3Stack>(args[1], "values.relative", "(kr, 3, 3)");
    PosValues pos = take<PosValues>(args[2], "values.positional", "(kp, 3)");
    PosValues contact = take<PosValues>(args[3], "values.contact", "(kc, 3)");
    TransformsF T = take<TransformsF>(args[4], "T", "(4m, 3)");
    if (T.shape(0) != 4 * static_cast<size_t>(s.m()))
      throw std::invalid_argument("solve: T has " + std::to_string(T.shape(0)) + " rows, expected 4m = " +
                                  std::to_string(4 * s.m()));
    if (full.shape(0) != s.kf()) throw std::invalid_argument(shape_msg("values.full", full.shape(0), s.kf()));
    if (rel.shape(0) != s.kr()) throw std::invalid_argument(shape_msg("values.relative", rel.shape(0), s.kr()));
    if (pos.shape(0) != s.kp()) throw std::invalid_argument(shape_msg("values.positional", pos.shape(0), s.kp()));
    if (contact.shape(0) != s.kc())
      throw std::invalid_argument(shape_msg("values.contact", contact.shape(0), s.kc()));
    for (int i = 0; i < kArrays; ++i) held_[i] = nb::borrow(args[i]);
    full_ = full.data();
    rel_ = rel.data();
    pos_ = pos.data();
    contact_ = contact.data();
    t_ = T.data();
  }

  nb::object owner_;  // the FastSolver (kept alive)
  FastSolver* solver_;
  nb::object held_[kArrays];
  const float *full_ = nullptr, *rel_ = nullptr, *pos_ = nullptr, *contact_ = nullptr;
  float* t_ = nullptr;
};

}  // namespace

NB_MODULE(_native, m) {
  m.doc() = "puppet's native core: FAST per-frame iterations (C++17, Eigen).";
  m.attr("simd") = kernels().isa;  // instruction set of the kernels chosen for this CPU

  m.attr("rotation_interleave") = kRotationInterleave;  // most batches of 8 the rotation fit runs at once
  m.def("fit_rotations", &fit_rotations_py, nb::arg("S").noconvert(), nb::arg("R").noconvert(),
        nb::arg("interleave") = kRotationInterleave, nb::call_guard<nb::gil_scoped_release>(),
        "Closest proper rotation of each 3x3 matrix, written into R.\n\n"
        "S: (r, 3, 3) float32 C-contiguous covariances.\n"
        "R: (r, 3, 3) float32 C-contiguous output, R[k] in SO(3) minimising ||R[k] - S[k]||_F.\n"
        "Zero or non-finite S[k] gives the identity; reflections are corrected (det R = +1).\n"
        "interleave: the most batches of 8 matrices computed at once (1..rotation_interleave; 1 is the\n"
        "plain schedule, one batch at a time); results agree across values to float32 rounding.");

  nb::class_<SolveStats>(m, "SolveStats", "Statistics of the last FastSolver.solve call (updated in place).")
      .def_ro("iterations", &SolveStats::iterations, "global steps run")
      .def_ro("energy", &SolveStats::energy, "reduced ARAP energy of the returned T (model units^2)")
      .def_ro("rejected", &SolveStats::rejected, "accelerated steps rejected by the energy safeguard")
      .def_ro("history_size", &SolveStats::history_size, "entries of FastSolver.history filled")
      .def("__repr__", [](const SolveStats& s) {
        return "SolveStats(iterations=" + std::to_string(s.iterations) + ", energy=" + std::to_string(s.energy) +
               ", rejected=" + std::to_string(s.rejected) + ")";
      });

  nb::class_<SolveCall>(m, "SolveCall",
                        "FastSolver.solve for a per-frame loop: SolveCall(solver)(full, relative, positional, "
                        "contact, T, iterations, tol, accelerate, record_history) runs FAST iterations, updating T "
                        "(4m, 3) float32 in place (warm start from T); the arrays of the last call are kept "
                        "(checked once, not converted again while the same objects come back).")
      .def(nb::init<nb::handle>(), nb::arg("solver"))
      .def("__call__", &SolveCall::operator(), nb::arg("full"), nb::arg("relative"), nb::arg("positional"),
           nb::arg("contact"), nb::arg("T"), nb::arg("iterations"), nb::arg("tol"), nb::arg("accelerate"),
           nb::arg("record_history"));

  nb::class_<FastSolver>(m, "FastSolver",
                         "Per-pattern FAST solver state (see solver_native/include/fast_solver.h). "
                         "Build it through puppet.fast.FastModel.solver().")
      .def("__init__",
           [](FastSolver* self, int m_, int r, int kf, int kp, int kr, ConstMatrixF csm, ConstMatrixF g,
              ConstMatrixF p2, ConstMatrixF q, ConstMatrixD h, double c0, ConstIndexVec rel_child,
              ConstIndexVec rel_parent, int anderson_window, int history_capacity) {
             FastSolver* tmp = make_solver(m_, r, kf, kp, kr, csm, g, p2, q, h, c0, rel_child, rel_parent,
                                           anderson_window, history_capacity);
             new (self) FastSolver(std::move(*tmp));
             delete tmp;
           },
           nb::arg("m"), nb::arg("r"), nb::arg("kf"), nb::arg("kp"), nb::arg("kr"), nb::arg("csm"), nb::arg("g"),
           nb::arg("p2"), nb::arg("q"), nb::arg("h"), nb::arg("c0"), nb::arg("rel_child"), nb::arg("rel_parent"),
           nb::arg("anderson_window") = 5, nb::arg("history_capacity") = 1024)
      .def("set_dynamics",
           [](FastSolver& s, ConstMatrixF mass_h2, ConstMatrixF hm, ConstMatrixF hforce, ConstMatrixF force,
              float damping) {
             const size_t n4 = 4 * static_cast<size_t>(s.m());
             auto sq = [n4](const ConstMatrixF& a) { return a.shape(0) == n4 && a.shape(1) == n4; };
             auto th = [n4](const ConstMatrixF& a) { return a.shape(0) == n4 && a.shape(1) == 3; };
             if (!sq(mass_h2) || !sq(hm) || !th(hforce) || !th(force))
               throw std::invalid_argument("set_dynamics: expected (4m, 4m), (4m, 4m), (4m, 3), (4m, 3) matrices");
             s.set_dynamics(mass_h2.data(), hm.data(), hforce.data(), force.data(), damping);
           },
           nb::arg("mass_h2"), nb::arg("hm"), nb::arg("hforce"), nb::arg("force"), nb::arg("damping"),
           "Enable dynamics (see fast_solver.h): the solver's factor must be made with Q + M~/h^2.")
      .def("set_contacts",
           [](FastSolver& s, ConstMatrixD rows, ConstMatrixI axes) {
             const size_t n4 = 4 * static_cast<size_t>(s.m());
             if (rows.shape(1) != n4 || axes.shape(0) != rows.shape(0) || axes.shape(1) != 3)
               throw std::invalid_argument("set_contacts: expected rows (kc, 4m) and axes (kc, 3)");
             s.set_contacts(static_cast<int>(rows.shape(0)), rows.data(), axes.data());
           },
           nb::arg("rows"), nb::arg("axes"),
           "Per-axis positional rows (contacts): rows (kc, 4m) float64 LBS rows, axes (kc, 3) int32 0/1.")
      .def("set_limits",
           [](FastSolver& s, ConstIndexVec child, ConstIndexVec parent, ConstMatrixD axis, ConstMatrixD bounds) {
             const size_t nl = child.shape(0);
             if (parent.shape(0) != nl || axis.shape(0) != nl || axis.shape(1) != 3 || bounds.shape(0) != nl ||
                 bounds.shape(1) != 3)
               throw std::invalid_argument("set_limits: expected child, parent (nl,), axis (nl, 3), bounds (nl, 3)");
             for (size_t i = 0; i < nl; ++i)
               if (child.data()[i] < 0 || child.data()[i] >= s.m() || parent.data()[i] < 0 ||
                   parent.data()[i] >= s.m())
                 throw std::invalid_argument("set_limits: handle index out of range");
             s.set_limits(static_cast<int>(nl), child.data(), parent.data(), axis.data(), bounds.data());
           },
           nb::arg("child"), nb::arg("parent"), nb::arg("axis"), nb::arg("bounds"),
           "Joint limits on free handles: axis (nl, 3) unit bone directions, bounds (nl, 3) radians "
           "(swing max, twist min, twist max).")
      .def("set_probes",
           [](FastSolver& s, ConstMatrixD rows, double diag, double reach) {
             if (rows.shape(1) != 4 * static_cast<size_t>(s.m()) || rows.shape(0) == 0)
               throw std::invalid_argument("set_probes: expected rows (p, 4m) with p >= 1");
             if (!(diag > 0.0) || !std::isfinite(diag) || !(reach > 0.0) || !std::isfinite(reach))
               throw std::invalid_argument("set_probes: diag and reach must be positive and finite");
             s.set_probes(static_cast<int>(rows.shape(0)), rows.data(), diag, reach);
           },
           nb::arg("rows"), nb::arg("diag"), nb::arg("reach"),
           "Tolerance stop: rows (p, 4m) float64, the LBS rows M_v of the probe vertices (V' = M T); "
           "diag: the rest mesh's bounding-box diagonal (tol's unit); reach: the largest |v| of the rest mesh.")
      .def_prop_ro("active_limits", &FastSolver::active_limits, "limits projected in the last global step")
      .def("reset_history", &FastSolver::reset_history,
           "Forget the inertia history: the next solve starts at rest (no velocity).")
      .def_prop_ro("stats", [](FastSolver& s) -> const SolveStats& { return s.stats(); },
                   nb::rv_policy::reference_internal)
      .def_prop_ro("history",
                   [](FastSolver& s) {
                     return nb::ndarray<nb::numpy, const double, nb::ndim<1>>(
                         s.history(), {static_cast<size_t>(s.history_capacity())}, nb::handle());
                   },
                   nb::rv_policy::reference_internal,
                   "(capacity,) float64 view: energies recorded by solve(record_history=True)")
      .def_prop_ro("m", &FastSolver::m)
      .def_prop_ro("r", &FastSolver::r);
}
