// Test clients of pnp processes connect as the processes' own clients do: securely, with a
// certificate from the machine's PKI folder ($PNP_PKI), which every pnp application of that
// folder trusts (docs/security.md, "secure by default").
#pragma once

#include <memory>
#include <string>

#include "ua/client/config.hpp"
#include "ua/pki/pki.hpp"

namespace pnp::testing {

// Every ua::client::Client made afterwards in this process (without a security of its own)
// connects with SignAndEncrypt and the test's certificate.
inline void useMachinePki() {
    auto store = std::make_shared<ua::pki::CertificateStore>(ua::pki::defaultFolder());
    ua::pki::CertificateRequest request;
    request.applicationUri = "urn:pnp:test:client";
    request.commonName = "pnp test client";
    ua::client::ClientSecurity security;
    security.identity = store->loadOrCreateOwn(request, "pnp-test-client");
    security.trust = store;
    ua::client::setDefaultSecurity(
        ua::client::DefaultSecurity{security, request.applicationUri, request.commonName});
}

}  // namespace pnp::testing
