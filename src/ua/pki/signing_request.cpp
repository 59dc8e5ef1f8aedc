// PKCS#10 certification requests for Part 12 CreateSigningRequest, and the subject name form
// Part 12 uses ("CN=name/O=organisation/DC=host").
#include <openssl/err.h>
#include <openssl/objects.h>
#include <openssl/x509.h>
#include <openssl/x509v3.h>

#include <string>
#include <string_view>
#include <vector>

#include "ua/pki/openssl_util.hpp"
#include "ua/pki/pki.hpp"

namespace pnp::ua::pki {

namespace {

using namespace detail;
using X509ReqPtr = Owned<X509_REQ, X509_REQ_free>;
using X509NamePtr = Owned<X509_NAME, X509_NAME_free>;
inline void freeExtensionStack(STACK_OF(X509_EXTENSION) * s) {
    sk_X509_EXTENSION_pop_free(s, X509_EXTENSION_free);
}
using ExtensionStackPtr = Owned<STACK_OF(X509_EXTENSION), freeExtensionStack>;

constexpr std::size_t kMaxSubjectName = 1024;
constexpr std::size_t kMaxSubjectAttributes = 16;

struct Attribute {
    std::string name;  // OpenSSL short name (CN, O, ST, ...)
    std::string value;
};

bool isSpace(char c) { return c == ' ' || c == '\t'; }

// Whether `c` separates attributes outside quotes: '/' always, ',' when no '/' does.
bool separatesOutsideQuotes(std::string_view text, char c) {
    bool quoted = false;
    for (char t : text) {
        if (t == '"') quoted = !quoted;
        if (!quoted && t == c) return true;
    }
    return false;
}

std::vector<Attribute> parseSubjectName(std::string_view text) {
    if (text.size() > kMaxSubjectName) throw PkiError("subject name longer than 1024 characters");
    const bool slashes = separatesOutsideQuotes(text, '/');
    auto separator = [&](char c) { return c == '/' || (!slashes && c == ','); };
    std::vector<Attribute> out;
    std::size_t i = 0;
    const std::size_t n = text.size();
    auto bad = [&](const std::string& why) {
        return PkiError("subject name '" + std::string(text) + "': " + why);
    };
    while (true) {
        while (i < n && (isSpace(text[i]) || separator(text[i]))) ++i;
        if (i == n) break;
        const std::size_t keyStart = i;
        while (i < n && text[i] != '=' && !separator(text[i])) ++i;
        if (i == n || text[i] != '=') throw bad("expected NAME=VALUE");
        std::string_view key = text.substr(keyStart, i - keyStart);
        while (!key.empty() && isSpace(key.back())) key.remove_suffix(1);
        ++i;  // '='
        while (i < n && isSpace(text[i])) ++i;
        std::string value;
        if (i < n && text[i] == '"') {
            const std::size_t close = text.find('"', i + 1);
            if (close == std::string_view::npos) throw bad("unterminated quote");
            value = std::string(text.substr(i + 1, close - i - 1));
            i = close + 1;
            while (i < n && isSpace(text[i])) ++i;
            if (i < n && !separator(text[i])) throw bad("text after a quoted value");
        } else {
            const std::size_t start = i;
            while (i < n && !separator(text[i])) {
                if (text[i] == '=' || text[i] == '"') throw bad("'=' or '\"' in an unquoted value");
                ++i;
            }
            std::string_view v = text.substr(start, i - start);
            while (!v.empty() && isSpace(v.back())) v.remove_suffix(1);
            value = std::string(v);
        }
        std::string name(key);
        if (name == "S") name = "ST";  // Part 12 writes the state as S
        if (name.empty() || OBJ_txt2nid(name.c_str()) == NID_undef) {
            ERR_clear_error();
            throw bad("unknown attribute '" + name + "'");
        }
        if (value.empty()) throw bad("empty value of " + name);
        if (out.size() == kMaxSubjectAttributes) throw bad("more than 16 attributes");
        out.push_back({std::move(name), std::move(value)});
    }
    if (out.empty()) throw bad("no attribute");
    return out;
}

X509NamePtr makeName(const std::vector<Attribute>& attributes) {
    X509NamePtr name(X509_NAME_new());
    check(name != nullptr, "X509_NAME_new");
    for (const Attribute& a : attributes) {
        if (X509_NAME_add_entry_by_txt(name.get(), a.name.c_str(), MBSTRING_UTF8,
                                       reinterpret_cast<const unsigned char*>(a.value.data()),
                                       static_cast<int>(a.value.size()), -1, 0) != 1) {
            throw PkiError("invalid " + a.name + " '" + a.value + "': " + opensslError());
        }
    }
    return name;
}

void pushExtension(STACK_OF(X509_EXTENSION) * stack, X509_EXTENSION* ext, const char* what) {
    if (ext == nullptr) throw PkiError(std::string(what) + ": " + opensslError());
    if (sk_X509_EXTENSION_push(stack, ext) == 0) {
        X509_EXTENSION_free(ext);
        check(false, what);
    }
}

void pushConfigured(STACK_OF(X509_EXTENSION) * stack, int nid, const char* value) {
    X509V3_CTX ctx;
    X509V3_set_ctx(&ctx, nullptr, nullptr, nullptr, nullptr, 0);
    pushExtension(stack, X509V3_EXT_conf_nid(nullptr, &ctx, nid, value), value);
}

// SubjectAltName: the ApplicationUri (required here), host names and addresses.
X509_EXTENSION* subjectAltName(const CertificateRequest& r) {
    if (r.applicationUri.empty()) throw PkiError("invalid ApplicationUri");
    GeneralNamesPtr names = subjectAltNames(r);
    return X509V3_EXT_i2d(NID_subject_alt_name, 0, names.get());
}

bool needsQuotes(const std::string& value) {
    return value.find_first_of("/=,\"") != std::string::npos || value.front() == ' ' ||
           value.back() == ' ';
}

}  // namespace

Bytes createSigningRequest(const crypto::PrivateKey& key, const CertificateRequest& request,
                           std::string_view subjectName) {
    if (!key) throw PkiError("a signing request needs a key");
    if (request.applicationUri.empty())
        throw PkiError("an application instance certificate needs an ApplicationUri");
    std::vector<Attribute> subject;
    if (!subjectName.empty()) {
        subject = parseSubjectName(subjectName);
    } else {
        if (request.commonName.empty()) throw PkiError("the certificate needs a common name");
        subject.push_back({"CN", request.commonName});
        if (!request.organization.empty()) subject.push_back({"O", request.organization});
    }

    X509ReqPtr req(X509_REQ_new());
    check(req != nullptr, "X509_REQ_new");
    check(X509_REQ_set_version(req.get(), X509_REQ_VERSION_1) == 1, "X509_REQ_set_version");
    check(X509_REQ_set_subject_name(req.get(), makeName(subject).get()) == 1, "subject");
    check(X509_REQ_set_pubkey(req.get(), key.native()) == 1, "public key");

    ExtensionStackPtr extensions(sk_X509_EXTENSION_new_null());
    check(extensions != nullptr, "extensions");
    pushExtension(extensions.get(), subjectAltName(request), "SubjectAltName");
    pushConfigured(extensions.get(), NID_basic_constraints, "critical,CA:FALSE");
    pushConfigured(extensions.get(), NID_key_usage,
                   "critical,digitalSignature,nonRepudiation,keyEncipherment,dataEncipherment");
    pushConfigured(extensions.get(), NID_ext_key_usage, "serverAuth,clientAuth");
    check(X509_REQ_add_extensions(req.get(), extensions.get()) == 1, "X509_REQ_add_extensions");

    check(X509_REQ_sign(req.get(), key.native(), EVP_sha256()) > 0, "X509_REQ_sign");
    unsigned char* out = nullptr;
    const int n = i2d_X509_REQ(req.get(), &out);
    check(n > 0, "i2d_X509_REQ");
    Bytes der(out, out + n);
    OPENSSL_free(out);
    return der;
}

std::string subjectNameOf(const Certificate& cert) {
    if (cert.native() == nullptr) throw PkiError("subjectNameOf: no certificate");
    const X509_NAME* name = X509_get_subject_name(cert.native());
    std::string out;
    for (int i = 0; i < X509_NAME_entry_count(name); ++i) {
        const X509_NAME_ENTRY* entry = X509_NAME_get_entry(name, i);
        const int nid = OBJ_obj2nid(X509_NAME_ENTRY_get_object(entry));
        const char* shortName = nid == NID_undef ? nullptr : OBJ_nid2sn(nid);
        if (shortName == nullptr) continue;  // not expressible in the text form
        unsigned char* utf8 = nullptr;
        const int len = ASN1_STRING_to_UTF8(&utf8, X509_NAME_ENTRY_get_data(entry));
        if (len <= 0) {
            ERR_clear_error();
            continue;
        }
        std::string value(reinterpret_cast<const char*>(utf8), static_cast<std::size_t>(len));
        OPENSSL_free(utf8);
        if (value.find('"') != std::string::npos) continue;  // cannot be quoted
        if (!out.empty()) out += '/';
        out += shortName;
        out += '=';
        out += needsQuotes(value) ? '"' + value + '"' : value;
    }
    return out;
}

}  // namespace pnp::ua::pki
