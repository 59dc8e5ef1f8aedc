#include "ua/transport/channel_security.hpp"

#include <algorithm>
#include <cstring>

#include "ua/types/status_codes.hpp"

namespace pnp::ua::transport {

namespace {

// Every failed check of a received chunk: one status for the peer, the detail for our log.
[[noreturn]] void securityCheckFailed(const char* what) {
    throw TransportError(status::BadSecurityChecksFailed, what);
}

constexpr std::size_t kSequenceHeaderSize = 8;
// MSG / CLO: message header + channel id + token id; encryption starts after it.
constexpr std::size_t kSymmetricSecurityHeaderEnd = kMessageHeaderSize + 8;

void putLengthPrefixed(Buffer& b, crypto::ByteView bytes) {
    BinaryEncoder e(b);
    if (bytes.empty()) {
        e.number(Int32{-1});
        return;
    }
    e.number(static_cast<Int32>(bytes.size()));
    e.raw(bytes.data(), bytes.size());
}

}  // namespace

AsymmetricHeader parseAsymmetricHeader(const RawChunk& raw) {
    AsymmetricHeader h;
    std::size_t at = kMessageHeaderSize + 4;  // after the secure channel id
    auto field = [&]() -> crypto::ByteView {
        if (raw.size - std::min(raw.size, at) < 4)
            throw TransportError(status::BadDecodingError, "OPN security header truncated");
        const auto n = static_cast<Int32>(getUInt32(raw.data + at));
        at += 4;
        if (n <= 0) {
            if (n < -1) throw TransportError(status::BadDecodingError, "negative length");
            return {};
        }
        if (raw.size - at < static_cast<std::size_t>(n))
            throw TransportError(status::BadDecodingError, "OPN security header truncated");
        crypto::ByteView v(raw.data + at, static_cast<std::size_t>(n));
        at += static_cast<std::size_t>(n);
        return v;
    };
    const auto uri = field();
    h.policyUri = {reinterpret_cast<const char*>(uri.data()), uri.size()};
    h.senderCertificate = field();
    h.receiverThumbprint = field();
    h.end = at;
    return h;
}

ChannelSecurity::ChannelSecurity(const crypto::SecurityPolicy& policy, MessageSecurityMode mode,
                                 const pki::Identity& own, pki::Certificate remote)
    : policy_(&policy),
      mode_(mode),
      own_(own),
      ownChain_(own.certificate.der()),
      remote_(std::move(remote)),
      remoteKey_(remote_.publicKey()),
      remoteThumbprint_(remote_.thumbprint()) {}

// ---- asymmetric -------------------------------------------------------------------------
Buffer ChannelSecurity::sealOpen(UInt32 channelId, UInt32 sequenceNumber, UInt32 requestId,
                                 crypto::ByteView body) const {
    const std::size_t signatureSize = static_cast<std::size_t>(own_.key.bits()) / 8;
    const int remoteBits = remoteKey_.bits();
    const std::size_t plainBlock =
        crypto::plainBlockSize(remoteBits, policy_->asymmetricEncryption);
    const std::size_t cipherBlock = crypto::cipherBlockSize(remoteBits);
    const bool extra = cipherBlock > 256;  // a key over 2048 bits: ExtraPaddingSize

    Buffer chunk;
    chunk.reserve(kMessageHeaderSize + 4 + 12 + policy_->uri.size() + ownChain_.size() + 20 +
                  body.size() + 2 * cipherBlock + signatureSize + 2 * plainBlock);
    chunk.resize(kMessageHeaderSize);
    {
        BinaryEncoder e(chunk);
        e.number(channelId);
    }
    putLengthPrefixed(chunk, crypto::view(policy_->uri));
    putLengthPrefixed(chunk, ownChain_);
    putLengthPrefixed(chunk, remoteThumbprint_);
    const std::size_t headerEnd = chunk.size();

    const std::size_t unpadded =
        kSequenceHeaderSize + body.size() + 1 + (extra ? 1 : 0) + signatureSize;
    const std::size_t paddingSize = (plainBlock - unpadded % plainBlock) % plainBlock;
    const std::size_t plainSize = unpadded + paddingSize;
    const std::size_t encryptedSize = plainSize / plainBlock * cipherBlock;
    {
        BinaryEncoder e(chunk);
        e.number(sequenceNumber);
        e.number(requestId);
        e.raw(body.data(), body.size());
    }
    Byte* pad = chunk.append(paddingSize + 1 + (extra ? 1 : 0));
    std::memset(pad, static_cast<int>(paddingSize & 0xFF), paddingSize + 1);
    if (extra) pad[paddingSize + 1] = static_cast<Byte>(paddingSize >> 8);
    encodeMessageHeader(chunk.data(), MessageType::OpenSecureChannel, ChunkType::Final,
                        static_cast<UInt32>(headerEnd + encryptedSize));
    const crypto::Bytes signature = crypto::sign(own_.key, policy_->asymmetricSignature,
                                                 crypto::ByteView(chunk.data(), chunk.size()));
    BinaryEncoder(chunk).raw(signature.data(), signature.size());

    const crypto::Bytes cipher =
        crypto::encrypt(remoteKey_, policy_->asymmetricEncryption,
                        crypto::ByteView(chunk.data() + headerEnd, chunk.size() - headerEnd));
    chunk.resize(headerEnd);
    BinaryEncoder(chunk).raw(cipher.data(), cipher.size());
    return chunk;
}

Buffer ChannelSecurity::openOpen(const RawChunk& raw, const AsymmetricHeader& h) const {
    const std::size_t ownBytes = static_cast<std::size_t>(own_.key.bits()) / 8;
    const std::size_t signatureSize = static_cast<std::size_t>(remoteKey_.bits()) / 8;
    const std::size_t encrypted = raw.size - h.end;
    if (encrypted == 0 || encrypted % ownBytes != 0) securityCheckFailed("OPN: not whole blocks");
    // The signature covers the chunk in plain text: the clear headers, then what decrypts.
    Buffer plain(h.end + encrypted);
    std::memcpy(plain.data(), raw.data, h.end);
    const auto n = crypto::decryptInto(own_.key, policy_->asymmetricEncryption,
                                       crypto::ByteView(raw.data + h.end, encrypted),
                                       std::span<std::uint8_t>(plain.data() + h.end, encrypted));
    if (!n) securityCheckFailed("OPN: decryption failed");
    const std::size_t total = h.end + *n;
    if (*n < kSequenceHeaderSize + 1 + signatureSize) securityCheckFailed("OPN: too short");
    const std::size_t signedSize = total - signatureSize;
    if (!crypto::verify(remoteKey_, policy_->asymmetricSignature,
                        crypto::ByteView(plain.data(), signedSize),
                        crypto::ByteView(plain.data() + signedSize, signatureSize)))
        securityCheckFailed("OPN: signature");
    // Padding: PaddingSize + 1 bytes of its low byte, then ExtraPaddingSize when our key
    // (which it was encrypted with) is over 2048 bits.
    std::size_t at = signedSize - 1;
    std::size_t paddingSize = plain[at];
    const Byte low = ownBytes > 256 ? plain[at - 1] : plain[at];
    if (ownBytes > 256) {
        paddingSize = (static_cast<std::size_t>(plain[at]) << 8) | low;
        --at;
    }
    const std::size_t bodyStart = h.end + kSequenceHeaderSize;
    if (at < bodyStart + paddingSize) securityCheckFailed("OPN: padding");
    for (std::size_t i = at - paddingSize; i <= at; ++i)
        if (plain[i] != low) securityCheckFailed("OPN: padding");
    Buffer out;
    out.assign(plain.data() + h.end, plain.data() + (at - paddingSize));
    return out;
}

// ---- symmetric keys -----------------------------------------------------------------------
void ChannelSecurity::installToken(UInt32 tokenId, crypto::ByteView clientNonce,
                                   crypto::ByteView serverNonce, bool isServer) {
    const auto clientKeys = crypto::deriveKeys(*policy_, serverNonce, clientNonce);
    const auto serverKeys = crypto::deriveKeys(*policy_, clientNonce, serverNonce);
    previous_ = std::move(current_);
    current_.emplace(
        TokenKeys{tokenId, crypto::SymmetricCipher(*policy_, isServer ? serverKeys : clientKeys),
                  crypto::SymmetricCipher(*policy_, isServer ? clientKeys : serverKeys)});
    // The client sends with the new token at once; the server until the client uses it
    // (sendWith) with the one it had.
    if (!isServer || sendToken_ == 0) sendToken_ = tokenId;
}

void ChannelSecurity::sendWith(UInt32 tokenId) {
    if (hasToken(tokenId)) sendToken_ = tokenId;
}

ChannelSecurity::TokenKeys* ChannelSecurity::keysFor(UInt32 tokenId) {
    if (current_ && current_->tokenId == tokenId) return &*current_;
    if (previous_ && previous_->tokenId == tokenId) return &*previous_;
    return nullptr;
}

// ---- symmetric ------------------------------------------------------------------------------
std::size_t ChannelSecurity::maxBodyPerChunk(std::size_t maxChunkSize) const {
    if (encrypts()) {
        const std::size_t encrypted = (maxChunkSize - kSymmetricSecurityHeaderEnd) / 16 * 16;
        return encrypted - kSequenceHeaderSize - 32 - 1;
    }
    return maxChunkSize - kSymmetricHeaderSize - 32;
}

void ChannelSecurity::sealSymmetric(Buffer& message, MessageType type, UInt32 channelId,
                                    UInt32 requestId, SequenceGenerator& sequence,
                                    std::size_t maxChunkSize) {
    TokenKeys* keys = keysFor(sendToken_);
    if (keys == nullptr) throw TransportError(status::BadSecureChannelClosed, "no keys to send");
    crypto::SymmetricCipher& cipher = keys->send;
    const bool encrypt = encrypts();
    const std::size_t body = message.size() - kSymmetricHeaderSize;
    const std::size_t maxBody = maxBodyPerChunk(maxChunkSize);
    const std::size_t n = body == 0 ? 1 : (body + maxBody - 1) / maxBody;

    // Finishes the chunk at p whose body (len bytes) is in place: header, padding, signature,
    // encryption. Returns its size.
    auto finish = [&](Byte* p, std::size_t len, ChunkType ct) {
        std::size_t size = kSymmetricHeaderSize + len;
        if (encrypt) {
            const std::size_t unpadded = kSequenceHeaderSize + len + 1 + 32;
            const std::size_t paddingSize = (16 - unpadded % 16) % 16;
            std::memset(p + size, static_cast<int>(paddingSize), paddingSize + 1);
            size += paddingSize + 1;
        }
        size += 32;
        encodeMessageHeader(p, type, ct, static_cast<UInt32>(size));
        putUInt32(p + 8, channelId);
        putUInt32(p + 12, keys->tokenId);
        putUInt32(p + 16, sequence.next());
        putUInt32(p + 20, requestId);
        cipher.sign(crypto::ByteView(p, size - 32), p + size - 32);
        if (encrypt)
            cipher.encrypt(std::span<std::uint8_t>(p + kSymmetricSecurityHeaderEnd,
                                                   size - kSymmetricSecurityHeaderEnd));
        return size;
    };

    if (n == 1) {
        message.append(16 + 32);  // room for padding and signature
        const std::size_t size = finish(message.data(), body, ChunkType::Final);
        message.resize(size);
        return;
    }
    Buffer out(n * maxChunkSize);
    std::size_t written = 0;
    for (std::size_t i = 0; i < n; ++i) {
        const std::size_t len = std::min(maxBody, body - i * maxBody);
        Byte* p = out.data() + written;
        std::memcpy(p + kSymmetricHeaderSize, message.data() + kSymmetricHeaderSize + i * maxBody,
                    len);
        written += finish(p, len, i + 1 == n ? ChunkType::Final : ChunkType::Intermediate);
    }
    out.resize(written);
    message = std::move(out);
}

RawChunk ChannelSecurity::openSymmetric(const RawChunk& raw) {
    if (raw.size < kSymmetricHeaderSize + 32) securityCheckFailed("chunk too short");
    TokenKeys* keys = keysFor(getUInt32(raw.data + 12));
    if (keys == nullptr)
        throw TransportError(status::BadSecureChannelTokenUnknown,
                             "token id " + std::to_string(getUInt32(raw.data + 12)));
    // The chunk lies in our receive buffer, which is ours to decrypt in place.
    Byte* p = const_cast<Byte*>(raw.data);
    std::size_t size = raw.size;
    if (encrypts()) {
        if ((size - kSymmetricSecurityHeaderEnd) % 16 != 0) securityCheckFailed("not whole blocks");
        keys->receive.decrypt(std::span<std::uint8_t>(p + kSymmetricSecurityHeaderEnd,
                                                      size - kSymmetricSecurityHeaderEnd));
    }
    if (!keys->receive.verify(crypto::ByteView(p, size - 32), crypto::ByteView(p + size - 32, 32)))
        securityCheckFailed("signature");
    size -= 32;
    if (encrypts()) {
        const Byte paddingSize = p[size - 1];
        if (size - 1 < kSymmetricHeaderSize + paddingSize) securityCheckFailed("padding");
        for (std::size_t i = size - 1 - paddingSize; i < size; ++i)
            if (p[i] != paddingSize) securityCheckFailed("padding");
        size -= static_cast<std::size_t>(paddingSize) + 1;
    }
    return RawChunk{raw.header, raw.data, size};
}

}  // namespace pnp::ua::transport
