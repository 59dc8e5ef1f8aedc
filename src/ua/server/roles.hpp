// Roles and permissions (OPC 10000-3 §4.9 and §5.2.9 RolePermissions / UserRolePermissions,
// §8.55 PermissionType; OPC 10000-18 well-known roles).
//
// A session holds roles (SessionIdentity::roles, granted by AccessControl::activateSession);
// a node's effective permissions are its RolePermissions if it has them, else the
// DefaultRolePermissions of its namespace, else the server-wide default. With nothing
// configured every session may do everything (the address space then checks nothing at all,
// so the default costs nothing). The checks are made by the address-space services, which
// take the calling session's identity (AddressSpace::read(request, &identity) & co.).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "ua/types/builtin.hpp"
#include "ua/types/ns0_types_model.hpp"

namespace pnp::ua::server {

// PermissionType bits (OPC 10000-3 §8.55).
namespace permission {
inline constexpr UInt32 Browse = 1u << 0;
inline constexpr UInt32 ReadRolePermissions = 1u << 1;
inline constexpr UInt32 WriteAttribute = 1u << 2;
inline constexpr UInt32 WriteRolePermissions = 1u << 3;
inline constexpr UInt32 WriteHistorizing = 1u << 4;
inline constexpr UInt32 Read = 1u << 5;
inline constexpr UInt32 Write = 1u << 6;
inline constexpr UInt32 ReadHistory = 1u << 7;
inline constexpr UInt32 InsertHistory = 1u << 8;
inline constexpr UInt32 ModifyHistory = 1u << 9;
inline constexpr UInt32 DeleteHistory = 1u << 10;
inline constexpr UInt32 ReceiveEvents = 1u << 11;
inline constexpr UInt32 Call = 1u << 12;
inline constexpr UInt32 AddReference = 1u << 13;
inline constexpr UInt32 RemoveReference = 1u << 14;
inline constexpr UInt32 DeleteNode = 1u << 15;
inline constexpr UInt32 AddNode = 1u << 16;
inline constexpr UInt32 All = (1u << 17) - 1;
}  // namespace permission

// The well-known roles of OPC 10000-18 §4.2 (Objects in namespace 0, below
// Server/ServerCapabilities/RoleSet). Their index in kWellKnownRoles is their bit in
// SessionIdentity::roleBits.
struct WellKnownRole {
    std::string_view name;
    UInt32 id;  // ns=0
};
inline constexpr std::array<WellKnownRole, 8> kWellKnownRoles{{
    {"Anonymous", 15644},
    {"AuthenticatedUser", 15656},
    {"Observer", 15668},
    {"Operator", 15680},
    {"Engineer", 16036},
    {"Supervisor", 15692},
    {"ConfigureAdmin", 15716},
    {"SecurityAdmin", 15704},
}};
namespace role {
NodeId anonymous();
NodeId authenticatedUser();
NodeId observer();
NodeId operator_();
NodeId engineer();
NodeId supervisor();
NodeId configureAdmin();
NodeId securityAdmin();
}  // namespace role
// The bit of a well-known role (0..7), -1 for other roles.
int wellKnownRoleBit(const NodeId& role);
// "Operator" (case-insensitive) -> ns=0;i=15680; also "ns=2;i=7"-style NodeIds for other
// roles. nullopt if neither.
std::optional<NodeId> parseRole(std::string_view text);
// The role's name for a well-known role, its NodeId text otherwise.
std::string roleName(const NodeId& role);

// Who a session belongs to, as decided by AccessControl::activateSession.
struct SessionIdentity {
    bool anonymous = true;
    std::string userName;           // or the X.509 user certificate's subject
    std::vector<NodeId> roles;      // granted roles (always Anonymous; AuthenticatedUser for every
                                    // non-anonymous user); change them with grant()
    bool encryptedChannel = false;  // the session's channel is SignAndEncrypt (set by the lead)
    std::uint32_t roleBits = 0;     // the well-known roles among `roles` (bit: wellKnownRoleBit)

    bool hasRole(const NodeId& role) const;
    void grant(const NodeId& role);  // keeps roles and roleBits in step; duplicates ignored
};

// A RolePermissionType[] prepared for evaluation: the permissions of the eight well-known
// roles in an array, other roles in a short list.
class RolePermissionSet {
  public:
    RolePermissionSet() = default;
    explicit RolePermissionSet(std::vector<RolePermissionType> entries);
    const std::vector<RolePermissionType>& entries() const { return entries_; }
    // The permissions of a session holding these roles. Roles whose bit is in
    // `encryptionRequired` count only on an encrypted channel.
    UInt32 permissionsOf(const SessionIdentity& user, std::uint32_t encryptionRequired) const;
    // The entries that apply to the session (the UserRolePermissions attribute).
    std::vector<RolePermissionType> entriesOf(const SessionIdentity& user,
                                              std::uint32_t encryptionRequired) const;

  private:
    std::vector<RolePermissionType> entries_;
    std::array<UInt32, kWellKnownRoles.size()> wellKnown_{};
    std::vector<RolePermissionType> other_;
};

// What AddressSpace keeps for the checks (AddressSpace::setRolePermissions & co.).
struct PermissionDefaults {
    // Server-wide default (nullopt: every session may do everything).
    std::optional<std::vector<RolePermissionType>> serverDefault;
    // Per namespace index (NamespaceMetadata DefaultRolePermissions).
    std::vector<std::pair<UInt16, std::vector<RolePermissionType>>> namespaceDefaults;
    // Per node.
    std::vector<std::pair<NodeId, std::vector<RolePermissionType>>> nodes;
    // Roles that count only on a SignAndEncrypt channel (SessionIdentity::encryptedChannel).
    std::vector<NodeId> encryptionRequired;
};

// The ready-made policy of pnp servers (apply it with AddressSpace::applyPermissions):
//  - everyone (Anonymous, so every session) may browse, read values and role permissions,
//    receive events, and call the standard methods of namespace 0;
//  - Operator, Engineer, Supervisor and ConfigureAdmin may also write values and call methods
//    in every other namespace (skill parameters and skill methods);
//  - Engineer, Supervisor and ConfigureAdmin may also write other attributes there
//    (configuration);
//  - only SecurityAdmin may call the ServerConfiguration methods (UpdateCertificate,
//    CreateSigningRequest, ApplyChanges, GetRejectedList, ...), and SecurityAdmin counts only
//    over a SignAndEncrypt channel.
PermissionDefaults pnpRolePolicy();

}  // namespace pnp::ua::server
