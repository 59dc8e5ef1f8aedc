// The users of a server: names with salted PBKDF2-HMAC-SHA256 password hashes, X.509 users
// by certificate thumbprint, and the roles each one gets (ua/server/roles.hpp). Never holds
// or writes a plain password.
//
// File format (line-based text, mode 0600; '#' starts a comment line):
//   NAME:ROLES:pbkdf2-sha256:ITERATIONS:SALT_BASE64:HASH_BASE64
//   NAME:ROLES:x509-sha1:THUMBPRINT_HEX
// ROLES: comma-separated well-known role names (Operator, SecurityAdmin, ...) or numeric
// role NodeIds ("ns=2;i=7"); may be empty. NAME: 1..64 of [A-Za-z0-9._@-].
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "ua/types/builtin.hpp"

namespace pnp::ua::server {

class UserStoreError : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

struct UserRecord {
    std::string name;
    std::vector<NodeId> roles;
    // Password users.
    unsigned iterations = 0;
    std::vector<std::uint8_t> salt;  // 16 random bytes
    std::vector<std::uint8_t> hash;  // 32 bytes
    // Certificate users: SHA-1 of the certificate's DER, lower-case hex (40 characters).
    std::string thumbprint;
    bool isCertificateUser() const { return !thumbprint.empty(); }
};

class UserStore {
  public:
    static constexpr unsigned kDefaultIterations = 100'000;
    static constexpr unsigned kMinIterations = 1'000;  // below: refused (tests use few)
    static constexpr unsigned kMaxIterations = 10'000'000;
    static constexpr std::size_t kMaxUsers = 10'000;
    static constexpr std::size_t kMaxLineLength = 4096;
    static constexpr std::size_t kMaxFileSize = kMaxUsers * 256;
    static constexpr std::size_t kMaxPasswordLength = 1024;
    static constexpr std::size_t kMaxRolesPerUser = 32;

    // $PNP_USERS, else ${XDG_DATA_HOME:-$HOME/.local/share}/pnp/users.
    static std::string defaultPath();

    // Throws UserStoreError "FILE:LINE: what is wrong" (or "FILE: ..." for the file itself).
    static UserStore load(const std::string& path);
    static UserStore parse(std::string_view text, const std::string& fileName = "users");
    // Writes the file with mode 0600 (a new file replaces the old one atomically).
    void save(const std::string& path) const;
    std::string serialize() const;

    // Throw UserStoreError for a bad name, an existing user, a bad role list ...
    void addUser(const std::string& name, std::string_view password, std::vector<NodeId> roles,
                 unsigned iterations = kDefaultIterations);
    void addCertificateUser(const std::string& name, const std::string& thumbprintHex,
                            std::vector<NodeId> roles);
    void setPassword(const std::string& name, std::string_view password,
                     unsigned iterations = kDefaultIterations);
    void setRoles(const std::string& name, std::vector<NodeId> roles);
    bool remove(const std::string& name);

    const UserRecord* find(std::string_view name) const;
    const UserRecord* findByThumbprint(std::string_view thumbprintHex) const;
    const std::vector<UserRecord>& users() const { return users_; }
    bool empty() const { return users_.empty(); }
    bool hasPasswordUsers() const;
    bool hasCertificateUsers() const;

    // The password user `name` if `password` is right, else null. Takes the same time whether
    // or not the user exists (a dummy hash is computed for unknown names) and compares in
    // constant time.
    const UserRecord* verifyPassword(std::string_view name, std::string_view password) const;

    static bool validName(std::string_view name);

  private:
    std::vector<UserRecord> users_;
};

}  // namespace pnp::ua::server
