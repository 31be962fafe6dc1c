// The MuJoCo 2.2.2 peer: the scene written as MJCF, loaded from memory (a VFS) and stepped by
// mj_step with MuJoCo's defaults (Newton solver, 100 iterations, pyramidal cones, Euler).
//
// Every dynamic body is a free body (a <freejoint>) whose frame is its centre of mass with
// principal axes (peer_common.h), with phys's mass and principal moments as its <inertial>;
// static bodies are bodies without joints; kinematic bodies are mocap bodies moved each step by
// their velocity (MuJoCo gives mocap bodies no velocity in contacts). Joints are equality
// constraints between free bodies, which is what MuJoCo users do for loops: MuJoCo's own joints
// live in a kinematic tree (a body's DOFs relative to its parent), and its tree of ball joints
// diverges on our chains (measured: shared/TOOLCHAIN_FACTS.md, "Peer engines"). So:
//   ball      -> <connect> at B's anchor (A's anchor is where that point is at the initial pose);
//   fixed     -> <weld> at the initial relative pose;
//   hinge     -> two <connect>s on the axis, 1 m apart (no limits, no motor: those need a hinge
//                joint in the tree);
//   distance  -> a spatial tendon between two sites: rigid as a tendon <equality>, limits as
//                the tendon's range (no spring);
//   prismatic -> unsupported (a slide joint needs the tree).
// Contacts: condim 3 (sliding friction only, as phys). MuJoCo mixes friction by the max of the
// two geoms' (phys: geometric mean; the same for scenes with one friction) and has no
// restitution (contacts are soft with the default solref; a scene's restitution is ignored).
// Errors: MuJoCo's own text (a load that fails, a buffer full at the initial pose) as
// engineError; when MuJoCo finds the state unstable later it resets it to the initial pose,
// and read() then reports NaN instead (MuJoCo prints its warning).
#include <mujoco/mujoco.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <limits>
#include <map>
#include <sstream>

#include "peers/peer.h"
#include "peers/peer_common.h"

namespace phys::peers {
namespace {

constexpr int kMinContacts = 100;             // MuJoCo's default nconmax
constexpr int kCountingContactsPerGeom = 16;  // contact buffer of the counting load
constexpr int kSpareContactsPerGeom = 4;      // contacts beyond the initial ones
constexpr int kRowsPerContact = 4;            // pyramidal cone, condim 3
constexpr char kSizePlaceholder[] = "<size/>";
constexpr float kHingePointSpacing = 1;  // m between a hinge's two connect points

std::string num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}
std::string vec(Vec3 v) {
  return num(v.x) + " " + num(v.y) + " " + num(v.z);
}
/// MuJoCo's quaternion order: w x y z.
std::string quat(Quat q) {
  return num(q.w) + " " + num(q.x) + " " + num(q.y) + " " + num(q.z);
}
std::string bodyName(int i) {
  return "b" + std::to_string(i);
}

/// The rotation taking +z (a MuJoCo plane's normal) to n.
Quat rotationFromZ(Vec3 n) {
  Vec3 axis = cross({0, 0, 1}, n);
  if (length(axis) < 1e-6f) return n.z > 0 ? Quat{} : Quat{1, 0, 0, 0};
  return Quat::fromAxisAngle(axis, std::acos(std::clamp(n.z, -1.0f, 1.0f)));
}

/// A site (a point on a body, for tendons) in a body's MJCF frame.
struct Site {
  std::string name;
  Vec3 pos;
};

class MujocoPeer final : public PeerEngine {
 public:
  ~MujocoPeer() override {
    if (data_) mj_deleteData(data_);
    if (model_) mj_deleteModel(model_);
  }

  std::string name() const override { return "mujoco"; }
  std::string version() const override { return mj_versionString(); }

  Status build(const Scene& scene, const PeerBudget& budget) override;
  void step() override;
  void read(std::vector<PeerBodyState>* out) const override;

 private:
  /// The scene's MJCF, with kSizePlaceholder where the buffer sizes go.
  Status writeModel(const PeerBudget& budget, std::string* xml);
  /// Loads the model with these buffer sizes and makes its data (the initial pose's contacts
  /// computed).
  Status load(const std::string& xml, int nconmax, int njmax);

  Scene scene_;
  std::vector<PeerBodyMass> mass_;
  int substeps_ = 1;
  mjModel* model_ = nullptr;
  mjData* data_ = nullptr;
  std::vector<int> qpos_, dof_, mocap_;  ///< per scene body: free joint addresses, mocap index
  int movingGeoms_ = 0, jointRows_ = 0;
  /// MuJoCo found the state unstable (NaN, Inf or huge accelerations) and reset it to the
  /// initial pose: read() then reports non-finite states, never the silently restarted ones.
  bool diverged_ = false;
};

/// Why MuJoCo cannot run a joint as this adapter builds joints, or empty.
std::string unsupportedJoint(const JointDef& d) {
  switch (d.type) {
    case JointType::Hinge:
      if (d.enableLimit || d.enableMotor)
        return "a hinge with limits or a motor (joints are equality constraints between free "
               "bodies here; MuJoCo's limits and motors need a hinge joint in its kinematic "
               "tree)";
      return {};
    case JointType::Prismatic:
      return "a prismatic joint (MuJoCo has no sliding equality constraint; a slide joint needs "
             "its kinematic tree)";
    case JointType::Distance:
      if (d.springHertz > 0) return "a distance joint with a spring";
      return {};
    default:
      return {};
  }
}

Status MujocoPeer::writeModel(const PeerBudget& budget, std::string* xml) {
  const Scene& s = scene_;
  auto dynamic = [&](int i) { return i >= 0 && s.bodies[size_t(i)].type == BodyType::Dynamic; };
  auto inBody = [&](int i, Vec3 p) {  // a point of body i (-1: world) in its MJCF frame
    return i < 0 ? p : pointInPeerFrame(mass_[size_t(i)], p);
  };
  auto worldPoint = [&](int i, Vec3 p) {
    return i < 0 ? p : apply({s.bodies[size_t(i)].position, s.bodies[size_t(i)].rotation}, p);
  };

  std::ostringstream eq, tendons, excludes;
  std::map<int, std::vector<Site>> sites;  // by scene body, -1 = world
  jointRows_ = 0;
  for (size_t k = 0; k < s.joints.size(); ++k) {
    const SceneJoint& j = s.joints[k];
    const JointDef& d = j.def;
    std::string why = unsupportedJoint(d);
    if (!why.empty()) return unsupported("mujoco: joints[" + std::to_string(k) + "]: " + why);
    // Equality constraints on bodies that cannot move are empty rows: skip them.
    if (!dynamic(j.bodyA) && !dynamic(j.bodyB)) continue;
    if (!d.collideConnected && j.bodyA >= 0 && j.bodyB >= 0)
      excludes << "<exclude body1=\"" << bodyName(j.bodyA) << "\" body2=\"" << bodyName(j.bodyB)
               << "\"/>\n";
    // body1 is a dynamic one; body2 may be the world.
    bool bFirst = dynamic(j.bodyB);
    int b1 = bFirst ? j.bodyB : j.bodyA, b2 = bFirst ? j.bodyA : j.bodyB;
    Vec3 anchor = bFirst ? d.anchorB : d.anchorA, axis = bFirst ? d.axisB : d.axisA;
    std::string pair = "body1=\"" + bodyName(b1) + "\"" +
                       (b2 >= 0 ? " body2=\"" + bodyName(b2) + "\"" : std::string());
    switch (d.type) {
      case JointType::Ball:
        eq << "<connect " << pair << " anchor=\"" << vec(inBody(b1, anchor)) << "\"/>\n";
        jointRows_ += 3;
        break;
      case JointType::Fixed:
        eq << "<weld " << pair << "/>\n";
        jointRows_ += 6;
        break;
      case JointType::Hinge: {
        Vec3 p = inBody(b1, anchor);
        Vec3 q = inBody(b1, anchor + normalize(axis) * kHingePointSpacing);
        eq << "<connect " << pair << " anchor=\"" << vec(p) << "\"/>\n";
        eq << "<connect " << pair << " anchor=\"" << vec(q) << "\"/>\n";
        jointRows_ += 6;
        break;
      }
      case JointType::Distance: {
        std::string t = "t" + std::to_string(k);
        sites[j.bodyA].push_back({t + "a", inBody(j.bodyA, d.anchorA)});
        sites[j.bodyB].push_back({t + "b", inBody(j.bodyB, d.anchorB)});
        tendons << "<spatial name=\"" << t << "\"";
        if (d.enableLimit)
          tendons << " limited=\"true\" range=\"" << num(d.lower) << " " << num(d.upper) << "\"";
        tendons << "><site site=\"" << t << "a\"/><site site=\"" << t << "b\"/></spatial>\n";
        jointRows_ += 2;
        if (!d.enableLimit) {
          // A tendon equality holds length - (length at the initial pose) = polycoef[0].
          float initial = length(worldPoint(j.bodyB, d.anchorB) - worldPoint(j.bodyA, d.anchorA));
          float offset = d.length >= 0 ? d.length - initial : 0;
          eq << "<tendon tendon1=\"" << t << "\" polycoef=\"" << num(offset) << " 0 0 0 0\"/>\n";
          jointRows_ += 1;
        }
        break;
      }
      case JointType::Prismatic:
        break;  // rejected above
    }
  }

  std::ostringstream assets, world;
  movingGeoms_ = 0;
  auto writeSites = [&](int i) {
    for (const Site& site : sites[i])
      world << "<site name=\"" << site.name << "\" pos=\"" << vec(site.pos) << "\"/>\n";
  };
  writeSites(-1);
  for (size_t i = 0; i < s.bodies.size(); ++i) {
    const BodyDef& b = s.bodies[i];
    const PeerBodyMass& m = mass_[i];
    Transform pose = toPeerPose(m, b.position, b.rotation);
    world << "<body name=\"" << bodyName(int(i)) << "\" pos=\"" << vec(pose.p) << "\" quat=\""
          << quat(pose.q) << "\"" << (b.type == BodyType::Kinematic ? " mocap=\"true\"" : "")
          << ">\n";
    if (b.type == BodyType::Dynamic) {
      Vec3 I = m.principalInertia;
      world << "<freejoint/>\n<inertial pos=\"0 0 0\" mass=\"" << num(m.mass) << "\" diaginertia=\""
            << vec(I) << "\"/>\n";
    }
    for (size_t k = 0; k < b.shapes.size(); ++k) {
      const ShapeDef& shape = b.shapes[k];
      const ShapeGeom& g = shape.geom;
      Transform local = shapeInPeerFrame(m, shape.local);
      std::ostringstream type;
      switch (g.type) {
        case ShapeType::Sphere:
          type << "type=\"sphere\" size=\"" << num(g.radius) << "\"";
          break;
        case ShapeType::Box:
          type << "type=\"box\" size=\"" << vec(g.halfExtents) << "\"";
          break;
        case ShapeType::Capsule:  // both along the local z axis
          type << "type=\"capsule\" size=\"" << num(g.radius) << " " << num(g.halfHeight) << "\"";
          break;
        case ShapeType::Plane:  // MuJoCo's plane is z = 0 in its frame, infinite ("0 0 1")
          local = local * Transform{g.normal * g.offset, rotationFromZ(g.normal)};
          type << "type=\"plane\" size=\"0 0 1\"";
          break;
        case ShapeType::Hull: {
          // MuJoCo takes the vertices and builds the hull itself (qhull).
          std::string mesh = "m" + std::to_string(i) + "_" + std::to_string(k);
          assets << "<mesh name=\"" << mesh << "\" vertex=\"";
          for (Vec3 v : g.hull->vertices) assets << vec(v) << " ";
          assets << "\"/>\n";
          type << "type=\"mesh\" mesh=\"" << mesh << "\"";
          break;
        }
      }
      world << "<geom " << type.str() << " pos=\"" << vec(local.p) << "\" quat=\"" << quat(local.q)
            << "\" friction=\"" << num(shape.material.friction) << " 0.005 0.0001\"/>\n";
      if (b.type != BodyType::Static) ++movingGeoms_;
    }
    writeSites(int(i));
    world << "</body>\n";
  }

  std::ostringstream x;
  x << "<mujoco model=\"" << (s.name.empty() ? "scene" : s.name) << "\">\n"
    << "<compiler angle=\"radian\" inertiafromgeom=\"false\" balanceinertia=\"true\"/>\n"
    << kSizePlaceholder << "\n"
    << "<option timestep=\"" << num(double(s.world.timeStep) / substeps_) << "\" gravity=\""
    << vec(s.world.gravity) << "\"";
  if (budget.iterations > 0) x << " iterations=\"" << budget.iterations << "\"";
  x << "/>\n<default><geom condim=\"3\"/></default>\n"
    << "<asset>\n"
    << assets.str() << "</asset>\n"
    << "<worldbody>\n"
    << world.str() << "</worldbody>\n"
    << "<contact>\n"
    << excludes.str() << "</contact>\n"
    << "<tendon>\n"
    << tendons.str() << "</tendon>\n"
    << "<equality>\n"
    << eq.str() << "</equality>\n"
    << "</mujoco>\n";
  *xml = x.str();
  return Status::Ok();
}

Status MujocoPeer::load(const std::string& xml, int nconmax, int njmax) {
  if (data_) mj_deleteData(data_), data_ = nullptr;
  if (model_) mj_deleteModel(model_), model_ = nullptr;
  std::string sized = xml;
  sized.replace(sized.find(kSizePlaceholder), std::strlen(kSizePlaceholder),
                "<size nconmax=\"" + std::to_string(nconmax) + "\" njmax=\"" +
                    std::to_string(njmax) + "\"/>");
  static const char kFile[] = "scene.xml";
  auto vfs = std::make_unique<mjVFS>();  // about 2 MB of file name slots
  mj_defaultVFS(vfs.get());
  if (mj_makeEmptyFileVFS(vfs.get(), kFile, int(sized.size())) != 0)
    return engineError("mujoco: cannot add the model to a VFS");
  std::memcpy(vfs->filedata[mj_findFileVFS(vfs.get(), kFile)], sized.data(), sized.size());
  char error[1024] = "";
  model_ = mj_loadXML(kFile, vfs.get(), error, sizeof error);
  mj_deleteVFS(vfs.get());
  if (!model_)
    return engineError("mujoco: mj_loadXML (nconmax " + std::to_string(nconmax) + ", njmax " +
                       std::to_string(njmax) + "): " + error);
  data_ = mj_makeData(model_);
  if (!data_) return engineError("mujoco: mj_makeData failed");
  mj_forward(model_, data_);
  return Status::Ok();
}

Status MujocoPeer::build(const Scene& scene, const PeerBudget& budget) {
  if (model_) return engineError("mujoco: build() called twice");
  Status st = computePeerBodies(scene, &mass_);
  if (!st.ok()) return st;
  scene_ = scene;
  substeps_ = std::max(1, budget.substeps);
  std::string xml;
  st = writeModel(budget, &xml);
  if (!st.ok()) return st;
  // Buffers: MuJoCo 2.2.2 preallocates nconmax contacts and njmax constraint rows, and its
  // arena (about 6 njmax^2 numbers) cannot be allocated past roughly 12,000 rows (a size in an
  // int), so they cannot just be generous. A first load with a small row buffer counts the
  // contacts at the initial pose; the model is then loaded with room for those plus
  // kSpareContactsPerGeom per moving geom (or, where MuJoCo cannot allocate that, for the
  // initial ones only), 4 rows per contact plus the joints' rows. Larger scenes fail with
  // MuJoCo's own message ("could not create mjData").
  // The counting load overflows its row buffer on purpose: keep MuJoCo's (global) warning
  // handler from printing that.
  void (*warn)(const char*) = mju_user_warning;
  mju_user_warning = [](const char*) {};
  st = load(xml, std::max(kMinContacts, kCountingContactsPerGeom * movingGeoms_), kMinContacts);
  mju_user_warning = warn;
  if (!st.ok()) return st;
  const int initialContacts = data_->ncon;
  for (int spare : {kSpareContactsPerGeom * movingGeoms_, 0}) {
    const int ncon = std::max(kMinContacts, initialContacts + spare);
    st = load(xml, ncon, kRowsPerContact * ncon + jointRows_);
    if (st.ok()) break;
  }
  if (!st.ok()) return st;
  for (int w : {mjWARN_CONTACTFULL, mjWARN_CNSTRFULL, mjWARN_BADQACC}) {
    const mjWarningStat& stat = data_->warning[w];
    if (stat.number > 0)
      return engineError("mujoco: at the initial pose: " +
                         std::string(mju_warningText(w, stat.lastinfo)));
  }

  qpos_.assign(scene.bodies.size(), -1);
  dof_.assign(scene.bodies.size(), -1);
  mocap_.assign(scene.bodies.size(), -1);
  for (size_t i = 0; i < scene.bodies.size(); ++i) {
    const BodyDef& b = scene.bodies[i];
    int id = mj_name2id(model_, mjOBJ_BODY, bodyName(int(i)).c_str());
    if (b.type == BodyType::Kinematic) mocap_[i] = model_->body_mocapid[id];
    if (b.type != BodyType::Dynamic) continue;
    int joint = model_->body_jntadr[id];
    qpos_[i] = model_->jnt_qposadr[joint];
    dof_[i] = model_->jnt_dofadr[joint];
    // A free joint's velocity: the origin's (here the centre of mass's) linear velocity in the
    // world frame, then the angular velocity in the body frame.
    Quat q = toPeerPose(mass_[i], b.position, b.rotation).q;
    Vec3 w = invRotate(q, b.angularVelocity);
    mjtNum* v = data_->qvel + dof_[i];
    v[0] = b.linearVelocity.x, v[1] = b.linearVelocity.y, v[2] = b.linearVelocity.z;
    v[3] = w.x, v[4] = w.y, v[5] = w.z;
  }
  mj_forward(model_, data_);
  return Status::Ok();
}

void MujocoPeer::step() {
  const double h = model_->opt.timestep;
  const Vec3 g = scene_.world.gravity;
  for (int s = 0; s < substeps_; ++s) {
    for (size_t i = 0; i < scene_.bodies.size(); ++i) {
      const BodyDef& b = scene_.bodies[i];
      if (mocap_[i] >= 0) {  // kinematic: advance the pose by the body's velocity
        mjtNum* p = data_->mocap_pos + 3 * mocap_[i];
        mjtNum* q = data_->mocap_quat + 4 * mocap_[i];
        for (int k = 0; k < 3; ++k) p[k] += h * b.linearVelocity[k];
        Quat r = integrateRotation(Quat{float(q[1]), float(q[2]), float(q[3]), float(q[0])},
                                   b.angularVelocity, float(h));
        q[0] = r.w, q[1] = r.x, q[2] = r.y, q[3] = r.z;
      }
      if (dof_[i] < 0 || (b.gravityScale == 1 && b.linearDamping == 0 && b.angularDamping == 0))
        continue;
      // Gravity scales other than 1 and phys's damping (v *= 1 / (1 + h d)) as forces at the
      // centre of mass (xfrc_applied: world frame, force then torque).
      const mjtNum* qp = data_->qpos + qpos_[i] + 3;
      const mjtNum* v = data_->qvel + dof_[i];
      Quat q = normalize(Quat{float(qp[1]), float(qp[2]), float(qp[3]), float(qp[0])});
      double m = mass_[i].mass;
      double cl = b.linearDamping / (1 + h * b.linearDamping);
      double ca = b.angularDamping / (1 + h * b.angularDamping);
      Vec3 wLocal{float(v[3]), float(v[4]), float(v[5])};
      Vec3 torque = rotate(q, mulComponents(mass_[i].principalInertia, wLocal)) * float(-ca);
      mjtNum* f = data_->xfrc_applied + 6 * model_->jnt_bodyid[model_->dof_jntid[dof_[i]]];
      for (int k = 0; k < 3; ++k) {
        f[k] = m * (g[k] * (b.gravityScale - 1) - cl * v[k]);
        f[3 + k] = torque[k];
      }
    }
    mj_step(model_, data_);
  }
  if (data_->warning[mjWARN_BADQACC].number > 0) diverged_ = true;
}

void MujocoPeer::read(std::vector<PeerBodyState>* out) const {
  out->resize(scene_.bodies.size());
  for (size_t i = 0; i < scene_.bodies.size(); ++i) {
    const BodyDef& b = scene_.bodies[i];
    if (diverged_ && qpos_[i] >= 0) {
      const float nan = std::numeric_limits<float>::quiet_NaN();
      (*out)[i] = {{nan, nan, nan}, {nan, nan, nan, nan}, {nan, nan, nan}, {nan, nan, nan}};
      continue;
    }
    if (mocap_[i] >= 0) {
      const mjtNum* p = data_->mocap_pos + 3 * mocap_[i];
      const mjtNum* q = data_->mocap_quat + 4 * mocap_[i];
      (*out)[i] = {Vec3{float(p[0]), float(p[1]), float(p[2])},
                   normalize(Quat{float(q[1]), float(q[2]), float(q[3]), float(q[0])}),
                   b.linearVelocity, b.angularVelocity};
      continue;
    }
    if (qpos_[i] < 0) {
      (*out)[i] = {b.position, b.rotation, {}, {}};
      continue;
    }
    // The free joint: position and rotation of the principal frame, the centre of mass's
    // velocity (world) and the angular velocity in the body frame.
    const mjtNum* p = data_->qpos + qpos_[i];
    const mjtNum* v = data_->qvel + dof_[i];
    Quat q = normalize(Quat{float(p[4]), float(p[5]), float(p[6]), float(p[3])});
    Vec3 w = rotate(q, Vec3{float(v[3]), float(v[4]), float(v[5])});
    (*out)[i] = peerStateToPhys(mass_[i], Vec3{float(p[0]), float(p[1]), float(p[2])}, q,
                                Vec3{float(v[0]), float(v[1]), float(v[2])}, w);
  }
}

}  // namespace

std::unique_ptr<PeerEngine> makeMujocoPeer() {
  return std::make_unique<MujocoPeer>();
}

}  // namespace phys::peers
