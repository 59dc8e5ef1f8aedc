// Sans-I/O building blocks of OPC UA Secure Conversation (OPC 10000-6 §6.7.2):
//   ChunkReader       byte stream -> complete chunks (framing, header checks)
//   parseSecureChunk  OPN / MSG / CLO chunk -> channel id, security / sequence headers, body
//   SequenceValidator / SequenceGenerator   sequence numbers (legacy wrap rule, §6.7.2.4)
//   MessageAssembler  chunks -> messages (size / count limits, abort chunks, request ids)
//   writeSymmetricChunks / makeOpenChunk    messages -> chunks (in place for MSG / CLO)
// Everything throws TransportError with the status the peer should get in an ERR message.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstring>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "ua/transport/tcp_messages.hpp"

namespace pnp::ua::transport {

// One complete chunk, header included. Valid until the next readSpace() / commit().
struct RawChunk {
    MessageHeader header;
    const Byte* data = nullptr;  // the whole chunk (starts with the 8-byte header)
    std::size_t size = 0;
};

// A linear receive buffer that frames chunks. The socket reads straight into readSpace();
// complete chunks are handed out without copying. The buffer is sized by the configured
// receive buffer: a length field is checked against the negotiated maximum chunk size as
// soon as the 8 header bytes are there, before anything else happens.
// The buffer is a ByteBlock that values decoded from it may keep references to (large
// ByteStrings, see BinaryDecoder::shareFrom): readSpace() reuses it only while nothing else
// holds it, and otherwise continues in a new block.
class ChunkReader {
  public:
    // capacity: bytes of the buffer, >= every maxChunkSize ever set.
    explicit ChunkReader(std::size_t capacity, std::size_t maxChunkSize);

    void setMaxChunkSize(std::size_t n);  // clamped to the capacity
    std::size_t maxChunkSize() const { return maxChunk_; }

    // Where the next read may write (compacts the buffer first). Never empty once every
    // complete chunk has been taken out with next().
    std::span<Byte> readSpace();
    void commit(std::size_t n);
    // The next complete chunk, nullopt when more bytes are needed. Throws
    // TransportError(BadTcpMessageTypeInvalid / BadTcpMessageTooLarge / BadDecodingError)
    // for an invalid header.
    std::optional<RawChunk> next();
    // Copies bytes in (tests, tools): appends what fits and returns how many were taken.
    std::size_t append(const Byte* p, std::size_t n);

    std::size_t buffered() const { return end_ - begin_; }
    void clear();
    // The block the chunks handed out by next() lie in.
    ByteBlock* block() const { return buf_.get(); }

  private:
    ByteBlockRef buf_;
    std::size_t capacity_;
    std::size_t maxChunk_;
    std::size_t begin_ = 0;
    std::size_t end_ = 0;
};

// The parts of an OPN / MSG / CLO chunk (SecurityPolicy None: no padding, no signature).
struct SecureChunk {
    MessageType type = MessageType::Message;
    ChunkType chunkType = ChunkType::Final;
    UInt32 channelId = 0;
    UInt32 tokenId = 0;                  // MSG, CLO (symmetric security header)
    std::string_view securityPolicyUri;  // OPN (asymmetric security header)
    std::size_t senderCertificateSize = 0;
    std::size_t receiverThumbprintSize = 0;
    UInt32 sequenceNumber = 0;
    UInt32 requestId = 0;
    const Byte* body = nullptr;
    std::size_t bodySize = 0;
};

// Throws TransportError(BadDecodingError) when the headers do not fit into the chunk, and
// BadTcpMessageTypeInvalid for a chunk that is not OPN / MSG / CLO.
SecureChunk parseSecureChunk(const RawChunk& chunk);

// Receiving side of the sequence numbers of one channel. The first number is accepted as it
// is; every later one shall be the previous + 1, or, when the previous one is greater than
// UInt32.MaxValue - 1024, a number smaller than 1024 (legacy sequence numbers, which
// SecurityPolicy None uses). Throws TransportError(BadSequenceNumberInvalid).
class SequenceValidator {
  public:
    void check(UInt32 sequenceNumber);
    void reset() { started_ = false; }

  private:
    bool started_ = false;
    UInt32 last_ = 0;
};

// Sending side: 1, 2, ... and after UInt32.MaxValue - 1024 back to 1.
class SequenceGenerator {
  public:
    explicit SequenceGenerator(UInt32 first = 1) : next_(first) {}
    UInt32 next() {
        UInt32 v = next_;
        next_ = v > kWrapAbove ? 1 : v + 1;
        return v;
    }
    UInt32 peek() const { return next_; }
    static constexpr UInt32 kWrapAbove = 0xFFFFFFFFu - 1024u;

  private:
    UInt32 next_;
};

// Reassembles messages from chunks. Chunks of different messages must not be interleaved:
// while a message is incomplete, every chunk shall carry its message type and request id.
// Bytes that all connections of a server together may hold in partially received
// (multi-chunk) messages. MaxMessageSize bounds one message; this bounds their sum, which
// would otherwise be maxConnections x MaxMessageSize (1000 x 16 MiB) for clients that
// trickle in large messages. Thread-safe.
class MemoryBudget {
  public:
    explicit MemoryBudget(std::size_t limit) : limit_(limit) {}
    // Takes n bytes if they fit; false (nothing taken) otherwise.
    bool tryTake(std::size_t n) {
        std::size_t used = used_.load(std::memory_order_relaxed);
        do {
            if (n > limit_ - std::min(used, limit_)) return false;
        } while (!used_.compare_exchange_weak(used, used + n, std::memory_order_relaxed));
        return true;
    }
    void give(std::size_t n) { used_.fetch_sub(n, std::memory_order_relaxed); }
    std::size_t used() const { return used_.load(std::memory_order_relaxed); }
    std::size_t limit() const { return limit_; }

  private:
    std::atomic<std::size_t> used_{0};
    std::size_t limit_;
};

class MessageAssembler {
  public:
    struct Limits {
        std::size_t maxMessageSize = kDefaultMaxMessageSize;  // body bytes, 0: none
        std::size_t maxChunkCount = 0;                        // 0: none
    };
    enum class Result { Incomplete, Complete, Aborted };
    struct Event {
        Result result = Result::Incomplete;
        MessageType type = MessageType::Message;
        UInt32 requestId = 0;
        // Complete: the message body. Points into the chunk (single-chunk message: no copy)
        // or into the assembly buffer; valid until the next add().
        const Byte* body = nullptr;
        std::size_t size = 0;
        bool assembled = false;  // body is in assemblyBuffer() (may be moved out)
        // Aborted: the Error and Reason of the abort chunk.
        StatusCode abortStatus;
        std::string abortReason;
    };

    MessageAssembler() = default;
    explicit MessageAssembler(Limits limits) : limits_(limits) {}
    ~MessageAssembler() { release(); }
    MessageAssembler(const MessageAssembler&) = delete;
    MessageAssembler& operator=(const MessageAssembler&) = delete;
    void setLimits(Limits limits) { limits_ = limits; }
    // Partial messages take their bytes from `budget` (shared by many assemblers, outlives
    // this one); when it is exhausted add() throws BadTcpNotEnoughResources.
    void setBudget(MemoryBudget* budget) { budget_ = budget; }
    // Drops an incomplete message and stops using the budget (which may go away next).
    void leaveBudget() {
        reset();
        budget_ = nullptr;
    }

    // Throws TransportError: BadTcpMessageTooLarge (message size / chunk count limits),
    // BadTcpMessageTypeInvalid (a chunk of another message type while one is incomplete),
    // BadDecodingError (a chunk of another request id while one is incomplete, malformed
    // abort chunk).
    Event add(const SecureChunk& chunk);

    bool inProgress() const { return chunks_ > 0; }
    // The buffer behind an assembled message; the caller may move it out.
    Buffer& assemblyBuffer() { return assembly_; }

  private:
    void reset() {
        chunks_ = 0;
        assembly_.clear();
        release();
    }
    void release() {
        if (budget_ && held_) budget_->give(held_);
        held_ = 0;
    }
    Limits limits_;
    MemoryBudget* budget_ = nullptr;
    std::size_t held_ = 0;  // bytes taken from budget_ for the incomplete message
    Buffer assembly_;
    std::size_t chunks_ = 0;  // chunks of the incomplete message
    MessageType type_ = MessageType::Message;
    UInt32 requestId_ = 0;
};

// A buffer for a message to send: kSymmetricHeaderSize reserved bytes, then the caller
// appends the type NodeId and the encoded body.
Buffer newMessageBuffer();

// Chunks needed for a body of bodySize bytes with chunks of at most maxChunkSize bytes.
std::size_t chunkCount(std::size_t bodySize, std::size_t maxChunkSize);

// Turns `message` (kSymmetricHeaderSize reserved bytes + body) into complete MSG / CLO
// chunks, in place: one chunk costs no copy; several are made by moving the body parts
// apart inside the same buffer. Takes one sequence number per chunk.
void writeSymmetricChunks(Buffer& message, MessageType type, UInt32 channelId, UInt32 tokenId,
                          UInt32 requestId, SequenceGenerator& sequence, std::size_t maxChunkSize);
// The same for a message with spliced byte runs (BinaryEncoder with Splices): one chunk is
// sent as it is, the splices written from where they are; several are joined first.
// Returns the splices still to be written around `message` (empty after a join).
Splices writeSymmetricChunks(Buffer& message, Splices&& splices, MessageType type, UInt32 channelId,
                             UInt32 tokenId, UInt32 requestId, SequenceGenerator& sequence,
                             std::size_t maxChunkSize);

// One OPN chunk with the SecurityPolicy None asymmetric header (null certificate and
// thumbprint) around `body` (type NodeId + encoded Open request / response).
Buffer makeOpenChunk(UInt32 channelId, UInt32 sequenceNumber, UInt32 requestId, const Byte* body,
                     std::size_t size);

// Little-endian helpers.
inline void putUInt32(Byte* p, UInt32 v) { std::memcpy(p, &v, 4); }
inline UInt32 getUInt32(const Byte* p) {
    UInt32 v;
    std::memcpy(&v, p, 4);
    return v;
}

}  // namespace pnp::ua::transport
