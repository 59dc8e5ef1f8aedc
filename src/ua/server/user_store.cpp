#include "ua/server/user_store.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "ua/crypto/crypto.hpp"
#include "ua/server/roles.hpp"

namespace pnp::ua::server {

namespace {
constexpr std::string_view kPbkdf2 = "pbkdf2-sha256";
constexpr std::string_view kX509 = "x509-sha1";
constexpr std::size_t kSaltSize = 16;
constexpr std::size_t kHashSize = 32;

std::vector<std::string_view> split(std::string_view s, char sep) {
    std::vector<std::string_view> out;
    std::size_t start = 0;
    while (true) {
        std::size_t p = s.find(sep, start);
        out.push_back(s.substr(start, p == std::string_view::npos ? s.npos : p - start));
        if (p == std::string_view::npos) return out;
        start = p + 1;
    }
}

std::string rolesText(const std::vector<NodeId>& roles) {
    std::string out;
    for (const auto& r : roles) {
        if (!out.empty()) out += ',';
        out += roleName(r);
    }
    return out;
}

void checkRoles(const std::vector<NodeId>& roles) {
    if (roles.size() > UserStore::kMaxRolesPerUser) throw UserStoreError("too many roles");
    for (const auto& r : roles) {
        std::string text = roleName(r);
        if (text.find_first_of(":,\n") != std::string::npos)
            throw UserStoreError("role " + text + " cannot be stored (':' or ',' in its NodeId)");
    }
}

std::vector<NodeId> parseRoles(std::string_view text) {
    std::vector<NodeId> roles;
    if (text.empty()) return roles;
    for (auto part : split(text, ',')) {
        auto r = parseRole(part);
        if (!r) throw UserStoreError("unknown role '" + std::string(part) + "'");
        if (std::find(roles.begin(), roles.end(), *r) == roles.end()) roles.push_back(*r);
    }
    if (roles.size() > UserStore::kMaxRolesPerUser) throw UserStoreError("too many roles");
    return roles;
}

bool validThumbprint(std::string_view s) {
    return s.size() == 40 && std::all_of(s.begin(), s.end(), [](char c) {
               return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f');
           });
}

std::vector<std::uint8_t> fromBase64(std::string_view s, std::size_t expected, const char* what) {
    auto b = ByteString::fromBase64(s);
    if (!b || b->size() != expected)
        throw UserStoreError(std::string("bad ") + what + " (base64 of " +
                             std::to_string(expected) + " bytes expected)");
    return {b->begin(), b->end()};
}

std::string toBase64(const std::vector<std::uint8_t>& b) {
    return ByteString(std::string(b.begin(), b.end())).toBase64();
}

void checkPassword(std::string_view password) {
    if (password.empty()) throw UserStoreError("empty password");
    if (password.size() > UserStore::kMaxPasswordLength) throw UserStoreError("password too long");
}

void checkIterations(unsigned iterations) {
    if (iterations < UserStore::kMinIterations || iterations > UserStore::kMaxIterations)
        throw UserStoreError("iterations must be " + std::to_string(UserStore::kMinIterations) +
                             " .. " + std::to_string(UserStore::kMaxIterations));
}

void hashInto(UserRecord& u, std::string_view password, unsigned iterations) {
    checkPassword(password);
    checkIterations(iterations);
    u.iterations = iterations;
    u.salt = crypto::randomBytes(kSaltSize);
    u.hash = crypto::pbkdf2Sha256(password, u.salt, iterations, kHashSize);
}

UserRecord parseLine(std::string_view line) {
    auto f = split(line, ':');
    if (f.size() < 3) throw UserStoreError("expected NAME:ROLES:KIND:...");
    UserRecord u;
    u.name = std::string(f[0]);
    if (!UserStore::validName(u.name))
        throw UserStoreError("bad user name '" + u.name + "' (1..64 of A-Z a-z 0-9 . _ @ -)");
    u.roles = parseRoles(f[1]);
    if (f[2] == kPbkdf2) {
        if (f.size() != 6)
            throw UserStoreError("expected NAME:ROLES:pbkdf2-sha256:ITERATIONS:SALT:HASH");
        const std::string it(f[3]);
        if (it.empty() || it.size() > 8 || !std::all_of(it.begin(), it.end(), ::isdigit))
            throw UserStoreError("bad iteration count '" + it + "'");
        u.iterations = static_cast<unsigned>(std::stoul(it));
        checkIterations(u.iterations);
        u.salt = fromBase64(f[4], kSaltSize, "salt");
        u.hash = fromBase64(f[5], kHashSize, "hash");
    } else if (f[2] == kX509) {
        if (f.size() != 4) throw UserStoreError("expected NAME:ROLES:x509-sha1:THUMBPRINT");
        if (!validThumbprint(f[3]))
            throw UserStoreError("bad thumbprint (40 lower-case hex digits expected)");
        u.thumbprint = std::string(f[3]);
    } else {
        throw UserStoreError("unknown kind '" + std::string(f[2]) +
                             "' (pbkdf2-sha256 or x509-sha1)");
    }
    return u;
}
}  // namespace

bool UserStore::validName(std::string_view name) {
    return !name.empty() && name.size() <= 64 && std::all_of(name.begin(), name.end(), [](char c) {
        return std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '_' || c == '@' ||
               c == '-';
    });
}

std::string UserStore::defaultPath() {
    if (const char* p = std::getenv("PNP_USERS"); p && *p) return p;
    std::string base;
    if (const char* x = std::getenv("XDG_DATA_HOME"); x && *x)
        base = x;
    else if (const char* h = std::getenv("HOME"); h && *h)
        base = std::string(h) + "/.local/share";
    else
        base = ".";
    return base + "/pnp/users";
}

UserStore UserStore::parse(std::string_view text, const std::string& fileName) {
    UserStore store;
    std::size_t lineNo = 0;
    std::size_t pos = 0;
    while (pos < text.size()) {
        std::size_t end = text.find('\n', pos);
        if (end == std::string_view::npos) end = text.size();
        std::string_view line = text.substr(pos, end - pos);
        pos = end + 1;
        ++lineNo;
        auto fail = [&](const std::string& what) {
            throw UserStoreError(fileName + ":" + std::to_string(lineNo) + ": " + what);
        };
        if (line.size() > kMaxLineLength) fail("line too long");
        if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
        if (line.empty() || line.front() == '#') continue;
        try {
            UserRecord u = parseLine(line);
            if (store.find(u.name)) fail("user '" + u.name + "' listed twice");
            if (u.isCertificateUser() && store.findByThumbprint(u.thumbprint))
                fail("certificate " + u.thumbprint + " listed twice");
            if (store.users_.size() >= kMaxUsers) fail("too many users");
            store.users_.push_back(std::move(u));
        } catch (const UserStoreError& e) {
            if (std::string_view(e.what()).starts_with(fileName + ":")) throw;
            fail(e.what());
        }
    }
    return store;
}

UserStore UserStore::load(const std::string& path) {
    std::error_code ec;
    auto size = std::filesystem::file_size(path, ec);
    if (ec) throw UserStoreError(path + ": " + ec.message());
    if (size > kMaxFileSize) throw UserStoreError(path + ": file too large");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw UserStoreError(path + ": cannot open: " + std::strerror(errno));
    std::string text(static_cast<std::size_t>(size), '\0');
    in.read(text.data(), static_cast<std::streamsize>(size));
    if (static_cast<std::size_t>(in.gcount()) != size) throw UserStoreError(path + ": read error");
    return parse(text, path);
}

std::string UserStore::serialize() const {
    std::string out = "# pnp users (pnp user ...): NAME:ROLES:pbkdf2-sha256:ITERATIONS:SALT:HASH\n";
    for (const auto& u : users_) {
        out += u.name + ":" + rolesText(u.roles) + ":";
        if (u.isCertificateUser())
            out += std::string(kX509) + ":" + u.thumbprint;
        else
            out += std::string(kPbkdf2) + ":" + std::to_string(u.iterations) + ":" +
                   toBase64(u.salt) + ":" + toBase64(u.hash);
        out += '\n';
    }
    return out;
}

void UserStore::save(const std::string& path) const {
    const std::filesystem::path p(path);
    std::error_code ec;
    if (p.has_parent_path()) std::filesystem::create_directories(p.parent_path(), ec);
    if (ec) throw UserStoreError(path + ": cannot create its folder: " + ec.message());
    const std::string tmp = path + ".tmp";
    ::unlink(tmp.c_str());
    int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
    if (fd < 0) throw UserStoreError(tmp + ": cannot create: " + std::strerror(errno));
    const std::string text = serialize();
    std::size_t done = 0;
    while (done < text.size()) {
        ssize_t n = ::write(fd, text.data() + done, text.size() - done);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) {
            int err = errno;
            ::close(fd);
            ::unlink(tmp.c_str());
            throw UserStoreError(tmp + ": write failed: " + std::strerror(err));
        }
        done += static_cast<std::size_t>(n);
    }
    if (::fsync(fd) != 0 || ::close(fd) != 0) {
        ::unlink(tmp.c_str());
        throw UserStoreError(tmp + ": write failed: " + std::strerror(errno));
    }
    if (::rename(tmp.c_str(), path.c_str()) != 0) {
        int err = errno;
        ::unlink(tmp.c_str());
        throw UserStoreError(path + ": cannot replace: " + std::strerror(err));
    }
}

void UserStore::addUser(const std::string& name, std::string_view password,
                        std::vector<NodeId> roles, unsigned iterations) {
    if (!validName(name)) throw UserStoreError("bad user name '" + name + "'");
    if (find(name)) throw UserStoreError("user '" + name + "' exists");
    if (users_.size() >= kMaxUsers) throw UserStoreError("too many users");
    checkRoles(roles);
    UserRecord u;
    u.name = name;
    u.roles = std::move(roles);
    hashInto(u, password, iterations);
    users_.push_back(std::move(u));
}

void UserStore::addCertificateUser(const std::string& name, const std::string& thumbprintHex,
                                   std::vector<NodeId> roles) {
    if (!validName(name)) throw UserStoreError("bad user name '" + name + "'");
    if (find(name)) throw UserStoreError("user '" + name + "' exists");
    std::string t = thumbprintHex;
    std::transform(t.begin(), t.end(), t.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (!validThumbprint(t)) throw UserStoreError("bad thumbprint (40 hex digits expected)");
    if (findByThumbprint(t)) throw UserStoreError("certificate " + t + " belongs to a user");
    if (users_.size() >= kMaxUsers) throw UserStoreError("too many users");
    checkRoles(roles);
    UserRecord u;
    u.name = name;
    u.roles = std::move(roles);
    u.thumbprint = std::move(t);
    users_.push_back(std::move(u));
}

void UserStore::setPassword(const std::string& name, std::string_view password,
                            unsigned iterations) {
    auto it = std::find_if(users_.begin(), users_.end(), [&](auto& u) { return u.name == name; });
    if (it == users_.end()) throw UserStoreError("no user '" + name + "'");
    if (it->isCertificateUser())
        throw UserStoreError("user '" + name + "' logs in with a certificate");
    hashInto(*it, password, iterations);
}

void UserStore::setRoles(const std::string& name, std::vector<NodeId> roles) {
    auto it = std::find_if(users_.begin(), users_.end(), [&](auto& u) { return u.name == name; });
    if (it == users_.end()) throw UserStoreError("no user '" + name + "'");
    checkRoles(roles);
    it->roles = std::move(roles);
}

bool UserStore::remove(const std::string& name) {
    return std::erase_if(users_, [&](const UserRecord& u) { return u.name == name; }) != 0;
}

const UserRecord* UserStore::find(std::string_view name) const {
    for (const auto& u : users_)
        if (u.name == name) return &u;
    return nullptr;
}

const UserRecord* UserStore::findByThumbprint(std::string_view thumbprintHex) const {
    for (const auto& u : users_)
        if (u.isCertificateUser() && u.thumbprint == thumbprintHex) return &u;
    return nullptr;
}

bool UserStore::hasPasswordUsers() const {
    return std::any_of(users_.begin(), users_.end(),
                       [](const UserRecord& u) { return !u.isCertificateUser(); });
}

bool UserStore::hasCertificateUsers() const {
    return std::any_of(users_.begin(), users_.end(),
                       [](const UserRecord& u) { return u.isCertificateUser(); });
}

const UserRecord* UserStore::verifyPassword(std::string_view name,
                                            std::string_view password) const {
    const UserRecord* user = find(name);
    if (user && user->isCertificateUser()) user = nullptr;
    // An unknown user costs the same hash as a known one (iterations of a real user).
    static const std::vector<std::uint8_t> dummySalt(kSaltSize, 0x5a);
    static const std::vector<std::uint8_t> dummyHash(kHashSize, 0);
    unsigned iterations = kDefaultIterations;
    if (user) {
        iterations = user->iterations;
    } else {
        for (const auto& u : users_)
            if (!u.isCertificateUser()) {
                iterations = u.iterations;
                break;
            }
    }
    const bool tooLong = password.size() > kMaxPasswordLength;
    if (tooLong) password = password.substr(0, kMaxPasswordLength);
    const auto& salt = user ? user->salt : dummySalt;
    const auto& expected = user ? user->hash : dummyHash;
    const auto actual = crypto::pbkdf2Sha256(password, salt, iterations, kHashSize);
    const bool same = crypto::constantTimeEqual(actual, expected);
    return (same && user && !tooLong) ? user : nullptr;
}

}  // namespace pnp::ua::server
