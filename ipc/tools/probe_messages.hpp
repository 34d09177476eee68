#pragma once
// Deterministic test messages shared by the probe and latency programs: message k is a
// pure function of k, so a subscriber in another process can check every field bit for bit.
#include <cstdint>
#include <string>

#include "stillpoint/ipc/messages.hpp"

namespace stillpoint::ipc::probe {

PoseMessage testPose(std::uint64_t k);
StatusMessage testStatus(std::uint64_t k);
// Frame k's objects: k % 4 of them (none every fourth frame), the last label
// of the longest length a message carries.
ObjectsMessage testObjects(std::uint64_t k);
std::string diff(const ObjectsMessage& expected, const ObjectsMessage& got);
// Empty when equal (publish_stamp is ignored: the publisher sets it), else the first
// differing field.
std::string diff(const PoseMessage& expected, const PoseMessage& got);
std::string diff(const StatusMessage& expected, const StatusMessage& got);

}  // namespace stillpoint::ipc::probe
