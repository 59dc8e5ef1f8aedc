#include "ua/transport/secure_channel.hpp"

#include <algorithm>
#include <cstring>

#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::transport {

namespace {

// Receive buffer: the largest chunk plus room to take in the start of the next ones with
// the same read.
constexpr std::size_t kReadSlack = 16 * 1024;
// Before the Hello the largest acceptable chunk: a Hello is at most 8 + 20 + 4 + 4096 bytes.
constexpr std::size_t kPreHelloMaxChunk = kMinBufferSize;

std::size_t readCapacity(const TransportLimits& l) {
    return std::max(l.receiveBufferSize, kMinBufferSize) + kReadSlack;
}

// Channel::feed(): bytes copied in as if they had been read from the socket.
template <class Channel>
void feedBytes(Channel& channel, const Byte* p, std::size_t n, TimePoint now) {
    while (n > 0 && channel.state() != Channel::State::Closed) {
        auto space = channel.readSpace();
        std::size_t k = std::min(n, space.size());
        std::memcpy(space.data(), p, k);
        channel.received(k, now);
        p += k;
        n -= k;
    }
}

template <class T>
NodeId encodingId() {
    return NodeId(0, DataTypeInfo<T>::binaryEncodingId);
}

NodeId decodeTypeId(BinaryDecoder& d) {
    NodeId id;
    decode(d, id);
    return id;
}

// The RequestHandle of an encoded response (type NodeId, then ResponseHeader: Timestamp,
// RequestHandle, ...); 0 when it cannot be read.
UInt32 responseRequestHandle(const Buffer& message) {
    try {
        BinaryDecoder d(message.data() + kSymmetricHeaderSize,
                        message.size() - kSymmetricHeaderSize);
        decodeTypeId(d);
        d.skip(8);
        return d.number<UInt32>();
    } catch (const DecodeError&) {
        return 0;
    }
}

// Whether a message exceeds what the peer announced. The spec counts the message body
// against MaxMessageSize; some stacks (node-opcua) count whole chunks, so we count the chunk
// headers too and never send what either reading would reject.
bool exceedsPeerLimits(const NegotiatedLimits& l, std::size_t body, std::size_t chunks) {
    if (l.maxSendChunkCount && chunks > l.maxSendChunkCount) return true;
    return l.maxSendMessageSize && body + chunks * kSymmetricHeaderSize > l.maxSendMessageSize;
}

// Part 6 §6.7.6: on a secured channel a wrong sequence number (a replayed or a skipped chunk)
// is one more failed security check for the peer, BadSecurityChecksFailed like the others;
// BadSequenceNumberInvalid stays in the reason for our log.
void checkSequence(SequenceValidator& validator, UInt32 sequenceNumber, bool secured) {
    try {
        validator.check(sequenceNumber);
    } catch (const TransportError& e) {
        if (!secured) throw;
        throw TransportError(status::BadSecurityChecksFailed,
                             "BadSequenceNumberInvalid: " + e.message());
    }
}

}  // namespace

// =======================================================================================
// ServerChannel
// =======================================================================================
ServerChannel::ServerChannel(const ServerTransportConfig& config, Hooks& hooks, TimePoint now,
                             MemoryBudget* budget)
    : config_(config),
      hooks_(hooks),
      reader_(readCapacity(config), kPreHelloMaxChunk),
      started_(now),
      lastReceive_(now) {
    assembler_.setBudget(budget);
}

void ServerChannel::feed(const Byte* p, std::size_t n, TimePoint now) {
    feedBytes(*this, p, n, now);
}

void ServerChannel::received(std::size_t n, TimePoint now) {
    reader_.commit(n);
    lastReceive_ = now;
    if (state_ == State::Closed) {
        reader_.clear();
        return;
    }
    try {
        while (state_ != State::Closed) {
            auto chunk = reader_.next();
            if (!chunk) break;
            handleChunk(*chunk, now);
        }
    } catch (const TransportError& e) {
        fail(e.status(), e.message());
    } catch (const DecodeError& e) {
        fail(status::BadDecodingError, e.what());
    } catch (const std::exception& e) {
        fail(status::BadTcpInternalError, e.what());
    }
    if (state_ == State::Closed) reader_.clear();
}

void ServerChannel::handleChunk(const RawChunk& raw, TimePoint now) {
    switch (raw.header.type) {
        case MessageType::Hello:
            if (state_ != State::AwaitHello)
                throw TransportError(status::BadTcpMessageTypeInvalid, "unexpected HEL");
            handleHello(raw);
            return;
        case MessageType::OpenSecureChannel:
        case MessageType::Message:
        case MessageType::CloseSecureChannel:
            if (state_ == State::AwaitHello) {
                throw TransportError(status::BadTcpMessageTypeInvalid,
                                     std::string(toString(raw.header.type)) + " before HEL");
            }
            handleSecureChunk(raw, now);
            return;
        default:
            throw TransportError(
                status::BadTcpMessageTypeInvalid,
                std::string(toString(raw.header.type)) + " is not accepted by a server");
    }
}

void ServerChannel::handleHello(const RawChunk& raw) {
    Hello hello = decodeHello(raw.data + kMessageHeaderSize, raw.size - kMessageHeaderSize);
    Acknowledge ack;
    limits_ = negotiateAsServer(hello, config_, ack);
    helloVersion_ = hello.protocolVersion;
    endpointUrl_ = std::move(hello.endpointUrl);
    reader_.setMaxChunkSize(limits_.receiveBufferSize);
    assembler_.setLimits({limits_.maxReceiveMessageSize, limits_.maxReceiveChunkCount});
    state_ = State::AwaitOpen;
    hooks_.write(encodeMessage(ack));
}

void ServerChannel::handleSecureChunk(const RawChunk& raw, TimePoint now) {
    if (raw.header.type == MessageType::OpenSecureChannel) {
        const AsymmetricHeader h = parseAsymmetricHeader(raw);
        if (h.policyUri != kSecurityPolicyNone) {
            handleSecuredOpen(raw, now);
            return;
        }
        if (security_) {
            throw TransportError(status::BadSecurityPolicyRejected,
                                 "SecurityPolicy None on a secured channel");
        }
    }
    // A secured channel's MSG / CLO: the channel id is clear text, the rest is checked and
    // decrypted before anything in it is looked at.
    RawChunk opened = raw;
    if (security_ && raw.header.type != MessageType::OpenSecureChannel) {
        if (raw.size >= 12 && getUInt32(raw.data + 8) != channelId_) {
            throw TransportError(status::BadSecureChannelIdInvalid,
                                 "secure channel id " + std::to_string(getUInt32(raw.data + 8)) +
                                     ", expected " + std::to_string(channelId_));
        }
        opened = security_->openSymmetric(raw);
    }
    SecureChunk c = parseSecureChunk(opened);
    if (state_ == State::AwaitOpen) {
        if (c.type != MessageType::OpenSecureChannel) {
            throw TransportError(status::BadTcpMessageTypeInvalid,
                                 std::string(toString(c.type)) + " before OpenSecureChannel");
        }
    } else {  // Open
        if (c.channelId != channelId_) {
            throw TransportError(status::BadSecureChannelIdInvalid,
                                 "secure channel id " + std::to_string(c.channelId) +
                                     ", expected " + std::to_string(channelId_));
        }
        if (!current_.usable(now))
            throw TransportError(status::BadSecureChannelClosed, "security token expired");
        if (c.type != MessageType::OpenSecureChannel) checkToken(c.tokenId, now);
    }
    checkSequence(receiveSequence_, c.sequenceNumber, security_ != nullptr);

    auto ev = assembler_.add(c);
    if (ev.result != MessageAssembler::Result::Complete) return;  // incomplete / aborted
    switch (ev.type) {
        case MessageType::OpenSecureChannel:
            handleOpen(ev.requestId, ev.body, ev.size, now);
            break;
        case MessageType::Message:
            handleMessage(ev.requestId, ev.body, ev.size, ev.assembled ? nullptr : reader_.block());
            break;
        case MessageType::CloseSecureChannel:
            close();
            break;
        default:
            break;
    }
}

void ServerChannel::handleSecuredOpen(const RawChunk& raw, TimePoint now) {
    const AsymmetricHeader h = parseAsymmetricHeader(raw);
    const ServerSecurityConfig* sc = config_.security.get();
    const crypto::SecurityPolicy* policy = crypto::findPolicy(h.policyUri);
    if (sc == nullptr || policy == nullptr ||
        std::find(sc->policies.begin(), sc->policies.end(), policy) == sc->policies.end()) {
        throw TransportError(status::BadSecurityPolicyRejected,
                             "SecurityPolicy " + std::string(h.policyUri.substr(0, 200)));
    }
    if (raw.header.chunkType != ChunkType::Final)
        throw TransportError(status::BadSecurityChecksFailed, "OPN in several chunks");
    const UInt32 channelId = getUInt32(raw.data + kMessageHeaderSize);
    if (state_ == State::Open) {
        // Renew: the same channel, policy and client certificate.
        if (channelId != channelId_) {
            throw TransportError(status::BadSecureChannelIdInvalid,
                                 "secure channel id " + std::to_string(channelId));
        }
        if (!security_ || &security_->policy() != policy)
            throw TransportError(status::BadSecurityPolicyRejected, "policy changed on renew");
        const auto& der = security_->remoteCertificate().der();
        if (h.senderCertificate.size() < der.size() ||
            !std::equal(der.begin(), der.end(), h.senderCertificate.begin()))
            throw TransportError(status::BadSecurityChecksFailed, "renew: another certificate");
    } else {
        if (crypto::ByteView(sc->identity.certificate.thumbprint()).size() !=
                h.receiverThumbprint.size() ||
            !crypto::constantTimeEqual(sc->identity.certificate.thumbprint(), h.receiverThumbprint))
            throw TransportError(status::BadSecurityChecksFailed, "receiver thumbprint");
        std::vector<pki::Certificate> chain;
        try {
            chain = pki::Certificate::chainFromDer(h.senderCertificate);
        } catch (const std::exception& e) {
            throw TransportError(status::BadSecurityChecksFailed,
                                 std::string("sender certificate: ") + e.what());
        }
        if (chain.empty())
            throw TransportError(status::BadSecurityChecksFailed, "no sender certificate");
        if (sc->validateClient) {
            const StatusCode st = sc->validateClient(chain);
            if (st.isBad()) {
                throw TransportError(status::BadSecurityChecksFailed,
                                     "client certificate: " + std::string(st.name()));
            }
        }
        security_ = std::make_unique<ChannelSecurity>(*policy, MessageSecurityMode::Invalid,
                                                      sc->identity, chain.front());
    }
    const Buffer plain = security_->openOpen(raw, h);
    if (plain.size() < 8) throw TransportError(status::BadSecurityChecksFailed, "OPN: too short");
    SecureChunk c;
    c.type = MessageType::OpenSecureChannel;
    c.chunkType = ChunkType::Final;
    c.channelId = channelId;
    c.securityPolicyUri = h.policyUri;
    c.sequenceNumber = getUInt32(plain.data());
    c.requestId = getUInt32(plain.data() + 4);
    c.body = plain.data() + 8;
    c.bodySize = plain.size() - 8;
    checkSequence(receiveSequence_, c.sequenceNumber, true);
    auto ev = assembler_.add(c);
    if (ev.result == MessageAssembler::Result::Complete)
        handleOpen(ev.requestId, ev.body, ev.size, now);
}

void ServerChannel::checkToken(UInt32 tokenId, TimePoint now) {
    if (tokenId == current_.tokenId) {
        // The client uses the newest token: the previous one is done with.
        if (previous_ && security_) {
            security_->sendWith(current_.tokenId);
            security_->dropPrevious();
        }
        previous_.reset();
        sendTokenId_ = current_.tokenId;
        return;
    }
    if (previous_ && tokenId == previous_->tokenId && previous_->usable(now)) return;
    throw TransportError(status::BadSecureChannelTokenUnknown,
                         "token id " + std::to_string(tokenId));
}

void ServerChannel::dropExpiredPrevious(TimePoint now) {
    if (previous_ && !previous_->usable(now)) {
        previous_.reset();
        sendTokenId_ = current_.tokenId;
        if (security_) {
            security_->sendWith(current_.tokenId);
            security_->dropPrevious();
        }
    }
}

void ServerChannel::handleOpen(UInt32 requestId, const Byte* body, std::size_t size,
                               TimePoint now) {
    BinaryDecoder d(body, size);
    OpenSecureChannelRequest req;
    if (decodeTypeId(d) != encodingId<OpenSecureChannelRequest>())
        throw TransportError(status::BadDecodingError, "OPN without OpenSecureChannelRequest");
    decode(d, req);

    if (req.clientProtocolVersion != helloVersion_ &&
        req.clientProtocolVersion != kProtocolVersion) {
        throw TransportError(status::BadProtocolVersionUnsupported,
                             "OpenSecureChannel protocol version " +
                                 std::to_string(req.clientProtocolVersion) + " differs from HEL");
    }
    const bool renew = req.requestType == SecurityTokenRequestType::Renew;
    if (!(req.requestType == SecurityTokenRequestType::Issue && state_ == State::AwaitOpen) &&
        !(renew && state_ == State::Open)) {
        throw TransportError(status::BadRequestTypeInvalid, state_ == State::Open
                                                                ? "Issue on an open secure channel"
                                                                : "Renew before Issue");
    }
    if (!security_ && req.securityMode != MessageSecurityMode::None) {
        throw TransportError(status::BadSecurityModeRejected,
                             "MessageSecurityMode " + std::string(toString(req.securityMode)) +
                                 " with SecurityPolicy None");
    }
    ByteString serverNonce;
    if (security_) {
        const bool modeOk = req.securityMode == MessageSecurityMode::Sign ||
                            req.securityMode == MessageSecurityMode::SignAndEncrypt;
        if (!modeOk || (renew && req.securityMode != security_->mode())) {
            throw TransportError(status::BadSecurityModeRejected,
                                 "MessageSecurityMode " + std::string(toString(req.securityMode)));
        }
        if (req.clientNonce.size() != security_->policy().nonceLength)
            throw TransportError(status::BadNonceInvalid, "client nonce length");
        security_->setMode(req.securityMode);
        {
            const auto nonce = crypto::randomBytes(security_->policy().nonceLength);
            serverNonce = ByteString(nonce.data(), nonce.size());
        }
    }

    // Clamped to [min, max]; max wins if a configuration has them the wrong way round.
    auto lifetime = std::min(
        std::max(std::chrono::milliseconds(req.requestedLifetime), config_.minTokenLifetime),
        config_.maxTokenLifetime);
    if (!renew) channelId_ = hooks_.newChannelId();
    TokenState token{nextTokenId_++, now, lifetime};
    if (nextTokenId_ == 0) nextTokenId_ = 1;
    if (renew) {
        // Keep sending with the token the client has been using until it uses the new one
        // (Part 4 §5.5.2.1); it stays acceptable until then or until it expires.
        sendTokenId_ = current_.tokenId;
        previous_ = current_;
    } else {
        sendTokenId_ = token.tokenId;
        state_ = State::Open;
    }
    current_ = token;
    if (security_) {
        security_->installToken(token.tokenId,
                                crypto::ByteView(req.clientNonce.data(), req.clientNonce.size()),
                                crypto::ByteView(serverNonce.data(), serverNonce.size()), true);
        if (!renew) security_->sendWith(token.tokenId);
    }

    OpenSecureChannelResponse resp;
    resp.responseHeader.timestamp = DateTime::now();
    resp.responseHeader.requestHandle = req.requestHeader.requestHandle;
    resp.serverProtocolVersion = kProtocolVersion;
    resp.securityToken.channelId = channelId_;
    resp.securityToken.tokenId = token.tokenId;
    resp.securityToken.createdAt = resp.responseHeader.timestamp;
    resp.securityToken.revisedLifetime = static_cast<UInt32>(lifetime.count());
    resp.serverNonce = std::move(serverNonce);
    Buffer out;
    out.reserve(128);
    BinaryEncoder e(out);
    encode(e, encodingId<OpenSecureChannelResponse>());
    encode(e, resp);
    if (security_) {
        hooks_.write(security_->sealOpen(channelId_, sendSequence_.next(), requestId,
                                         crypto::ByteView(out.data(), out.size())));
        return;
    }
    hooks_.write(
        makeOpenChunk(channelId_, sendSequence_.next(), requestId, out.data(), out.size()));
}

std::string_view ServerChannel::securityPolicyUri() const {
    return security_ ? security_->policy().uri : kSecurityPolicyNone;
}

MessageSecurityMode ServerChannel::securityMode() const {
    return security_ ? security_->mode() : MessageSecurityMode::None;
}

std::size_t ServerChannel::chunksFor(std::size_t body) const {
    if (!security_) return chunkCount(body, limits_.sendBufferSize);
    const std::size_t maxBody = security_->maxBodyPerChunk(limits_.sendBufferSize);
    return body == 0 ? 1 : (body + maxBody - 1) / maxBody;
}

void ServerChannel::handleMessage(UInt32 requestId, const Byte* body, std::size_t size,
                                  ByteBlock* block) {
    BinaryDecoder d(body, size);
    IncomingRequest r;
    r.requestId = requestId;
    r.typeId = decodeTypeId(d);
    r.body = d.position();
    r.size = d.remaining();
    r.block = block;
    hooks_.request(r);
}

bool ServerChannel::send(UInt32 requestId, Buffer&& message) {
    return sendMessage(requestId, std::move(message), false);
}

bool ServerChannel::send(UInt32 requestId, Buffer&& message, Splices&& splices,
                         std::shared_ptr<const void> keepAlive) {
    return sendMessage(requestId, std::move(message), false, std::move(splices),
                       std::move(keepAlive));
}

bool ServerChannel::sendMessage(UInt32 requestId, Buffer&& message, bool isFault, Splices&& splices,
                                std::shared_ptr<const void> keepAlive) {
    if (state_ != State::Open) return false;
    if (message.size() < kSymmetricHeaderSize) return false;
    if (previous_) dropExpiredPrevious(Clock::now());
    const std::size_t body = message.size() + splicedSize(splices) - kSymmetricHeaderSize;
    const std::size_t chunks = chunksFor(body);
    if (exceedsPeerLimits(limits_, body, chunks)) {
        // Limits so small that not even a ServiceFault fits (found by the fuzzer): the
        // client cannot be answered, so the channel ends with an ERR.
        if (isFault) {
            fail(status::BadResponseTooLarge, "a ServiceFault of " + std::to_string(body) +
                                                  " bytes exceeds the client's limits");
            return false;
        }
        return sendServiceFault(requestId, responseRequestHandle(message),
                                status::BadResponseTooLarge);
    }
    if (security_) {
        // Signed (and encrypted) as a whole: spliced byte runs are joined first.
        if (!splices.empty()) message = joinSplices(std::move(message), splices);
        security_->sealSymmetric(message, MessageType::Message, channelId_, requestId,
                                 sendSequence_, limits_.sendBufferSize);
        hooks_.write(std::move(message));
        return true;
    }
    Splices left =
        writeSymmetricChunks(message, std::move(splices), MessageType::Message, channelId_,
                             sendTokenId_, requestId, sendSequence_, limits_.sendBufferSize);
    if (left.empty())
        hooks_.write(std::move(message));
    else
        hooks_.writeSpliced(std::move(message), std::move(left), std::move(keepAlive));
    return true;
}

bool ServerChannel::sendServiceFault(UInt32 requestId, UInt32 requestHandle, StatusCode status) {
    if (state_ != State::Open) return false;
    Buffer b = newMessageBuffer();
    BinaryEncoder e(b);
    ServiceFault fault;
    fault.responseHeader.timestamp = DateTime::now();
    fault.responseHeader.requestHandle = requestHandle;
    fault.responseHeader.serviceResult = status;
    encode(e, encodingId<ServiceFault>());
    encode(e, fault);
    return sendMessage(requestId, std::move(b), true);
}

void ServerChannel::tick(TimePoint now) {
    if (state_ == State::Closed) return;
    if (state_ != State::Open && config_.helloTimeout.count() > 0 &&
        now - started_ >= config_.helloTimeout) {
        fail(status::BadTimeout, "no HEL / OpenSecureChannel within " +
                                     std::to_string(config_.helloTimeout.count()) + " ms");
        return;
    }
    if (config_.idleTimeout.count() > 0 && now - lastReceive_ >= config_.idleTimeout) {
        fail(status::BadTimeout,
             "nothing received for " + std::to_string(config_.idleTimeout.count()) + " ms");
        return;
    }
    if (state_ == State::Open) {
        dropExpiredPrevious(now);
        if (!current_.usable(now)) fail(status::BadSecureChannelClosed, "security token expired");
    }
}

void ServerChannel::close() {
    if (state_ == State::Closed) return;
    state_ = State::Closed;
    closeStatus_ = StatusCode{};
}

void ServerChannel::fail(StatusCode status, const std::string& reason) {
    if (state_ == State::Closed) return;
    state_ = State::Closed;
    closeStatus_ = status;
    closeReason_ = reason;
    // A failed security check tells the peer nothing about which one failed (a signature,
    // the padding, a certificate): the detail stays in closeReason() for our log.
    hooks_.write(encodeMessage(ErrorMessage{
        status, status == status::BadSecurityChecksFailed ? "security checks failed" : reason}));
}

// =======================================================================================
// ClientChannel
// =======================================================================================
ClientChannel::ClientChannel(const ClientConfig& config, std::string endpointUrl, Hooks& hooks)
    : config_(config),
      endpointUrl_(std::move(endpointUrl)),
      hooks_(hooks),
      reader_(readCapacity(config), std::max(config.receiveBufferSize, kMinBufferSize)) {
    if (const ClientSecurityConfig* sc = config_.security.get(); sc && sc->policy) {
        if (sc->mode != MessageSecurityMode::Sign &&
            sc->mode != MessageSecurityMode::SignAndEncrypt)
            throw std::invalid_argument("a secured channel's mode is Sign or SignAndEncrypt");
        security_ = std::make_unique<ChannelSecurity>(*sc->policy, sc->mode, sc->identity,
                                                      sc->serverCertificate);
    }
}

void ClientChannel::start(TimePoint /*now*/) {
    hello_ = makeHello(config_, endpointUrl_);
    state_ = State::AwaitAcknowledge;
    hooks_.write(encodeMessage(hello_));
}

void ClientChannel::feed(const Byte* p, std::size_t n, TimePoint now) {
    feedBytes(*this, p, n, now);
}

void ClientChannel::received(std::size_t n, TimePoint now) {
    reader_.commit(n);
    if (state_ == State::Closed) {
        reader_.clear();
        return;
    }
    auto abort = [&] {
        // Part 6 §7.1.5: a client that encounters a fatal error sends CloseSecureChannel.
        if (state_ == State::Open) {
            try {
                close();
            } catch (...) {
            }
        }
        state_ = State::Closed;
        reader_.clear();
    };
    try {
        while (state_ != State::Closed) {
            auto chunk = reader_.next();
            if (!chunk) break;
            handleChunk(*chunk, now);
        }
    } catch (const TransportError&) {
        abort();
        throw;
    } catch (const DecodeError& e) {
        abort();
        throw TransportError(status::BadDecodingError, e.what());
    }
}

void ClientChannel::handleChunk(const RawChunk& raw, TimePoint now) {
    switch (raw.header.type) {
        case MessageType::Acknowledge: {
            if (state_ != State::AwaitAcknowledge)
                throw TransportError(status::BadTcpMessageTypeInvalid, "unexpected ACK");
            Acknowledge ack =
                decodeAcknowledge(raw.data + kMessageHeaderSize, raw.size - kMessageHeaderSize);
            limits_ = negotiateAsClient(hello_, ack, config_);
            reader_.setMaxChunkSize(limits_.receiveBufferSize);
            assembler_.setLimits({limits_.maxReceiveMessageSize, limits_.maxReceiveChunkCount});
            state_ = State::AwaitOpen;
            writeOpenRequest(false, now);
            return;
        }
        case MessageType::Error: {
            ErrorMessage err =
                decodeError(raw.data + kMessageHeaderSize, raw.size - kMessageHeaderSize);
            state_ = State::Closed;
            throw TransportError(
                err.error.isBad() ? err.error : StatusCode(status::BadUnexpectedError),
                "server sent ERR" + (err.reason.empty() ? "" : " (" + err.reason + ")"));
        }
        case MessageType::OpenSecureChannel:
        case MessageType::Message:
            if (state_ != State::AwaitOpen && state_ != State::Open) {
                throw TransportError(status::BadTcpMessageTypeInvalid,
                                     std::string(toString(raw.header.type)) + " before ACK");
            }
            handleSecureChunk(raw, now);
            return;
        default:
            throw TransportError(
                status::BadTcpMessageTypeInvalid,
                std::string(toString(raw.header.type)) + " is not accepted by a client");
    }
}

void ClientChannel::checkToken(UInt32 tokenId, TimePoint now) {
    if (tokenId == current_.tokenId) return;
    if (previous_ && tokenId == previous_->tokenId && previous_->usable(now)) return;
    throw TransportError(status::BadSecureChannelTokenUnknown,
                         "token id " + std::to_string(tokenId));
}

void ClientChannel::handleSecureChunk(const RawChunk& raw, TimePoint now) {
    SecureChunk c;
    Buffer plain;  // a secured OPN's decrypted sequence header and body
    if (raw.header.type == MessageType::OpenSecureChannel) {
        const AsymmetricHeader h = parseAsymmetricHeader(raw);
        if (!security_) {
            c = parseSecureChunk(raw);
            if (c.securityPolicyUri != kSecurityPolicyNone)
                throw TransportError(status::BadSecurityPolicyRejected, "OPN response policy");
        } else {
            // The server answers with our policy, to our certificate, from its own.
            if (h.policyUri != security_->policy().uri)
                throw TransportError(status::BadSecurityPolicyRejected, "OPN response policy");
            if (raw.header.chunkType != ChunkType::Final)
                throw TransportError(status::BadSecurityChecksFailed, "OPN in several chunks");
            const auto ownThumbprint = config_.security->identity.certificate.thumbprint();
            const auto& serverDer = security_->remoteCertificate().der();
            if (h.receiverThumbprint.size() != ownThumbprint.size() ||
                !crypto::constantTimeEqual(h.receiverThumbprint, ownThumbprint) ||
                h.senderCertificate.size() < serverDer.size() ||
                !std::equal(serverDer.begin(), serverDer.end(), h.senderCertificate.begin()))
                throw TransportError(status::BadSecurityChecksFailed, "OPN response certificates");
            plain = security_->openOpen(raw, h);
            if (plain.size() < 8)
                throw TransportError(status::BadSecurityChecksFailed, "OPN: too short");
            c.type = MessageType::OpenSecureChannel;
            c.chunkType = ChunkType::Final;
            c.channelId = getUInt32(raw.data + kMessageHeaderSize);
            c.securityPolicyUri = h.policyUri;
            c.sequenceNumber = getUInt32(plain.data());
            c.requestId = getUInt32(plain.data() + 4);
            c.body = plain.data() + 8;
            c.bodySize = plain.size() - 8;
        }
        if (state_ == State::Open && c.channelId != channelId_) {
            throw TransportError(status::BadSecureChannelIdInvalid,
                                 "secure channel id " + std::to_string(c.channelId));
        }
    } else {
        if (state_ != State::Open)
            throw TransportError(status::BadTcpMessageTypeInvalid, "MSG before OPN response");
        if (raw.size >= 12 && getUInt32(raw.data + 8) != channelId_) {
            throw TransportError(status::BadSecureChannelIdInvalid,
                                 "secure channel id " + std::to_string(getUInt32(raw.data + 8)));
        }
        c = parseSecureChunk(security_ ? security_->openSymmetric(raw) : raw);
        checkToken(c.tokenId, now);
    }
    receiveSequence_.check(c.sequenceNumber);

    auto ev = assembler_.add(c);
    if (ev.result == MessageAssembler::Result::Incomplete) return;
    if (ev.result == MessageAssembler::Result::Aborted) {
        if (c.type == MessageType::OpenSecureChannel) {
            throw TransportError(
                ev.abortStatus.isBad() ? ev.abortStatus : StatusCode(status::BadUnexpectedError),
                "OpenSecureChannel aborted: " + ev.abortReason);
        }
        IncomingResponse r;
        r.requestId = ev.requestId;
        r.status = ev.abortStatus.isBad() ? ev.abortStatus : StatusCode(status::BadUnexpectedError);
        hooks_.response(std::move(r));
        return;
    }
    if (ev.type == MessageType::OpenSecureChannel) {
        handleOpenResponse(ev.requestId, ev.body, ev.size, now);
        return;
    }
    BinaryDecoder d(ev.body, ev.size);
    IncomingResponse r;
    r.requestId = ev.requestId;
    r.typeId = decodeTypeId(d);
    const std::size_t prefix = ev.size - d.remaining();
    // An assembled body stays in the assembly buffer; a single-chunk one is viewed in the
    // receive buffer or copied out of it. (Handing the receive buffer over instead and
    // allocating a new one was measured slower: glibc trims and re-faults the freed 80 KiB
    // every time.)
    if (ev.assembled) {
        r.body = MessageBody(std::move(assembler_.assemblyBuffer()), prefix, d.remaining());
    } else if (viewBodies_) {
        r.body = MessageBody::viewOf(d.position(), d.remaining(), reader_.block());
    } else {
        r.body = MessageBody(d.position(), d.remaining());
    }
    hooks_.response(std::move(r));
}

void ClientChannel::handleOpenResponse(UInt32 requestId, const Byte* body, std::size_t size,
                                       TimePoint now) {
    const bool renew = state_ == State::Open;
    const UInt32 expected = renew ? renewRequestId_ : openRequestId_;
    if (expected == 0 || requestId != expected) {
        throw TransportError(status::BadUnknownResponse,
                             "OPN response to request " + std::to_string(requestId));
    }
    BinaryDecoder d(body, size);
    NodeId typeId = decodeTypeId(d);
    if (typeId == encodingId<ServiceFault>()) {
        ServiceFault fault;
        decode(d, fault);
        StatusCode s = fault.responseHeader.serviceResult;
        throw TransportError(s.isBad() ? s : StatusCode(status::BadUnexpectedError),
                             "OpenSecureChannel failed");
    }
    if (typeId != encodingId<OpenSecureChannelResponse>())
        throw TransportError(status::BadUnknownResponse, "OPN without OpenSecureChannelResponse");
    OpenSecureChannelResponse resp;
    decode(d, resp);
    if (resp.responseHeader.serviceResult.isBad())
        throw TransportError(resp.responseHeader.serviceResult, "OpenSecureChannel failed");
    if (resp.serverProtocolVersion != limits_.protocolVersion) {
        throw TransportError(status::BadProtocolVersionUnsupported,
                             "OpenSecureChannel server protocol version " +
                                 std::to_string(resp.serverProtocolVersion));
    }
    const auto& tok = resp.securityToken;
    if (renew ? tok.channelId != channelId_ : tok.channelId == 0) {
        throw TransportError(
            status::BadSecureChannelIdInvalid,
            "OpenSecureChannelResponse channel id " + std::to_string(tok.channelId));
    }
    TokenState t;
    t.tokenId = tok.tokenId;
    t.created = now;
    t.lifetime = std::chrono::milliseconds(tok.revisedLifetime ? tok.revisedLifetime
                                                               : config_.requestedLifetime.count());
    if (security_) {
        if (resp.serverNonce.size() != security_->policy().nonceLength)
            throw TransportError(status::BadNonceInvalid, "server nonce length");
        security_->installToken(tok.tokenId, clientNonce_,
                                crypto::ByteView(resp.serverNonce.data(), resp.serverNonce.size()),
                                false);
    }
    if (renew) {
        previous_ = current_;
        renewRequestId_ = 0;
    } else {
        channelId_ = tok.channelId;
        openRequestId_ = 0;
        state_ = State::Open;
    }
    current_ = t;
}

std::size_t ClientChannel::chunksFor(std::size_t body) const {
    if (!security_) return chunkCount(body, limits_.sendBufferSize);
    const std::size_t maxBody = security_->maxBodyPerChunk(limits_.sendBufferSize);
    return body == 0 ? 1 : (body + maxBody - 1) / maxBody;
}

UInt32 ClientChannel::nextRequestId() {
    if (++requestIdCounter_ == 0) requestIdCounter_ = 1;
    return requestIdCounter_;
}

void ClientChannel::writeOpenRequest(bool renew, TimePoint /*now*/) {
    const UInt32 id = nextRequestId();
    OpenSecureChannelRequest req;
    req.requestHeader.timestamp = DateTime::now();
    req.requestHeader.requestHandle = id;
    req.clientProtocolVersion = hello_.protocolVersion;
    req.requestType = renew ? SecurityTokenRequestType::Renew : SecurityTokenRequestType::Issue;
    req.securityMode = security_ ? security_->mode() : MessageSecurityMode::None;
    if (security_) {
        clientNonce_ = crypto::randomBytes(security_->policy().nonceLength);
        req.clientNonce = ByteString(clientNonce_.data(), clientNonce_.size());
    }
    auto lifetime = std::clamp<std::chrono::milliseconds::rep>(config_.requestedLifetime.count(), 0,
                                                               0xFFFFFFFF);
    req.requestedLifetime = static_cast<UInt32>(lifetime);
    Buffer body;
    body.reserve(128);
    BinaryEncoder e(body);
    encode(e, encodingId<OpenSecureChannelRequest>());
    encode(e, req);
    Buffer chunk = security_ ? security_->sealOpen(renew ? channelId_ : 0, sendSequence_.next(), id,
                                                   crypto::ByteView(body.data(), body.size()))
                             : makeOpenChunk(renew ? channelId_ : 0, sendSequence_.next(), id,
                                             body.data(), body.size());
    if (renew)
        renewRequestId_ = id;
    else
        openRequestId_ = id;
    hooks_.write(std::move(chunk));
}

UInt32 ClientChannel::send(Buffer&& message) { return send(std::move(message), Splices{}); }

UInt32 ClientChannel::send(Buffer&& message, Splices&& splices) {
    if (state_ != State::Open)
        throw TransportError(status::BadSecureChannelClosed, "secure channel not open");
    if (message.size() < kSymmetricHeaderSize)
        throw std::invalid_argument("message buffer without the reserved header bytes");
    const std::size_t body = message.size() + splicedSize(splices) - kSymmetricHeaderSize;
    const std::size_t chunks = chunksFor(body);
    if (exceedsPeerLimits(limits_, body, chunks)) {
        throw TransportError(status::BadRequestTooLarge,
                             "request of " + std::to_string(body) + " bytes in " +
                                 std::to_string(chunks) + " chunks, server accepts " +
                                 std::to_string(limits_.maxSendMessageSize) + " bytes / " +
                                 std::to_string(limits_.maxSendChunkCount) + " chunks");
    }
    const UInt32 id = nextRequestId();
    if (security_) {
        if (!splices.empty()) message = joinSplices(std::move(message), splices);
        security_->sealSymmetric(message, MessageType::Message, channelId_, id, sendSequence_,
                                 limits_.sendBufferSize);
        hooks_.write(std::move(message));
        return id;
    }
    Splices left =
        writeSymmetricChunks(message, std::move(splices), MessageType::Message, channelId_,
                             current_.tokenId, id, sendSequence_, limits_.sendBufferSize);
    if (left.empty())
        hooks_.write(std::move(message));
    else
        hooks_.writeSpliced(std::move(message), left);
    return id;
}

TimePoint ClientChannel::renewalDue() const {
    if (state_ != State::Open) return TimePoint::max();
    return current_.created + current_.lifetime * 3 / 4;
}

bool ClientChannel::renewIfDue(TimePoint now) {
    if (state_ != State::Open || renewRequestId_ != 0 || now < renewalDue()) return false;
    writeOpenRequest(true, now);
    return true;
}

void ClientChannel::close() {
    if (state_ == State::Open) {
        state_ = State::Closed;
        Buffer b = newMessageBuffer();
        BinaryEncoder e(b);
        CloseSecureChannelRequest req;
        req.requestHeader.timestamp = DateTime::now();
        encode(e, encodingId<CloseSecureChannelRequest>());
        encode(e, req);
        if (security_)
            security_->sealSymmetric(b, MessageType::CloseSecureChannel, channelId_,
                                     nextRequestId(), sendSequence_, limits_.sendBufferSize);
        else
            writeSymmetricChunks(b, MessageType::CloseSecureChannel, channelId_, current_.tokenId,
                                 nextRequestId(), sendSequence_, limits_.sendBufferSize);
        hooks_.write(std::move(b));
    }
    state_ = State::Closed;
}

}  // namespace pnp::ua::transport
