// What a body is: the definition that creates it (BodyDef), the state a world reports of it
// (BodyState) and the mass properties it derived (BodyMass). Plain data; units are SI
// (m, kg, s, rad), z is up.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "phys/defs/ids.h"
#include "phys/defs/math.h"
#include "phys/defs/shape_def.h"

namespace phys {

enum class BodyType : uint8_t { Static = 0, Kinematic = 1, Dynamic = 2 };
inline const char* toString(BodyType t) {
  switch (t) {
    case BodyType::Static:
      return "static";
    case BodyType::Kinematic:
      return "kinematic";
    case BodyType::Dynamic:
      return "dynamic";
  }
  return "?";
}

/// Everything needed to create a body. Defaults: a dynamic body at the origin, at rest.
struct BodyDef {
  BodyType type = BodyType::Dynamic;
  Vec3 position;             ///< m, body frame origin in the world
  Quat rotation;             ///< unit quaternion
  Vec3 linearVelocity;       ///< m/s, of the centre of mass
  Vec3 angularVelocity;      ///< rad/s, world frame
  float linearDamping = 0;   ///< 1/s: v *= 1 / (1 + h * damping)
  float angularDamping = 0;  ///< 1/s
  float gravityScale = 1;
  /// kg. 0 means: compute mass, centre of mass and inertia from the shapes' densities.
  /// > 0 means: this mass; inertia scaled from the shapes' unless `inertia` is given.
  float mass = 0;
  Vec3 inertia;  ///< kg m^2, principal moments about the centre of mass in body axes; 0 = auto
  bool gyroscopic = true;  ///< integrate the gyroscopic torque (implicitly)
  /// May sleep when the world sleeps (WorldDef::sleep): false keeps this body, and every body
  /// in an island with it, awake (a body a client watches closely, a sensor).
  bool allowSleep = true;
  std::string name;        ///< optional, for scenes and logs
  std::vector<ShapeDef> shapes;
};

/// Read-only view of a body.
struct BodyState {
  BodyId id;
  BodyType type = BodyType::Dynamic;
  Vec3 position;  ///< body frame origin
  Quat rotation;
  Vec3 linearVelocity, angularVelocity;  ///< of the centre of mass; rad/s world frame
  Vec3 centerOfMass;                     ///< world
  float mass = 0;                        ///< kg (0 for static and kinematic bodies)
  Mat3 inertia = Mat3::zero();           ///< kg m^2, world frame, about the centre of mass
  bool sleeping = false;                 ///< asleep (SleepSettings): at rest, not stepped
  bool allowSleep = true;
};

/// The mass properties a world derived for a body (World::getBodyDef): what it simulates,
/// whether its definition gave them (BodyDef::mass, inertia) or its shapes' densities did.
struct BodyMass {
  float mass = 0;        ///< kg (0 for static and kinematic bodies)
  Vec3 localCenter;      ///< m, the centre of mass in the body frame
  Vec3 inertia;          ///< kg m^2, principal moments about the centre of mass (0: not dynamic)
  Quat inertiaRotation;  ///< the principal axes' frame in the body frame
};

}  // namespace phys
