// QoS presets as Cyclone DDS QoS objects (qos.h): the only DDS calls of phys_protocol.
#include "phys/protocol/qos.h"

namespace phys::protocol {

QosPtr makeQos(const QosPreset& p) {
  QosPtr qos(dds_create_qos());
  dds_qset_reliability(qos.get(),
                       p.reliability == Reliability::Reliable ? DDS_RELIABILITY_RELIABLE
                                                              : DDS_RELIABILITY_BEST_EFFORT,
                       DDS_MSECS(p.maxBlockingMs));
  dds_qset_durability(qos.get(), p.durability == Durability::TransientLocal
                                     ? DDS_DURABILITY_TRANSIENT_LOCAL
                                     : DDS_DURABILITY_VOLATILE);
  dds_qset_history(qos.get(),
                   p.history == History::KeepAll ? DDS_HISTORY_KEEP_ALL : DDS_HISTORY_KEEP_LAST,
                   p.depth);
  if (p.livelinessLeaseMs > 0)
    dds_qset_liveliness(qos.get(), DDS_LIVELINESS_MANUAL_BY_TOPIC, DDS_MSECS(p.livelinessLeaseMs));
  return qos;
}

}  // namespace phys::protocol
