// physview's binary WebSocket messages (docs/VIEWER.md "Messages"): every field is a
// little-endian 32-bit word (u32 or f32; the tick is two u32 words, the sim time one f64 in
// two words), so that the page reads them through typed-array views without copying.
//
//   frame  (kind 1): 48-byte header, then per body 9 words: id index, id generation,
//                    position x y z, rotation x y z w (the SDK's frame, index order)
//   shapes (kind 2): 24-byte header, hulls (vertices and triangles), then per body its
//                    motion type and shapes (kind, local pose, dimensions), 12 words a shape
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "phys/client/client.h"

namespace physview {

inline constexpr uint32_t kFrameMessage = 1;
inline constexpr uint32_t kShapesMessage = 2;
inline constexpr uint32_t kFrameHeaderBytes = 48;
inline constexpr uint32_t kFrameBodyWords = 9;
inline constexpr uint32_t kShapesHeaderBytes = 24;
inline constexpr uint32_t kShapeWords = 12;

/// Frame header flags.
inline constexpr uint32_t kFrameRunning = 1u << 0;
/// Shapes header flags: the message replaces every description the page holds (a world was
/// selected, its content replaced).
inline constexpr uint32_t kShapesReset = 1u << 0;

/// What the frame header carries besides the frame itself (from phys/status, about once a
/// second: the newest the bridge has).
struct FrameExtras {
  float tickMs = 0;
  uint32_t awake = 0;
  uint32_t contacts = 0;
  bool running = false;
};

/// One frame message into *out (resized; its capacity is reused from call to call).
void encodeFrame(const phys::client::StateFrame& frame, const FrameExtras& extras,
                 std::vector<uint8_t>* out);

/// A body as the page draws it: motion type and shapes, each in the body frame.
struct ShapeDesc {
  phys::ShapeType type = phys::ShapeType::Sphere;
  phys::Transform local;
  float dims[4] = {0, 0, 0, 0};  ///< sphere r; box hx hy hz; capsule r hh; plane nx ny nz d
  std::shared_ptr<const phys::ConvexHull> hull;  ///< hull shapes
};
struct BodyDesc {
  uint64_t id = 0;
  phys::BodyType type = phys::BodyType::Dynamic;
  std::vector<ShapeDesc> shapes;
};

/// Every body of a world with its shapes, from the world's snapshot (SaveSnapshot returning
/// bytes, which every client may ask for): state frames carry no shapes. The engine state is
/// restored into a local phys::World and read back; a portable snapshot is read as it is.
/// False with *error on failure (the request's error, a snapshot that does not decode).
bool describeWorld(phys::client::WorldHandle world, std::chrono::milliseconds timeout,
                   std::vector<BodyDesc>* out, std::string* error);

/// One shapes message for `bodies` (hulls shared by pointer are sent once).
void encodeShapes(uint32_t world, uint32_t flags, const std::vector<const BodyDesc*>& bodies,
                  std::vector<uint8_t>* out);

}  // namespace physview
