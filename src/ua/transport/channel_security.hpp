// The security of one secure channel (OPC 10000-6 §6.7.2 – §6.7.6), without any I/O:
// asymmetric OpenSecureChannel chunks (signed with the sender's key, then encrypted with the
// receiver's public key block by block, receiver thumbprint checked) and symmetric MSG / CLO
// chunks (HMAC-SHA256, AES-CBC with padding) with keys derived by P_SHA256 from the nonces of
// each token. ServerChannel and ClientChannel own one when the policy is not None.
//
// Every failure to verify, decrypt or unpad a received chunk is reported the same way
// (TransportError BadSecurityChecksFailed, the detail only in the message for the local log),
// so a peer learns nothing about which check failed.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "ua/crypto/crypto.hpp"
#include "ua/pki/pki.hpp"
#include "ua/transport/chunks.hpp"
#include "ua/types/ns0_enums.hpp"

namespace pnp::ua::transport {

// A server's secured channels. Absent (null in ServerTransportConfig): SecurityPolicy None
// only.
struct ServerSecurityConfig {
    pki::Identity identity;  // the application instance certificate and its key
    // The policies accepted in OpenSecureChannel (most secure first), each with Sign and
    // SignAndEncrypt. None is always accepted at this layer: the session layer decides what
    // a None channel may do (discovery only, unless a None endpoint is offered).
    std::vector<const crypto::SecurityPolicy*> policies;
    // Validates a client's certificate chain (leaf first) against the trust list: Good or
    // the reason (logged; the client gets BadSecurityChecksFailed). Called on the network
    // thread per OpenSecureChannel Issue. Null: every well-formed certificate is accepted.
    std::function<StatusCode(const std::vector<pki::Certificate>& chain)> validateClient;
};

// A client's secured channel. Absent (null in ClientConfig): SecurityPolicy None.
struct ClientSecurityConfig {
    const crypto::SecurityPolicy* policy = nullptr;
    MessageSecurityMode mode = MessageSecurityMode::SignAndEncrypt;
    pki::Identity identity;              // the client's certificate and key
    pki::Certificate serverCertificate;  // from the server's EndpointDescription (validated
                                         // by the caller before connecting)
};

// The asymmetric security header of a received OPN chunk, and where encryption starts.
struct AsymmetricHeader {
    std::string_view policyUri;
    crypto::ByteView senderCertificate;   // DER chain, leaf first
    crypto::ByteView receiverThumbprint;  // SHA-1 of the receiver's certificate
    std::size_t end = 0;                  // offset of the sequence header in the chunk
};
AsymmetricHeader parseAsymmetricHeader(const RawChunk& raw);

class ChannelSecurity {
  public:
    // Both sides: `own` signs and decrypts, `remote` (the peer's leaf) verifies and encrypts.
    ChannelSecurity(const crypto::SecurityPolicy& policy, MessageSecurityMode mode,
                    const pki::Identity& own, pki::Certificate remote);

    const crypto::SecurityPolicy& policy() const { return *policy_; }
    MessageSecurityMode mode() const { return mode_; }
    // The server learns the mode from the OpenSecureChannel request it just decrypted.
    void setMode(MessageSecurityMode mode) { mode_ = mode; }
    bool encrypts() const { return mode_ == MessageSecurityMode::SignAndEncrypt; }
    const pki::Certificate& remoteCertificate() const { return remote_; }
    // Our certificate and key on this channel (a server's may since have been replaced by
    // Part 12 ApplyChanges: the channel and its sessions keep the one it was opened with).
    const pki::Identity& ownIdentity() const { return own_; }

    // ---- asymmetric (OPN) -------------------------------------------------------------
    // One OPN chunk around `body` (type NodeId + encoded request / response).
    Buffer sealOpen(UInt32 channelId, UInt32 sequenceNumber, UInt32 requestId,
                    crypto::ByteView body) const;
    // Decrypts and verifies a received OPN chunk whose header `h` was parsed (the caller
    // checked the policy and sender). Returns the plaintext from the sequence header to the
    // end of the body (sequence number, request id, body). Throws BadSecurityChecksFailed.
    Buffer openOpen(const RawChunk& raw, const AsymmetricHeader& h) const;

    // ---- symmetric keys ---------------------------------------------------------------
    // Installs the keys of a token: the client's are P(serverNonce, clientNonce), the
    // server's P(clientNonce, serverNonce). The previous token's keys stay usable for
    // receiving until dropPrevious().
    void installToken(UInt32 tokenId, crypto::ByteView clientNonce, crypto::ByteView serverNonce,
                      bool isServer);
    void dropPrevious() { previous_.reset(); }
    bool hasToken(UInt32 tokenId) const {
        return (current_ && current_->tokenId == tokenId) ||
               (previous_ && previous_->tokenId == tokenId);
    }
    // Which token's keys the next sent message uses (the server keeps the previous one until
    // the client uses the new token).
    void sendWith(UInt32 tokenId);

    // ---- symmetric (MSG / CLO) --------------------------------------------------------
    // Largest body per chunk of at most maxChunkSize bytes.
    std::size_t maxBodyPerChunk(std::size_t maxChunkSize) const;
    // Chunks of `message` (kSymmetricHeaderSize reserved bytes + body), headers written,
    // padded, signed and encrypted. Takes one sequence number per chunk.
    void sealSymmetric(Buffer& message, MessageType type, UInt32 channelId, UInt32 requestId,
                       SequenceGenerator& sequence, std::size_t maxChunkSize);
    // Verifies and decrypts a received MSG / CLO chunk in place (its bytes are ours: the
    // receive buffer). Returns the chunk without padding and signature (its header still
    // says the original size). Throws BadSecurityChecksFailed; BadSecureChannelTokenUnknown
    // for a token without keys.
    RawChunk openSymmetric(const RawChunk& raw);

    // The token the keys of sent messages belong to.
    UInt32 sendTokenId() const { return sendToken_; }

  private:
    struct TokenKeys {
        UInt32 tokenId;
        crypto::SymmetricCipher send;
        crypto::SymmetricCipher receive;
    };
    TokenKeys* keysFor(UInt32 tokenId);

    const crypto::SecurityPolicy* policy_;
    MessageSecurityMode mode_;
    pki::Identity own_;
    crypto::Bytes ownChain_;  // own certificate DER as sent
    pki::Certificate remote_;
    crypto::PublicKey remoteKey_;
    crypto::Bytes remoteThumbprint_;
    std::optional<TokenKeys> current_;
    std::optional<TokenKeys> previous_;
    UInt32 sendToken_ = 0;
};

}  // namespace pnp::ua::transport
