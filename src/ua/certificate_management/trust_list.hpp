// Internal: the store's trust list as Part 12 sees it (TrustListDataType, OPC 10000-12
// §7.8.2.8), and the checks of the certificates a client hands in. Blocking (files of the
// store): called off the network thread.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "ua/pki/pki.hpp"
#include "ua/types/ns0_types_other.hpp"
#include "ua/types/status_code.hpp"

namespace pnp::ua::certificate_management::detail {

// TrustListMasks (OPC 10000-12 §7.8.2.9).
namespace mask {
inline constexpr UInt32 TrustedCertificates = 1;
inline constexpr UInt32 TrustedCrls = 2;
inline constexpr UInt32 IssuerCertificates = 4;
inline constexpr UInt32 IssuerCrls = 8;
inline constexpr UInt32 All = 15;
}  // namespace mask

// The lists of `masks` as the store holds them now (CRLs as DER; files that do not parse are
// left out). CRL files larger than maxFileBytes are skipped.
TrustListDataType readTrustList(const pki::CertificateStore& store, UInt32 masks,
                                std::size_t maxFileBytes);

// UA Binary (the TrustList file's content) and back; decode: Bad_DecodingError for
// anything but exactly one TrustListDataType (arrays of at most maxElements, byte strings of
// at most maxBytes), Bad_InvalidArgument for SpecifiedLists beyond All.
std::vector<Byte> encodeTrustList(const TrustListDataType& list);
StatusCode decodeTrustList(const std::vector<Byte>& bytes, std::size_t maxBytes,
                           std::size_t maxElements, TrustListDataType& out);

// CloseAndUpdate: every certificate and CRL is checked first (Bad_CertificateInvalid,
// Bad_CertificatePolicyCheckFailed: nothing changes); then each list named in
// specifiedLists replaces the folder's (new files first, then the ones no longer listed are
// removed, so that a validation in between never sees an empty folder).
StatusCode replaceTrustList(pki::CertificateStore& store, const TrustListDataType& list);

// AddCertificate (trusted list only): a well-formed application certificate (not a CA: those
// come with their CRLs through the file), key size within policy, signed by itself or by a CA
// of the trust list.
StatusCode addTrustedCertificate(pki::CertificateStore& store, const ByteString& der);

// RemoveCertificate: Bad_InvalidArgument when the thumbprint (40 hex digits) names no
// certificate of that list; Bad_CertificateChainIncomplete for a CA another certificate of the
// trust list needs. A CA's CRLs go with it.
StatusCode removeCertificate(pki::CertificateStore& store, const std::string& thumbprint,
                             bool trustedList);

// UpdateCertificate's checks of a new application instance certificate and its issuers
// (leaf first): structure, policy (2048..4096-bit RSA, SHA-2 signature), validity period, the
// ApplicationUri (exact), key usage (digitalSignature + keyEncipherment, serverAuth when
// extended key usage is present, no CA), each certificate signed by the next one.
StatusCode checkApplicationCertificate(const pki::Certificate& leaf,
                                       const std::vector<pki::Certificate>& issuers,
                                       const std::string& applicationUri);

// Whether a certificate's public key is the key's.
bool sameKey(const pki::Certificate& cert, const crypto::PrivateKey& key);

}  // namespace pnp::ua::certificate_management::detail
