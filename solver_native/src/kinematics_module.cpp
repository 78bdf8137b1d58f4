// nanobind module puppet._kinematics: forward kinematics of a skeleton and the constraint values
// it gives the solver (solver_native/include/forward_kinematics.h, constraint_values.h).
//
// A module of its own, apart from puppet._native (the solver): reading a rig and filling its
// values loads no solver code. Same binding rules as the solver's: fixed dtypes, C order, no
// conversion (a wrong array is a TypeError), GIL released, caller-owned outputs.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <stdexcept>
#include <string>

#include "array_types.h"
#include "constraint_values.h"
#include "forward_kinematics.h"
#include "servo_angles.h"

namespace nb = nanobind;
using namespace puppet;

namespace {

// The skeleton's axis arrays against the angle vector and the bone count (see forward_kinematics.h).
void check_axes(const char* fn, size_t dofs, const ConstRows3D& axes, const ConstIndexVec& axis_dof,
                const ConstIndexVec& bone_axes, size_t bones) {
  const size_t k = axes.shape(0);
  if (axis_dof.shape(0) != k)
    throw std::invalid_argument(std::string(fn) + ": axis_dof has " + std::to_string(axis_dof.shape(0)) +
                                " entries, axes has " + std::to_string(k) + " rows");
  if (bone_axes.shape(0) != bones + 1)
    throw std::invalid_argument(std::string(fn) + ": bone_axes has " + std::to_string(bone_axes.shape(0)) +
                                " entries, expected bones + 1 = " + std::to_string(bones + 1));
  const int32_t* o = bone_axes.data();
  bool ok = o[0] == 0 && static_cast<size_t>(o[bones]) == k;
  for (size_t i = 0; i < bones; ++i) ok = ok && o[i] <= o[i + 1];
  if (!ok)
    throw std::invalid_argument(std::string(fn) + ": bone_axes must rise from 0 to the number of axes (" +
                                std::to_string(k) + ")");
  for (size_t a = 0; a < k; ++a) {
    const int32_t d = axis_dof.data()[a];
    if (d < 0 || static_cast<size_t>(d) >= dofs)
      throw std::invalid_argument(std::string(fn) + ": axis " + std::to_string(a) + " reads angle " +
                                  std::to_string(d) + ", angles has " + std::to_string(dofs) + " entries");
  }
}

// Parents before children and one head per bone.
void check_tree(const char* fn, const ConstIndexVec& parents, const ConstRows3D& heads, size_t bones) {
  if (parents.shape(0) != bones || heads.shape(0) != bones)
    throw std::invalid_argument(std::string(fn) + ": parents has " + std::to_string(parents.shape(0)) +
                                " entries and heads " + std::to_string(heads.shape(0)) + " rows, expected " +
                                std::to_string(bones) + " bones");
  for (size_t i = 0; i < bones; ++i) {
    const int32_t p = parents.data()[i];
    if (p < -1 || p >= static_cast<int32_t>(i))
      throw std::invalid_argument(std::string(fn) + ": bone " + std::to_string(i) + " has parent " +
                                  std::to_string(p) + "; parents must come before children");
  }
}

void joint_rotations_py(ConstVecD angles, ConstRows3D axes, ConstIndexVec axis_dof, ConstIndexVec bone_axes,
                        RotationsD rot) {
  const size_t b = rot.shape(0);
  check_axes("joint_rotations", angles.shape(0), axes, axis_dof, bone_axes, b);
  joint_rotations(angles.data(), axes.data(), axis_dof.data(), bone_axes.data(), static_cast<int>(b), rot.data());
}

void pose_from_rotations_py(ConstRotationsD rot, ConstIndexVec parents, ConstRows3D heads, PosesD pose) {
  const size_t b = pose.shape(0);
  if (rot.shape(0) != b)
    throw std::invalid_argument("pose_from_rotations: rot has " + std::to_string(rot.shape(0)) +
                                " bones, pose has " + std::to_string(b));
  check_tree("pose_from_rotations", parents, heads, b);
  pose_from_rotations(rot.data(), parents.data(), heads.data(), static_cast<int>(b), pose.data());
}

void forward_kinematics_py(ConstVecD angles, ConstRows3D axes, ConstIndexVec axis_dof, ConstIndexVec bone_axes,
                           ConstIndexVec parents, ConstRows3D heads, RotationsD rot, PosesD pose) {
  const size_t b = rot.shape(0);
  if (pose.shape(0) != b)
    throw std::invalid_argument("forward_kinematics: rot has " + std::to_string(b) + " bones, pose has " +
                                std::to_string(pose.shape(0)));
  check_axes("forward_kinematics", angles.shape(0), axes, axis_dof, bone_axes, b);
  check_tree("forward_kinematics", parents, heads, b);
  joint_rotations(angles.data(), axes.data(), axis_dof.data(), bone_axes.data(), static_cast<int>(b), rot.data());
  pose_from_rotations(rot.data(), parents.data(), heads.data(), static_cast<int>(b), pose.data());
}

void constraint_values_py(ConstRotationsD rot, ConstPosesD pose, ConstIndexVec full_bones, FullValuesOut full,
                          ConstIndexVec relative_bones, Mat3Stack relative) {
  const size_t b = rot.shape(0);
  if (pose.shape(0) != b)
    throw std::invalid_argument("constraint_values: rot has " + std::to_string(b) + " bones, pose has " +
                                std::to_string(pose.shape(0)));
  auto check = [b](const char* name, const ConstIndexVec& bones, size_t out_rows) {
    if (bones.shape(0) != out_rows)
      throw std::invalid_argument(std::string("constraint_values: ") + name + "_bones has " +
                                  std::to_string(bones.shape(0)) + " entries, " + name + " has " +
                                  std::to_string(out_rows) + " rows");
    for (size_t q = 0; q < out_rows; ++q) {
      const int32_t j = bones.data()[q];
      if (j < 0 || static_cast<size_t>(j) >= b)
        throw std::invalid_argument(std::string("constraint_values: ") + name + "_bones[" + std::to_string(q) +
                                    "] = " + std::to_string(j) + " is not a bone (0.." + std::to_string(b) + ")");
    }
  };
  check("full", full_bones, full.shape(0));
  check("relative", relative_bones, relative.shape(0));
  constraint_values(rot.data(), pose.data(), full_bones.data(), static_cast<int>(full.shape(0)), full.data(),
                    relative_bones.data(), static_cast<int>(relative.shape(0)), relative.data());
}

using AnyD = nb::ndarray<const double, nb::c_contig, nb::device::cpu>;
using AnyDOut = nb::ndarray<double, nb::c_contig, nb::device::cpu>;
using TableD = nb::ndarray<const double, nb::shape<5, -1>, nb::c_contig, nb::device::cpu>;
using ZeroVec = nb::ndarray<const int64_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;

void servo_angles_py(AnyD ticks, ZeroVec zero, TableD table, AnyDOut out, bool clamp) {
  const size_t k = table.shape(1);
  if (zero.shape(0) != k)
    throw std::invalid_argument("servo_angles: zero has " + std::to_string(zero.shape(0)) + " entries, table " +
                                std::to_string(k) + " servos");
  if (ticks.ndim() < 1 || ticks.ndim() > 2 || ticks.shape(ticks.ndim() - 1) != k)
    throw std::invalid_argument("servo_angles: ticks must be (k,) or (n, k) with k = " + std::to_string(k) +
                                " servos");
  bool same = out.ndim() == ticks.ndim();
  for (size_t d = 0; same && d < ticks.ndim(); ++d) same = out.shape(d) == ticks.shape(d);
  if (!same) throw std::invalid_argument("servo_angles: out must have the shape of ticks");
  servo_angles(ticks.data(), k == 0 ? 0 : ticks.size() / k, zero.data(), table.data(), k, clamp, out.data());
}

}  // namespace

NB_MODULE(_kinematics, m) {
  m.doc() =
      "puppet's native forward kinematics: servo angles, joint rotations, bone poses, constraint values "
      "(float64 in).";

  m.def("servo_angles", &servo_angles_py, nb::arg("ticks").noconvert(), nb::arg("zero").noconvert(),
        nb::arg("table").noconvert(),
        nb::arg("out").noconvert(), nb::arg("clamp"), nb::call_guard<nb::gil_scoped_release>(),
        "Joint radians of raw ticks, written into out (see servo_angles.h).\n\n"
        "ticks: (k,) or (n, k) float64 counts. zero: (k,) int64 rest ticks. table: (5, k) float64 rows\n"
        "radians_per_tick, top, wrap (0/1), lo, hi. out: float64, the shape of ticks. clamp: clamp to [lo, hi].");
  m.def("joint_rotations", &joint_rotations_py, nb::arg("angles").noconvert(), nb::arg("axes").noconvert(),
        nb::arg("axis_dof").noconvert(), nb::arg("bone_axes").noconvert(), nb::arg("rot").noconvert(),
        nb::call_guard<nb::gil_scoped_release>(),
        "Each bone's joint rotation in model space, written into rot (see forward_kinematics.h).\n\n"
        "angles: (n,) float64 radians. axes: (k, 3) float64 unit axes in model space, grouped by bone,\n"
        "composition order within a bone. axis_dof: (k,) int32 angle index per axis. bone_axes: (b + 1,)\n"
        "int32, bone i's axes are axes[bone_axes[i]:bone_axes[i + 1]]. rot: (b, 3, 3) float64 output,\n"
        "identity for bones without axes.");
  m.def("pose_from_rotations", &pose_from_rotations_py, nb::arg("rot").noconvert(), nb::arg("parents").noconvert(),
        nb::arg("heads").noconvert(), nb::arg("pose").noconvert(), nb::call_guard<nb::gil_scoped_release>(),
        "Bone poses [A | t] from model-space joint rotations, written into pose.\n\n"
        "rot: (b, 3, 3) float64. parents: (b,) int32, -1 for roots, parents before children.\n"
        "heads: (b, 3) float64 rest pivots. pose: (b, 3, 4) float64 output, A_i = A_p R_i,\n"
        "t_i = A_p (h_i - R_i h_i) + t_p.");
  m.def("forward_kinematics", &forward_kinematics_py, nb::arg("angles").noconvert(), nb::arg("axes").noconvert(),
        nb::arg("axis_dof").noconvert(), nb::arg("bone_axes").noconvert(), nb::arg("parents").noconvert(),
        nb::arg("heads").noconvert(), nb::arg("rot").noconvert(), nb::arg("pose").noconvert(),
        nb::call_guard<nb::gil_scoped_release>(),
        "joint_rotations then pose_from_rotations in one call: rot (b, 3, 3) and pose (b, 3, 4) float64 out.");
  m.def("constraint_values", &constraint_values_py, nb::arg("rot").noconvert(), nb::arg("pose").noconvert(),
        nb::arg("full_bones").noconvert(), nb::arg("full").noconvert(), nb::arg("relative_bones").noconvert(),
        nb::arg("relative").noconvert(), nb::call_guard<nb::gil_scoped_release>(),
        "Constraint values of sensed bones from forward kinematics, written in place.\n\n"
        "rot: (b, 3, 3) float64 joint rotations; pose: (b, 3, 4) float64 bone poses.\n"
        "full_bones: (nf,) int32; full: (nf, 4, 3) float32 output, full[q] = pose[full_bones[q]].T.\n"
        "relative_bones: (nr,) int32; relative: (nr, 3, 3) float32 output, relative[q] = rot[relative_bones[q]].");
}
