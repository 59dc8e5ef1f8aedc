#include "ua/transport/chunks.hpp"

#include <algorithm>
#include <cstring>

#include "ua/types/status_codes.hpp"

namespace pnp::ua::transport {

// ---- ChunkReader -----------------------------------------------------------------------
ChunkReader::ChunkReader(std::size_t capacity, std::size_t maxChunkSize)
    : buf_(std::max(capacity, kMessageHeaderSize)),
      capacity_(std::max(capacity, kMessageHeaderSize)),
      maxChunk_(std::min(maxChunkSize, capacity_)) {}

void ChunkReader::setMaxChunkSize(std::size_t n) { maxChunk_ = std::min(n, capacity_); }

std::span<Byte> ChunkReader::readSpace() {
    if (begin_ > 0) {
        // The bytes before begin_ are about to be overwritten: values that still point
        // into them keep this block, the reader continues in a new one.
        const std::size_t left = end_ - begin_;
        if (buf_->unique()) {
            if (left != 0) std::memmove(buf_->data(), buf_->data() + begin_, left);
        } else {
            ByteBlockRef fresh(capacity_);
            if (left != 0) std::memcpy(fresh->data(), buf_->data() + begin_, left);
            buf_ = std::move(fresh);
        }
        begin_ = 0;
        end_ = left;
    }
    return {buf_->data() + end_, capacity_ - end_};
}

void ChunkReader::clear() {
    if (!buf_->unique()) buf_ = ByteBlockRef(capacity_);
    begin_ = end_ = 0;
}

void ChunkReader::commit(std::size_t n) { end_ = std::min(end_ + n, capacity_); }

std::size_t ChunkReader::append(const Byte* p, std::size_t n) {
    auto space = readSpace();
    std::size_t k = std::min(n, space.size());
    if (k) std::memcpy(space.data(), p, k);
    commit(k);
    return k;
}

std::optional<RawChunk> ChunkReader::next() {
    std::size_t avail = end_ - begin_;
    if (avail < kMessageHeaderSize) return std::nullopt;
    const Byte* p = buf_->data() + begin_;
    MessageHeader h = decodeMessageHeader(p);
    if (h.size > maxChunk_) {
        throw TransportError(status::BadTcpMessageTooLarge,
                             "chunk of " + std::to_string(h.size) + " bytes exceeds the " +
                                 std::to_string(maxChunk_) + " byte receive buffer");
    }
    if (avail < h.size) return std::nullopt;
    begin_ += h.size;
    return RawChunk{h, p, h.size};
}

// ---- secure chunks ---------------------------------------------------------------------
SecureChunk parseSecureChunk(const RawChunk& raw) {
    SecureChunk c;
    c.type = raw.header.type;
    c.chunkType = raw.header.chunkType;
    const Byte* p = raw.data + kMessageHeaderSize;
    const Byte* end = raw.data + raw.size;
    auto need = [&](std::size_t n) {
        if (static_cast<std::size_t>(end - p) < n)
            throw TransportError(status::BadDecodingError, "secure chunk headers truncated");
    };
    auto u32 = [&] {
        need(4);
        UInt32 v = getUInt32(p);
        p += 4;
        return v;
    };
    // Int32 length + bytes; -1 is null. Returns the bytes, checked against the chunk size.
    auto bytes = [&]() -> std::string_view {
        auto n = static_cast<Int32>(u32());
        if (n <= 0) {
            if (n < -1) throw TransportError(status::BadDecodingError, "negative length");
            return {};
        }
        need(static_cast<std::size_t>(n));
        std::string_view s(reinterpret_cast<const char*>(p), static_cast<std::size_t>(n));
        p += n;
        return s;
    };

    c.channelId = u32();
    switch (c.type) {
        case MessageType::OpenSecureChannel:
            c.securityPolicyUri = bytes();
            c.senderCertificateSize = bytes().size();
            c.receiverThumbprintSize = bytes().size();
            break;
        case MessageType::Message:
        case MessageType::CloseSecureChannel:
            c.tokenId = u32();
            break;
        default:
            throw TransportError(status::BadTcpMessageTypeInvalid,
                                 std::string(toString(c.type)) + " is not a secure message");
    }
    c.sequenceNumber = u32();
    c.requestId = u32();
    c.body = p;
    c.bodySize = static_cast<std::size_t>(end - p);
    return c;
}

// ---- sequence numbers ------------------------------------------------------------------
void SequenceValidator::check(UInt32 sequenceNumber) {
    if (!started_) {
        started_ = true;
        last_ = sequenceNumber;
        return;
    }
    bool ok = (last_ != 0xFFFFFFFFu && sequenceNumber == last_ + 1) ||
              (last_ > SequenceGenerator::kWrapAbove && sequenceNumber < 1024);
    if (!ok) {
        throw TransportError(status::BadSequenceNumberInvalid,
                             "sequence number " + std::to_string(sequenceNumber) + " after " +
                                 std::to_string(last_));
    }
    last_ = sequenceNumber;
}

// ---- MessageAssembler ------------------------------------------------------------------
MessageAssembler::Event MessageAssembler::add(const SecureChunk& chunk) {
    Event ev;
    ev.type = chunk.type;
    ev.requestId = chunk.requestId;

    if (chunks_ > 0) {
        if (chunk.type != type_) {
            throw TransportError(status::BadTcpMessageTypeInvalid,
                                 std::string(toString(chunk.type)) + " chunk inside a " +
                                     std::string(toString(type_)) + " message");
        }
        if (chunk.requestId != requestId_) {
            throw TransportError(status::BadDecodingError,
                                 "chunk of request " + std::to_string(chunk.requestId) +
                                     " while request " + std::to_string(requestId_) +
                                     " is incomplete");
        }
    }

    if (chunk.chunkType == ChunkType::Abort) {
        // Body: Error (UInt32) + Reason (String). The partial message is discarded.
        reset();
        ev.result = Result::Aborted;
        if (chunk.bodySize < 8)
            throw TransportError(status::BadDecodingError, "abort chunk too short");
        ev.abortStatus = StatusCode(getUInt32(chunk.body));
        auto n = static_cast<Int32>(getUInt32(chunk.body + 4));
        if (n > 0) {
            std::size_t len = std::min<std::size_t>(static_cast<std::size_t>(n),
                                                    std::min(chunk.bodySize - 8, kMaxReasonLength));
            ev.abortReason.assign(reinterpret_cast<const char*>(chunk.body + 8), len);
        }
        return ev;
    }

    std::size_t count = chunks_ + 1;
    std::size_t total = (chunks_ > 0 ? assembly_.size() : 0) + chunk.bodySize;
    if (limits_.maxChunkCount && count > limits_.maxChunkCount) {
        reset();
        throw TransportError(
            status::BadTcpMessageTooLarge,
            "message exceeds " + std::to_string(limits_.maxChunkCount) + " chunks");
    }
    if (limits_.maxMessageSize && total > limits_.maxMessageSize) {
        reset();
        throw TransportError(
            status::BadTcpMessageTooLarge,
            "message exceeds " + std::to_string(limits_.maxMessageSize) + " bytes");
    }

    if (chunk.chunkType == ChunkType::Final && chunks_ == 0) {
        // The common case: a single-chunk message is handed out where it is.
        ev.result = Result::Complete;
        ev.body = chunk.body;
        ev.size = chunk.bodySize;
        return ev;
    }

    if (chunks_ == 0) {
        assembly_.clear();
        type_ = chunk.type;
        requestId_ = chunk.requestId;
    }
    if (budget_) {
        if (!budget_->tryTake(chunk.bodySize)) {
            reset();
            throw TransportError(status::BadTcpNotEnoughResources,
                                 "the server's memory for incoming messages (" +
                                     std::to_string(budget_->limit()) + " bytes) is in use");
        }
        held_ += chunk.bodySize;
    }
    assembly_.insert(assembly_.end(), chunk.body, chunk.body + chunk.bodySize);
    chunks_ = count;
    if (chunk.chunkType == ChunkType::Intermediate) return ev;  // Incomplete

    // Complete: handed out for processing, so it no longer counts as incomplete.
    release();
    chunks_ = 0;
    ev.result = Result::Complete;
    ev.body = assembly_.data();
    ev.size = assembly_.size();
    ev.assembled = true;
    return ev;
}

// ---- writing ---------------------------------------------------------------------------
Buffer newMessageBuffer() {
    Buffer b;
    b.reserve(512);
    b.resize(kSymmetricHeaderSize);
    return b;
}

std::size_t chunkCount(std::size_t bodySize, std::size_t maxChunkSize) {
    std::size_t maxBody = maxChunkSize - kSymmetricHeaderSize;
    return bodySize == 0 ? 1 : (bodySize + maxBody - 1) / maxBody;
}

namespace {
void writeSymmetricHeader(Byte* p, MessageType type, ChunkType ct, std::size_t chunkSize,
                          UInt32 channelId, UInt32 tokenId, UInt32 seq, UInt32 requestId) {
    encodeMessageHeader(p, type, ct, static_cast<UInt32>(chunkSize));
    putUInt32(p + 8, channelId);
    putUInt32(p + 12, tokenId);
    putUInt32(p + 16, seq);
    putUInt32(p + 20, requestId);
}
}  // namespace

void writeSymmetricChunks(Buffer& message, MessageType type, UInt32 channelId, UInt32 tokenId,
                          UInt32 requestId, SequenceGenerator& sequence, std::size_t maxChunkSize) {
    const std::size_t body = message.size() - kSymmetricHeaderSize;
    const std::size_t maxBody = maxChunkSize - kSymmetricHeaderSize;
    const std::size_t n = chunkCount(body, maxChunkSize);
    if (n == 1) {
        writeSymmetricHeader(message.data(), type, ChunkType::Final, message.size(), channelId,
                             tokenId, sequence.next(), requestId);
        return;
    }
    // Chunk i's body starts at kSymmetricHeaderSize + i * maxBody now and moves to
    // i * maxChunkSize + kSymmetricHeaderSize, i.e. i * kSymmetricHeaderSize further right.
    // Moving the last part first never overwrites a part still to be moved.
    message.resize(body + n * kSymmetricHeaderSize);
    Byte* base = message.data();
    for (std::size_t i = n - 1; i >= 1; --i) {
        std::size_t len = std::min(maxBody, body - i * maxBody);
        std::memmove(base + i * maxChunkSize + kSymmetricHeaderSize,
                     base + kSymmetricHeaderSize + i * maxBody, len);
    }
    for (std::size_t i = 0; i < n; ++i) {
        std::size_t len = std::min(maxBody, body - i * maxBody);
        writeSymmetricHeader(
            base + i * maxChunkSize, type, i + 1 == n ? ChunkType::Final : ChunkType::Intermediate,
            len + kSymmetricHeaderSize, channelId, tokenId, sequence.next(), requestId);
    }
}

Splices writeSymmetricChunks(Buffer& message, Splices&& splices, MessageType type, UInt32 channelId,
                             UInt32 tokenId, UInt32 requestId, SequenceGenerator& sequence,
                             std::size_t maxChunkSize) {
    if (!splices.empty()) {
        const std::size_t total = message.size() + splicedSize(splices);
        if (chunkCount(total - kSymmetricHeaderSize, maxChunkSize) == 1) {
            writeSymmetricHeader(message.data(), type, ChunkType::Final, total, channelId, tokenId,
                                 sequence.next(), requestId);
            return std::move(splices);
        }
        message = joinSplices(std::move(message), splices);
    }
    writeSymmetricChunks(message, type, channelId, tokenId, requestId, sequence, maxChunkSize);
    return {};
}

Buffer makeOpenChunk(UInt32 channelId, UInt32 sequenceNumber, UInt32 requestId, const Byte* body,
                     std::size_t size) {
    Buffer b;
    b.reserve(kMessageHeaderSize + 4 + 4 + kSecurityPolicyNone.size() + 8 + 8 + size);
    b.resize(kMessageHeaderSize);
    BinaryEncoder e(b);
    e.number(channelId);
    e.number(static_cast<Int32>(kSecurityPolicyNone.size()));
    e.raw(kSecurityPolicyNone.data(), kSecurityPolicyNone.size());
    e.number(Int32{-1});  // SenderCertificate: null
    e.number(Int32{-1});  // ReceiverCertificateThumbprint: null
    e.number(sequenceNumber);
    e.number(requestId);
    e.raw(body, size);
    encodeMessageHeader(b.data(), MessageType::OpenSecureChannel, ChunkType::Final,
                        static_cast<UInt32>(b.size()));
    return b;
}

}  // namespace pnp::ua::transport
