// Shared definitions of the opc.tcp transport (OPC 10000-6 §6.7 OPC UA Secure Conversation,
// §7.1 OPC UA Connection Protocol): clock, errors, buffer limits.
#pragma once

#include <time.h>

#include <chrono>
#include <cstddef>
#include <stdexcept>
#include <string>
#include <string_view>

#include "ua/types/binary.hpp"

namespace pnp::ua::transport {

using Clock = std::chrono::steady_clock;
using TimePoint = Clock::time_point;
// An absolute point in time after which a blocking call gives up. TimePoint::max(): never.
using Deadline = Clock::time_point;
// Clock::now() at scheduler-tick resolution (CLOCK_MONOTONIC_COARSE, a few ms): ~4 ns
// instead of ~50 ns on a VM, where a precise reading per request is a visible share of a
// 15 us round trip. For bookkeeping (last receive, idle and renewal timers), not for
// measuring.
inline TimePoint coarseNow() {
    timespec ts{};
    ::clock_gettime(CLOCK_MONOTONIC_COARSE, &ts);
    return TimePoint(std::chrono::seconds(ts.tv_sec) + std::chrono::nanoseconds(ts.tv_nsec));
}
// Whether `deadline` has passed. The coarse clock lags by at most one tick (<= 10 ms for
// HZ >= 100), so the precise clock is read only for a deadline that near.
inline bool deadlinePassed(Deadline deadline) {
    constexpr auto kCoarseMargin = std::chrono::milliseconds(20);
    TimePoint coarse = coarseNow();
    if (coarse >= deadline) return true;
    return deadline - coarse < kCoarseMargin && Clock::now() >= deadline;
}

// A transport failure. status() is one of
//   BadTimeout                 a deadline passed (connect, send)
//   BadConnectionClosed        the peer closed the TCP connection / the connection is closed
//   BadTcpEndpointUrlInvalid   the endpoint URL cannot be parsed
//   BadCommunicationError      socket errors: name resolution, connect refused, reset, ...
//   BadRequestTooLarge         (ClientConnection::send) the request exceeds the server's
//                              MaxMessageSize / MaxChunkCount; nothing was sent and the
//                              connection stays usable
//   <code of an ERR message>   the server sent an Error message (BadTcpMessageTooLarge,
//                              BadSecureChannelIdInvalid, BadTcpServerTooBusy, ...)
//   <protocol violation>       the peer broke the protocol (BadTcpMessageTypeInvalid,
//                              BadSequenceNumberInvalid, BadDecodingError, ...)
// Apart from BadRequestTooLarge, a TransportError means the connection is closed.
class TransportError : public std::runtime_error {
  public:
    // what() reads "<message>: <status>".
    TransportError(StatusCode status, const std::string& message);
    StatusCode status() const noexcept { return status_; }
    // The message without the status (for wrapping into another error that adds it).
    const std::string& message() const noexcept { return message_; }

  private:
    StatusCode status_;
    std::string message_;
};

// Part 6 §7.1.2.3: buffer sizes shall be at least 8192 bytes.
inline constexpr UInt32 kMinBufferSize = 8192;
// The newest (and only) protocol version of OPC UA TCP / Secure Conversation.
inline constexpr UInt32 kProtocolVersion = 0;
inline constexpr std::string_view kSecurityPolicyNone =
    "http://opcfoundation.org/UA/SecurityPolicy#None";

// The limits one side of a connection announces in its Hello / Acknowledge and enforces on
// what it receives (whatever the peer announced).
struct TransportLimits {
    // Largest chunk we accept (>= 8192). Also sizes the per-connection receive buffer.
    UInt32 receiveBufferSize = 64 * 1024;
    // Largest chunk we send (>= 8192); the peer's receive buffer size may lower it.
    UInt32 sendBufferSize = 64 * 1024;
    // Largest message body we accept (sum of the chunk bodies). 0 means the default, 16 MiB:
    // we never receive without a limit.
    UInt32 maxMessageSize = 16 * 1024 * 1024;
    // Most chunks per message we accept. 0: derived from maxMessageSize and the negotiated
    // receive buffer size (enough chunks for a message of maxMessageSize in full chunks).
    UInt32 maxChunkCount = 0;
};

inline constexpr UInt32 kDefaultMaxMessageSize = 16 * 1024 * 1024;

// The limits that apply to one connection after the Hello / Acknowledge exchange, from the
// point of view of this side.
struct NegotiatedLimits {
    UInt32 protocolVersion = kProtocolVersion;
    UInt32 receiveBufferSize = kMinBufferSize;              // largest chunk we accept
    UInt32 sendBufferSize = kMinBufferSize;                 // largest chunk we send
    UInt32 maxReceiveMessageSize = kDefaultMaxMessageSize;  // our limit, never 0
    UInt32 maxReceiveChunkCount = 0;                        // our limit, never 0 after HEL/ACK
    UInt32 maxSendMessageSize = 0;  // the peer's limit on what we send, 0: none
    UInt32 maxSendChunkCount = 0;   // the peer's limit on what we send, 0: none
};

}  // namespace pnp::ua::transport
