// The names of the public enums (body type, joint type, backend), apart from the step so
// that a program which only reads or writes them does not pull the engine in with them: what
// parses commands (phys_protocol) needs them, and the client SDK's Python module
// (client_sdk/python) links PIC copies of only the engine files it needs.
#include <string>

#include "phys/dynamics/joint_def.h"
#include "phys/world/world.h"

namespace phys {

const char* toString(BodyType t) {
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

const char* toString(JointType t) {
  switch (t) {
    case JointType::Ball:
      return "ball";
    case JointType::Hinge:
      return "hinge";
    case JointType::Fixed:
      return "fixed";
    case JointType::Distance:
      return "distance";
    case JointType::Prismatic:
      return "prismatic";
  }
  return "?";
}

const char* toString(Backend b) {
  switch (b) {
    case Backend::Cpu:
      return "cpu";
    case Backend::Gpu:
      return "gpu";
    case Backend::Auto:
      return "auto";
  }
  return "?";
}

bool parseBackend(const std::string& text, Backend* out) {
  for (Backend b : {Backend::Cpu, Backend::Gpu, Backend::Auto}) {
    if (text == toString(b)) {
      *out = b;
      return true;
    }
  }
  return false;
}

}  // namespace phys
