// Hand-written ROS 1 message and service types of the ROS adapter (no genmsg / catkin at
// build time). Each is the one field `uint8[] data`, on the wire a uint32 length and the
// bytes, exactly what genmsg would generate for
//   pnp_bench/Bytes.msg      uint8[] data
//   pnp_bench/ByteCall.srv   uint8[] data --- uint8[] data
// MD5 sums as genmsg computes them: md5("uint8[] data") for the message and
// md5("uint8[] data" "uint8[] data") for the service (request text + response text).
// The deserializer bounds the length by the bytes actually received and by kMaxPayload
// (roscpp itself accepts a frame of up to 1 GB).
#pragma once

#include <ros/message_traits.h>
#include <ros/serialization.h>
#include <ros/service_traits.h>

#include <boost/shared_ptr.hpp>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

namespace pnp::bench::ros {

constexpr std::uint32_t kMaxPayload = 64u << 20;  // the driver's largest payload size

// One `uint8[] data` message; Tag only makes the topic message, the service request and the
// service response distinct C++ types (each has its own traits).
template <class Tag>
struct ByteMessage {
    std::vector<std::uint8_t> data;
    using Ptr = boost::shared_ptr<ByteMessage>;
    using ConstPtr = boost::shared_ptr<const ByteMessage>;
};

struct TopicTag {};
struct RequestTag {};
struct ResponseTag {};
using Bytes = ByteMessage<TopicTag>;
using ByteCallRequest = ByteMessage<RequestTag>;
using ByteCallResponse = ByteMessage<ResponseTag>;

struct ByteCall {
    using Request = ByteCallRequest;
    using Response = ByteCallResponse;
    Request request;
    Response response;
};

template <class Tag>
struct ByteMessageNames;
template <>
struct ByteMessageNames<TopicTag> {
    static constexpr const char* md5 = "f43a8e1b362b75baa741461b46adc7e0";
    static constexpr const char* type = "pnp_bench/Bytes";
};
template <>
struct ByteMessageNames<RequestTag> {
    static constexpr const char* md5 = "f43a8e1b362b75baa741461b46adc7e0";
    static constexpr const char* type = "pnp_bench/ByteCallRequest";
};
template <>
struct ByteMessageNames<ResponseTag> {
    static constexpr const char* md5 = "f43a8e1b362b75baa741461b46adc7e0";
    static constexpr const char* type = "pnp_bench/ByteCallResponse";
};
constexpr const char* kByteCallMd5 = "07ca5999d9d671038b26b777e731c7f0";
constexpr const char* kByteCallType = "pnp_bench/ByteCall";

}  // namespace pnp::bench::ros

namespace ros {
namespace message_traits {

template <class Tag>
struct IsMessage<pnp::bench::ros::ByteMessage<Tag>> : TrueType {};
template <class Tag>
struct IsMessage<const pnp::bench::ros::ByteMessage<Tag>> : TrueType {};
template <class Tag>
struct IsFixedSize<pnp::bench::ros::ByteMessage<Tag>> : FalseType {};
template <class Tag>
struct HasHeader<pnp::bench::ros::ByteMessage<Tag>> : FalseType {};

template <class Tag>
struct MD5Sum<pnp::bench::ros::ByteMessage<Tag>> {
    static const char* value() { return pnp::bench::ros::ByteMessageNames<Tag>::md5; }
    static const char* value(const pnp::bench::ros::ByteMessage<Tag>&) { return value(); }
};
template <class Tag>
struct DataType<pnp::bench::ros::ByteMessage<Tag>> {
    static const char* value() { return pnp::bench::ros::ByteMessageNames<Tag>::type; }
    static const char* value(const pnp::bench::ros::ByteMessage<Tag>&) { return value(); }
};
template <class Tag>
struct Definition<pnp::bench::ros::ByteMessage<Tag>> {
    static const char* value() { return "uint8[] data\n"; }
    static const char* value(const pnp::bench::ros::ByteMessage<Tag>&) { return value(); }
};

}  // namespace message_traits

namespace service_traits {

template <>
struct MD5Sum<pnp::bench::ros::ByteCall> {
    static const char* value() { return pnp::bench::ros::kByteCallMd5; }
    static const char* value(const pnp::bench::ros::ByteCall&) { return value(); }
};
template <>
struct DataType<pnp::bench::ros::ByteCall> {
    static const char* value() { return pnp::bench::ros::kByteCallType; }
    static const char* value(const pnp::bench::ros::ByteCall&) { return value(); }
};
// A request or response names its service (roscpp reads these to build the connection header).
template <>
struct MD5Sum<pnp::bench::ros::ByteCallRequest> : MD5Sum<pnp::bench::ros::ByteCall> {
    using MD5Sum<pnp::bench::ros::ByteCall>::value;
    static const char* value(const pnp::bench::ros::ByteCallRequest&) { return value(); }
};
template <>
struct DataType<pnp::bench::ros::ByteCallRequest> : DataType<pnp::bench::ros::ByteCall> {
    using DataType<pnp::bench::ros::ByteCall>::value;
    static const char* value(const pnp::bench::ros::ByteCallRequest&) { return value(); }
};
template <>
struct MD5Sum<pnp::bench::ros::ByteCallResponse> : MD5Sum<pnp::bench::ros::ByteCall> {
    using MD5Sum<pnp::bench::ros::ByteCall>::value;
    static const char* value(const pnp::bench::ros::ByteCallResponse&) { return value(); }
};
template <>
struct DataType<pnp::bench::ros::ByteCallResponse> : DataType<pnp::bench::ros::ByteCall> {
    using DataType<pnp::bench::ros::ByteCall>::value;
    static const char* value(const pnp::bench::ros::ByteCallResponse&) { return value(); }
};

}  // namespace service_traits

namespace serialization {

template <class Tag>
struct Serializer<pnp::bench::ros::ByteMessage<Tag>> {
    using Message = pnp::bench::ros::ByteMessage<Tag>;

    template <typename Stream>
    static void write(Stream& stream, const Message& m) {
        const auto n = static_cast<std::uint32_t>(m.data.size());
        stream.next(n);
        if (n > 0) std::memcpy(stream.advance(n), m.data.data(), n);
    }

    template <typename Stream>
    static void read(Stream& stream, Message& m) {
        std::uint32_t n = 0;
        stream.next(n);
        // Bounded before allocating: a length larger than what arrived is not our peer.
        if (n > stream.getLength() || n > pnp::bench::ros::kMaxPayload)
            throw StreamOverrunException("uint8[] length " + std::to_string(n) +
                                         " exceeds the received message");
        m.data.resize(n);
        if (n > 0) std::memcpy(m.data.data(), stream.advance(n), n);
    }

    static std::uint32_t serializedLength(const Message& m) {
        return 4 + static_cast<std::uint32_t>(m.data.size());
    }
};

}  // namespace serialization
}  // namespace ros
