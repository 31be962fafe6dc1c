// QoS presets (topics.h) as Cyclone DDS QoS objects. The only DDS calls of phys_protocol.
#pragma once

#include <dds/dds.h>

#include <memory>

#include "phys/protocol/topics.h"

namespace phys::protocol {

struct QosDeleter {
  void operator()(dds_qos_t* q) const { dds_delete_qos(q); }
};
using QosPtr = std::unique_ptr<dds_qos_t, QosDeleter>;

/// A new QoS object with the preset's reliability, durability and history; pass .get() to
/// dds_create_writer / dds_create_reader.
QosPtr makeQos(const QosPreset& preset);

}  // namespace phys::protocol
