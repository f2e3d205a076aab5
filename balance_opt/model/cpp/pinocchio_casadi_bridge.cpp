// The Pinocchio-CasADi bridge of balance-opt (see balance_opt/model/bridge.py).
//
// PyPI's `pin` wheels do not ship Pinocchio's Python bindings for casadi::SX, but they do ship
// its header-only CasADi scalar support. This program runs Pinocchio's own algorithms on
// casadi::SX and saves the result as a casadi::Function file that Python loads with
// casadi.Function.load (the program links the casadi wheel's own libcasadi).
//
// Usage:
//   pinocchio_casadi_bridge URDF OUT N JOINT_1 ... JOINT_N FRAME_1 ... FRAME_M
//
// URDF is a URDF file (locked joints already fixed), OUT the file to save the function to,
// JOINT_i the arm joints in arm order and FRAME_k the end-effector frames. The model gets a
// free-flyer root at the identity pose. The saved function is
//   pinocchio_primitives(q[N]) -> (A_G[6 x (6+N)], J_1[6 x (6+N)], ..., J_M[6 x (6+N)],
//                                  oMi[12 x (njoints-1)])
// with A_G the centroidal momentum matrix and J_k the frame Jacobian of FRAME_k in
// LOCAL_WORLD_ALIGNED axes; columns are the base twist (local = world at the identity) then
// the arm joints in arm order. oMi holds each joint's placement (joints 1 to njoints-1): its
// rotation by columns, then its translation. Continuous joints (Pinocchio's (cos, sin) pair)
// take the angle.
//
// Exit status: 0 on success, 1 on bad usage, 2 when the model cannot be built or a name is
// unknown (message on stderr).

#include <pinocchio/autodiff/casadi.hpp>  // before any other Pinocchio header

#include <pinocchio/algorithm/centroidal.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/multibody.hpp>
#include <pinocchio/parsers/urdf.hpp>

#include <cstdlib>
#include <exception>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

typedef casadi::SX SX;
typedef pinocchio::ModelTpl<SX> SXModel;
typedef SXModel::Data SXData;

// The (6+n) Pinocchio velocity indices of the base and the arm joints, in arm order.
std::vector<int> column_indices(const pinocchio::Model& model,
                                const std::vector<std::string>& joints) {
  std::vector<int> cols = {0, 1, 2, 3, 4, 5};
  for (const std::string& name : joints) {
    cols.push_back(model.joints[model.getJointId(name)].idx_v());
  }
  return cols;
}

// Pinocchio configuration: base at the identity, arm joints from the symbolic arm vector q.
SXModel::ConfigVectorType configuration(const pinocchio::Model& model,
                                        const std::vector<std::string>& joints, const SX& q) {
  SXModel::ConfigVectorType qp = pinocchio::neutral(model).cast<SX>();
  for (std::size_t i = 0; i < joints.size(); ++i) {
    const auto& joint = model.joints[model.getJointId(joints[i])];
    const SX qi = q(static_cast<casadi_int>(i));
    if (joint.nq() == 1) {
      qp[joint.idx_q()] = qi;
    } else if (joint.nq() == 2 && joint.nv() == 1) {  // continuous joint: (cos, sin)
      qp[joint.idx_q()] = cos(qi);
      qp[joint.idx_q() + 1] = sin(qi);
    } else {
      throw std::invalid_argument("joint '" + joints[i] + "' has " +
                                  std::to_string(joint.nv()) +
                                  " degrees of freedom; arm joints must have one");
    }
  }
  return qp;
}

// The selected columns of a 6 x nv Pinocchio matrix of SX scalars, as one SX matrix.
SX select_columns(const SXData::Matrix6x& M, const std::vector<int>& cols) {
  SX out = SX::zeros(6, static_cast<casadi_int>(cols.size()));
  for (casadi_int r = 0; r < 6; ++r) {
    for (std::size_t c = 0; c < cols.size(); ++c) {
      out(r, static_cast<casadi_int>(c)) = M(r, cols[c]);
    }
  }
  return out;
}

// Every joint's placement oMi, one column per joint (the universe left out): the rotation by
// columns, then the translation.
SX joint_placements(const SXModel& cmodel, const SXData& cdata) {
  SX out = SX::zeros(12, static_cast<casadi_int>(cmodel.njoints - 1));
  for (int j = 1; j < cmodel.njoints; ++j) {
    for (int c = 0; c < 3; ++c) {
      for (int r = 0; r < 3; ++r) {
        out(3 * c + r, j - 1) = cdata.oMi[j].rotation()(r, c);
      }
      out(9 + c, j - 1) = cdata.oMi[j].translation()(c);
    }
  }
  return out;
}

void check_names(const pinocchio::Model& model, const std::vector<std::string>& joints,
                 const std::vector<std::string>& frames) {
  for (const std::string& name : joints) {
    if (!model.existJointName(name)) {
      throw std::invalid_argument("no joint '" + name + "' in the URDF model");
    }
  }
  for (const std::string& name : frames) {
    if (!model.existFrame(name)) {
      throw std::invalid_argument("no frame '" + name + "' in the URDF model");
    }
  }
}

int run(const std::string& urdf, const std::string& out, const std::vector<std::string>& joints,
        const std::vector<std::string>& frames) {
  pinocchio::Model model;
  pinocchio::urdf::buildModel(urdf, pinocchio::JointModelFreeFlyer(), model);
  model.gravity.setZero();
  check_names(model, joints, frames);

  SXModel cmodel = model.cast<SX>();
  SXData cdata(cmodel);
  const SX q = SX::sym("q", static_cast<casadi_int>(joints.size()));
  const SXModel::ConfigVectorType qp = configuration(model, joints, q);
  const std::vector<int> cols = column_indices(model, joints);

  std::vector<SX> outputs;
  std::vector<std::string> names = {"A_G"};
  outputs.push_back(select_columns(pinocchio::computeCentroidalMap(cmodel, cdata, qp), cols));

  pinocchio::computeJointJacobians(cmodel, cdata, qp);  // also the joint placements oMi
  pinocchio::updateFramePlacements(cmodel, cdata);      // oMf, for LOCAL_WORLD_ALIGNED
  for (std::size_t k = 0; k < frames.size(); ++k) {
    SXData::Matrix6x J = SXData::Matrix6x::Zero(6, cmodel.nv);
    pinocchio::getFrameJacobian(cmodel, cdata, model.getFrameId(frames[k]),
                                pinocchio::LOCAL_WORLD_ALIGNED, J);
    outputs.push_back(select_columns(J, cols));
    names.push_back("J_" + std::to_string(k));
  }
  outputs.push_back(joint_placements(cmodel, cdata));
  names.push_back("oMi");
  casadi::Function f("pinocchio_primitives", {q}, outputs, {"q"}, names);
  f.save(out);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 4) {
    std::cerr << "usage: " << argv[0] << " URDF OUT N JOINT_1 ... JOINT_N FRAME_1 ... FRAME_M\n";
    return 1;
  }
  const long n = std::strtol(argv[3], nullptr, 10);
  if (n < 0 || 4 + n > argc) {
    std::cerr << "bad joint count '" << argv[3] << "'\n";
    return 1;
  }
  const std::vector<std::string> joints(argv + 4, argv + 4 + n);
  const std::vector<std::string> frames(argv + 4 + n, argv + argc);
  try {
    return run(argv[1], argv[2], joints, frames);
  } catch (const std::exception& exc) {
    std::cerr << exc.what() << "\n";
    return 2;
  }
}
