#include "fit_rotations.h"

#include <Eigen/Dense>
#include <cmath>

namespace puppet {

namespace {

using Mat3 = Eigen::Matrix<float, 3, 3, Eigen::RowMajor>;

bool all_finite(const Mat3& m) { return m.array().isFinite().all(); }

}  // namespace

void fit_rotations(const float* S, float* R, std::ptrdiff_t count) {
  for (std::ptrdiff_t k = 0; k < count; ++k) {
    Eigen::Map<const Mat3> s(S + 9 * k);
    Eigen::Map<Mat3> r(R + 9 * k);
    const float scale = s.cwiseAbs().maxCoeff();
    if (!all_finite(s) || !(scale > 0.0f)) {
      r.setIdentity();
      continue;
    }
    // Normalise first so that float precision holds at any mesh unit scale.
    const Mat3 sn = s / scale;
    Eigen::JacobiSVD<Mat3> svd(sn, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Mat3 u = svd.matrixU();
    const Mat3 v = svd.matrixV();
    if ((u * v.transpose()).determinant() < 0.0f) u.col(2) = -u.col(2);
    r = u * v.transpose();
  }
}

}  // namespace puppet
