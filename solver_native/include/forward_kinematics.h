// Forward kinematics of a skeleton: joint rotations from joint angles, bone poses from joint
// rotations (conventions: puppet/rig/skeleton.py). All float64, row-major, model units, radians.
//
//   b bones, parents before children (parents[i] < i, -1 for a root);
//   k joint axes in model space, grouped by bone and in composition order within a bone:
//   bone i's axes are a = bone_axes[i] .. bone_axes[i+1]-1 (none: no joint, identity).
//
//   R_i = prod_a Rod(axes[a], angles[axis_dof[a]])   (first axis outermost; Rodrigues:
//         Rod(u, x) = u u^T + cos x (I - u u^T) + sin x [u]_x)
//   A_i = A_p R_i,  t_i = A_p (h_i - R_i h_i) + t_p   (identity above roots; h = heads)
//
// Nothing is allocated; the caller owns every array.
#pragma once

#include <cstdint>

namespace puppet {

// rot: (b, 3, 3) out. angles: (dof_count,); axes: (k, 3) unit; axis_dof: (k,); bone_axes: (b + 1,).
void joint_rotations(const double* angles, const double* axes, const int32_t* axis_dof,
                     const int32_t* bone_axes, int bones, double* rot);

// pose: (b, 3, 4) out, [A_i | t_i] per bone. rot: (b, 3, 3); parents: (b,); heads: (b, 3).
void pose_from_rotations(const double* rot, const int32_t* parents, const double* heads, int bones,
                         double* pose);

}  // namespace puppet
