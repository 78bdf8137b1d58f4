#include "forward_kinematics.h"

#include <cmath>

namespace puppet {

namespace {

// out = a @ b (3x3 row-major; out may not alias a or b).
inline void mul3(const double* a, const double* b, double* out) {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) out[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
}

// Rodrigues' rotation by angle x about the unit axis u (3x3 row-major), evaluated as
// (I - u u^T) cos x + u u^T + [u]_x sin x.
inline void rodrigues(const double* u, double x, double* r) {
  const double c = std::cos(x), s = std::sin(x);
  const double cross[9] = {0.0, -u[2], u[1], u[2], 0.0, -u[0], -u[1], u[0], 0.0};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      const double outer = u[i] * u[j];
      r[3 * i + j] = ((i == j ? 1.0 : 0.0) - outer) * c + outer + cross[3 * i + j] * s;
    }
}

}  // namespace

void joint_rotations(const double* angles, const double* axes, const int32_t* axis_dof,
                     const int32_t* bone_axes, int bones, double* rot) {
  for (int i = 0; i < bones; ++i) {
    double* r = rot + 9 * i;
    const int lo = bone_axes[i], hi = bone_axes[i + 1];
    if (lo == hi) {
      for (int e = 0; e < 9; ++e) r[e] = (e % 4 == 0) ? 1.0 : 0.0;
      continue;
    }
    rodrigues(axes + 3 * lo, angles[axis_dof[lo]], r);
    for (int a = lo + 1; a < hi; ++a) {  // r = r @ Rod(axis a): the first axis stays outermost
      double next[9], prod[9];
      rodrigues(axes + 3 * a, angles[axis_dof[a]], next);
      mul3(r, next, prod);
      for (int e = 0; e < 9; ++e) r[e] = prod[e];
    }
  }
}

void pose_from_rotations(const double* rot, const int32_t* parents, const double* heads, int bones,
                         double* pose) {
  for (int i = 0; i < bones; ++i) {
    const double* r = rot + 9 * i;
    const double* h = heads + 3 * i;
    double* out = pose + 12 * i;
    double offset[3];  // h - R h
    for (int k = 0; k < 3; ++k) offset[k] = h[k] - (r[3 * k] * h[0] + r[3 * k + 1] * h[1] + r[3 * k + 2] * h[2]);
    const int p = parents[i];
    if (p < 0) {
      for (int k = 0; k < 3; ++k) {
        for (int j = 0; j < 3; ++j) out[4 * k + j] = r[3 * k + j];
        out[4 * k + 3] = offset[k];
      }
      continue;
    }
    const double* a = pose + 12 * p;  // [A_p | t_p]
    for (int k = 0; k < 3; ++k) {
      for (int j = 0; j < 3; ++j)
        out[4 * k + j] = a[4 * k] * r[j] + a[4 * k + 1] * r[3 + j] + a[4 * k + 2] * r[6 + j];
      out[4 * k + 3] = (a[4 * k] * offset[0] + a[4 * k + 1] * offset[1] + a[4 * k + 2] * offset[2]) + a[4 * k + 3];
    }
  }
}

}  // namespace puppet
