// Scene-specific metrics. A scene opts in by naming body groups in "metrics.groups":
//   ramp, ramp_box        friction_ramp.static_displacement_max (m), friction_ramp.accel_error_max
//   bounce_ball           restitution.rebound_height (m), restitution.rebound_ratio
//   tunnel_wall, tunnel_projectile   tunnelling.passed_through (count)
//   flight_projectile     free_flight.trajectory_error (m, against p0 + v0 t + g t^2 / 2)
//   flight_spinner        free_flight.angular_momentum_drift (relative)
//   windmill_rotor        windmill.speed_error (relative, while the rotor touches nothing)
//   bridge_car            bridge.cars_arrived (count of chassis past metrics.params.finish_x)
//   cradle_ball           cradle.last_speed_ratio, cradle.others_speed_ratio_max (a row of
//                         balls in order, the striker first: their fastest speeds over the
//                         0.1 s from the first impact, when the striker has lost a fifth of
//                         its speed, relative to the striker's fastest speed before it)
#include "scene_metrics.h"

#include <algorithm>
#include <cmath>
#include <optional>

namespace phys {

namespace {

struct DVec {
  double x = 0, y = 0, z = 0;
};
DVec d(Vec3 v) {
  return {v.x, v.y, v.z};
}
double norm(DVec v) {
  return std::sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
}
DVec sub(DVec a, DVec b) {
  return {a.x - b.x, a.y - b.y, a.z - b.z};
}

BodyState state(const World& w, BodyId id) {
  BodyState s;
  w.getBody(id, &s);
  return s;
}

/// Friction of a body's first shape (the scenes give each ramp box one shape).
float bodyFriction(const World& w, BodyId id) {
  std::vector<ShapeId> shapes = w.bodyShapes(id);
  ShapeDef def;
  if (shapes.empty() || !w.getShape(shapes[0], &def, nullptr).ok()) return 0;
  return def.material.friction;
}

class RampHook : public SceneMetricHook {
 public:
  RampHook(const World& w, BodyId ramp, std::vector<BodyId> boxes) : boxes_(std::move(boxes)) {
    BodyState r = state(w, ramp);
    Vec3 up = rotate(r.rotation, {0, 0, 1});
    double g = length(w.def().gravity);
    theta_ = std::acos(std::clamp(double(up.z), -1.0, 1.0));
    for (BodyId b : boxes_) {
      // Same mixing rule as the solver: the geometric mean of the two frictions.
      double mu = std::sqrt(double(bodyFriction(w, b)) * bodyFriction(w, ramp));
      double a = g * (std::sin(theta_) - mu * std::cos(theta_));
      expected_.push_back(a > 0 ? a : 0);
      start_.push_back(d(state(w, b).position));
      maxDisp_.push_back(0);
    }
  }
  void afterStep(const World& w) override {
    double t = w.time();
    for (size_t i = 0; i < boxes_.size(); ++i) {
      BodyState s = state(w, boxes_[i]);
      maxDisp_[i] = std::max(maxDisp_[i], norm(sub(d(s.position), start_[i])));
      double v = norm(d(s.linearVelocity));
      // Acceleration from the speed change after the first half second (contact settling).
      if (t >= 0.5 && speedAtHalf_.size() <= i) speedAtHalf_.push_back(v), tHalf_ = t;
      if (speedAtEnd_.size() <= i) speedAtEnd_.resize(boxes_.size());
      speedAtEnd_[i] = v;
    }
    tEnd_ = t;
  }
  void summarize(std::map<std::string, double>* out) const override {
    double staticMax = 0, accelErr = 0;
    bool anyStatic = false, anySliding = false;
    for (size_t i = 0; i < boxes_.size(); ++i) {
      if (expected_[i] == 0) {
        anyStatic = true;
        staticMax = std::max(staticMax, maxDisp_[i]);
      } else if (speedAtHalf_.size() > i && tEnd_ > tHalf_) {
        anySliding = true;
        double a = (speedAtEnd_[i] - speedAtHalf_[i]) / (tEnd_ - tHalf_);
        accelErr = std::max(accelErr, std::fabs(a - expected_[i]) / expected_[i]);
      }
    }
    if (anyStatic) (*out)["friction_ramp.static_displacement_max"] = staticMax;
    if (anySliding) (*out)["friction_ramp.accel_error_max"] = accelErr;
  }

 private:
  std::vector<BodyId> boxes_;
  std::vector<double> expected_, maxDisp_, speedAtHalf_, speedAtEnd_;
  std::vector<DVec> start_;
  double theta_ = 0, tHalf_ = 0, tEnd_ = 0;
};

class BounceHook : public SceneMetricHook {
 public:
  BounceHook(const World& w, BodyId ball) : ball_(ball) {
    z0_ = zMin_ = state(w, ball).centerOfMass.z;
  }
  void afterStep(const World& w) override {
    BodyState s = state(w, ball_);
    double z = s.centerOfMass.z, vz = s.linearVelocity.z;
    if (!bounced_) {
      zMin_ = std::min(zMin_, z);
      if (vz > 0 && z < z0_ - 0.01) bounced_ = true;  // first time it moves up after falling
    }
    if (bounced_ && !apexDone_) {
      zApex_ = std::max(zApex_, z);
      if (vz < 0) apexDone_ = true;  // past the first apex
    }
  }
  void summarize(std::map<std::string, double>* out) const override {
    if (!bounced_) return;
    double rebound = zApex_ - zMin_;
    (*out)["restitution.rebound_height"] = rebound;
    if (z0_ > zMin_) (*out)["restitution.rebound_ratio"] = rebound / (z0_ - zMin_);
  }

 private:
  BodyId ball_;
  double z0_ = 0, zMin_ = 0, zApex_ = -1e30;
  bool bounced_ = false, apexDone_ = false;
};

class TunnelHook : public SceneMetricHook {
 public:
  TunnelHook(const World& w, BodyId wall, std::vector<BodyId> shots) : shots_(std::move(shots)) {
    BodyState ws = state(w, wall);
    wallPos_ = d(ws.position);
    normal_ = rotate(ws.rotation, {1, 0, 0});
    for (BodyId b : shots_) side_.push_back(signedDistance(state(w, b).position) < 0 ? -1 : 1);
    passed_.assign(shots_.size(), false);
  }
  void afterStep(const World& w) override {
    for (size_t i = 0; i < shots_.size(); ++i) {
      double s = signedDistance(state(w, shots_[i]).position);
      if (!std::isfinite(s) || s * side_[i] < 0) passed_[i] = true;
    }
  }
  void summarize(std::map<std::string, double>* out) const override {
    (*out)["tunnelling.passed_through"] = double(std::count(passed_.begin(), passed_.end(), true));
  }

 private:
  /// Distance from the wall's mid-plane (its local x axis is the wall normal).
  double signedDistance(Vec3 p) const {
    DVec r = sub(d(p), wallPos_);
    return r.x * normal_.x + r.y * normal_.y + r.z * normal_.z;
  }
  std::vector<BodyId> shots_;
  std::vector<int> side_;
  std::vector<bool> passed_;
  DVec wallPos_;
  Vec3 normal_;
};

class FlightHook : public SceneMetricHook {
 public:
  FlightHook(const World& w, std::vector<BodyId> projectiles, std::vector<BodyId> spinners)
      : projectiles_(std::move(projectiles)), spinners_(std::move(spinners)) {
    g_ = d(w.def().gravity);
    for (BodyId b : projectiles_) {
      BodyState s = state(w, b);
      p0_.push_back(d(s.centerOfMass));
      v0_.push_back(d(s.linearVelocity));
    }
    for (BodyId b : spinners_) L0_.push_back(momentum(state(w, b)));
  }
  static DVec momentum(const BodyState& s) { return d(s.inertia * s.angularVelocity); }
  void afterStep(const World& w) override {
    double t = w.time();
    for (size_t i = 0; i < projectiles_.size(); ++i) {
      DVec p = d(state(w, projectiles_[i]).centerOfMass);
      DVec e{p0_[i].x + v0_[i].x * t + 0.5 * g_.x * t * t,
             p0_[i].y + v0_[i].y * t + 0.5 * g_.y * t * t,
             p0_[i].z + v0_[i].z * t + 0.5 * g_.z * t * t};
      double err = norm(sub(p, e));
      trajErr_ = std::max(trajErr_, std::isfinite(err) ? err : 1e30);
    }
    for (size_t i = 0; i < spinners_.size(); ++i) {
      DVec L = momentum(state(w, spinners_[i]));
      double drift = norm(sub(L, L0_[i])) / std::max(norm(L0_[i]), 1e-30);
      momDrift_ = std::max(momDrift_, std::isfinite(drift) ? drift : 1e30);
    }
  }
  void summarize(std::map<std::string, double>* out) const override {
    if (!projectiles_.empty()) (*out)["free_flight.trajectory_error"] = trajErr_;
    if (!spinners_.empty()) (*out)["free_flight.angular_momentum_drift"] = momDrift_;
  }

 private:
  std::vector<BodyId> projectiles_, spinners_;
  std::vector<DVec> p0_, v0_, L0_;
  DVec g_;
  double trajErr_ = 0, momDrift_ = 0;
};

class WindmillHook : public SceneMetricHook {
 public:
  WindmillHook(const World& w, BodyId rotor) : rotor_(rotor) {
    for (JointId j : w.joints()) {
      JointDef def;
      w.getJoint(j, &def, nullptr);
      if (def.enableMotor && (def.bodyA == rotor || def.bodyB == rotor)) {
        motor_ = j;
        break;
      }
    }
  }
  void afterStep(const World& w) override {
    JointDef def;
    if (!w.getJoint(motor_, &def, nullptr).ok() || w.time() < 1.0) return;
    for (const ContactInfo& c : w.contacts()) {
      if (c.bodyA == rotor_ || c.bodyB == rotor_) return;  // obstructed: not measured
    }
    // Relative angular speed about the hinge axis (A's frame), signed like the motor.
    BodyState r = state(w, rotor_);
    Vec3 wA{}, axis = def.axisA;
    if (!def.bodyA.isNull()) {
      BodyState a = state(w, def.bodyA);
      wA = a.angularVelocity;
      axis = rotate(a.rotation, def.axisA);
    }
    double speed = dot(def.bodyB == rotor_ ? r.angularVelocity - wA : wA - r.angularVelocity, axis);
    if (def.motorSpeed != 0) {
      err_ = std::max(err_, std::fabs(speed - def.motorSpeed) / std::fabs(def.motorSpeed));
      measured_ = true;
    }
  }
  void summarize(std::map<std::string, double>* out) const override {
    if (measured_) (*out)["windmill.speed_error"] = err_;
  }

 private:
  BodyId rotor_;
  JointId motor_;
  double err_ = 0;
  bool measured_ = false;
};

class BridgeHook : public SceneMetricHook {
 public:
  BridgeHook(std::vector<BodyId> cars, double finishX)
      : cars_(std::move(cars)), finishX_(finishX) {}
  void afterStep(const World& w) override {
    arrived_ = 0;
    for (BodyId c : cars_) arrived_ += state(w, c).position.x >= finishX_ ? 1 : 0;
  }
  void summarize(std::map<std::string, double>* out) const override {
    (*out)["bridge.cars_arrived"] = arrived_;
  }

 private:
  std::vector<BodyId> cars_;
  double finishX_;
  int arrived_ = 0;
};

class CradleHook : public SceneMetricHook {
 public:
  explicit CradleHook(std::vector<BodyId> balls) : balls_(std::move(balls)) {}
  void afterStep(const World& w) override {
    std::vector<double> speed;
    for (BodyId b : balls_) {
      const double v = norm(d(state(w, b).linearVelocity));
      speed.push_back(std::isfinite(v) ? v : 1e30);
    }
    if (!impactTime_) {
      // The first impact: the striker, which gathers speed until it strikes (a pendulum
      // released above the row), loses a fifth of its fastest speed so far.
      if (!(strikerMax_ > 0.1 && speed[0] < 0.8 * strikerMax_)) {
        strikerMax_ = std::max(strikerMax_, speed[0]);
        return;
      }
      impactTime_ = w.time();
    }
    if (w.time() > *impactTime_ + kWindow) return;
    lastMax_ = std::max(lastMax_, speed.back());
    for (size_t i = 0; i + 1 < speed.size(); ++i) othersMax_ = std::max(othersMax_, speed[i]);
  }
  void summarize(std::map<std::string, double>* out) const override {
    if (!impactTime_) return;
    (*out)["cradle.last_speed_ratio"] = lastMax_ / strikerMax_;
    (*out)["cradle.others_speed_ratio_max"] = othersMax_ / strikerMax_;
  }

 private:
  static constexpr double kWindow = 0.1;  ///< s after the first impact
  std::vector<BodyId> balls_;
  std::optional<double> impactTime_;
  double strikerMax_ = 0, lastMax_ = 0, othersMax_ = 0;
};

class Combined : public SceneMetricHook {
 public:
  std::vector<std::unique_ptr<SceneMetricHook>> hooks;
  void afterStep(const World& w) override {
    for (auto& h : hooks) h->afterStep(w);
  }
  void summarize(std::map<std::string, double>* out) const override {
    for (const auto& h : hooks) h->summarize(out);
  }
};

}  // namespace

std::unique_ptr<SceneMetricHook> makeSceneMetricHook(const Scene& scene, const World& world,
                                                     const std::vector<BodyId>& ids) {
  auto group = [&](const char* name) {
    std::vector<BodyId> out;
    auto it = scene.metrics.groups.find(name);
    if (it == scene.metrics.groups.end()) return out;
    for (int i : it->second)
      if (i >= 0 && size_t(i) < ids.size()) out.push_back(ids[size_t(i)]);
    return out;
  };
  auto all = std::make_unique<Combined>();
  std::vector<BodyId> ramp = group("ramp"), rampBoxes = group("ramp_box");
  if (!ramp.empty() && !rampBoxes.empty())
    all->hooks.push_back(std::make_unique<RampHook>(world, ramp[0], rampBoxes));
  for (BodyId b : group("bounce_ball"))
    all->hooks.push_back(std::make_unique<BounceHook>(world, b));
  std::vector<BodyId> wall = group("tunnel_wall"), shots = group("tunnel_projectile");
  if (!wall.empty() && !shots.empty())
    all->hooks.push_back(std::make_unique<TunnelHook>(world, wall[0], shots));
  std::vector<BodyId> proj = group("flight_projectile"), spin = group("flight_spinner");
  if (!proj.empty() || !spin.empty())
    all->hooks.push_back(std::make_unique<FlightHook>(world, proj, spin));
  for (BodyId r : group("windmill_rotor"))
    all->hooks.push_back(std::make_unique<WindmillHook>(world, r));
  std::vector<BodyId> cars = group("bridge_car");
  auto finish = scene.metrics.params.find("finish_x");
  if (!cars.empty() && finish != scene.metrics.params.end())
    all->hooks.push_back(std::make_unique<BridgeHook>(cars, finish->second));
  std::vector<BodyId> cradle = group("cradle_ball");
  if (cradle.size() >= 2) all->hooks.push_back(std::make_unique<CradleHook>(cradle));
  if (all->hooks.empty()) return nullptr;
  return all;
}

}  // namespace phys
