#include "phys/base/status.h"

namespace phys {

const char* toString(StatusCode c) {
  switch (c) {
    case StatusCode::Ok:
      return "OK";
    case StatusCode::InvalidArgument:
      return "INVALID_ARGUMENT";
    case StatusCode::NotFound:
      return "NOT_FOUND";
    case StatusCode::IncorrectState:
      return "INCORRECT_STATE";
    case StatusCode::ResourceExhausted:
      return "RESOURCE_EXHAUSTED";
  }
  return "?";
}

}  // namespace phys
