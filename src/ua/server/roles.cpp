#include "ua/server/roles.hpp"

#include <algorithm>
#include <cctype>

namespace pnp::ua::server {

namespace {
NodeId wellKnown(std::size_t bit) { return NodeId(0, kWellKnownRoles[bit].id); }

bool equalsIgnoreCase(std::string_view a, std::string_view b) {
    return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
               return std::tolower(static_cast<unsigned char>(x)) ==
                      std::tolower(static_cast<unsigned char>(y));
           });
}
}  // namespace

namespace role {
NodeId anonymous() { return wellKnown(0); }
NodeId authenticatedUser() { return wellKnown(1); }
NodeId observer() { return wellKnown(2); }
NodeId operator_() { return wellKnown(3); }
NodeId engineer() { return wellKnown(4); }
NodeId supervisor() { return wellKnown(5); }
NodeId configureAdmin() { return wellKnown(6); }
NodeId securityAdmin() { return wellKnown(7); }
}  // namespace role

int wellKnownRoleBit(const NodeId& role) {
    if (role.namespaceIndex() != 0 || !role.isNumeric()) return -1;
    for (std::size_t b = 0; b < kWellKnownRoles.size(); ++b)
        if (kWellKnownRoles[b].id == role.numeric()) return static_cast<int>(b);
    return -1;
}

std::optional<NodeId> parseRole(std::string_view text) {
    for (const auto& r : kWellKnownRoles)
        if (equalsIgnoreCase(r.name, text)) return NodeId(0, r.id);
    if (text.find('=') != std::string_view::npos) return NodeId::parse(text);
    return std::nullopt;
}

std::string roleName(const NodeId& role) {
    int bit = wellKnownRoleBit(role);
    return bit >= 0 ? std::string(kWellKnownRoles[static_cast<std::size_t>(bit)].name)
                    : role.toString();
}

bool SessionIdentity::hasRole(const NodeId& role) const {
    int bit = wellKnownRoleBit(role);
    if (bit >= 0) return ((roleBits >> bit) & 1u) != 0;
    return std::find(roles.begin(), roles.end(), role) != roles.end();
}

void SessionIdentity::grant(const NodeId& role) {
    if (std::find(roles.begin(), roles.end(), role) != roles.end()) return;
    roles.push_back(role);
    int bit = wellKnownRoleBit(role);
    if (bit >= 0) roleBits |= 1u << bit;
}

RolePermissionSet::RolePermissionSet(std::vector<RolePermissionType> entries)
    : entries_(std::move(entries)) {
    for (const auto& e : entries_) {
        int bit = wellKnownRoleBit(e.roleId);
        if (bit >= 0)
            wellKnown_[static_cast<std::size_t>(bit)] |= e.permissions;
        else
            other_.push_back(e);
    }
}

UInt32 RolePermissionSet::permissionsOf(const SessionIdentity& user,
                                        std::uint32_t encryptionRequired) const {
    std::uint32_t bits = user.roleBits;
    if (!user.encryptedChannel) bits &= ~encryptionRequired;
    UInt32 p = 0;
    for (std::size_t b = 0; bits != 0; ++b, bits >>= 1)
        if (bits & 1u) p |= wellKnown_[b];
    for (const auto& e : other_)
        if (user.hasRole(e.roleId)) p |= e.permissions;
    return p;
}

std::vector<RolePermissionType> RolePermissionSet::entriesOf(
    const SessionIdentity& user, std::uint32_t encryptionRequired) const {
    std::vector<RolePermissionType> out;
    for (const auto& e : entries_) {
        int bit = wellKnownRoleBit(e.roleId);
        bool counts = user.hasRole(e.roleId) &&
                      (bit < 0 || user.encryptedChannel || ((encryptionRequired >> bit) & 1u) == 0);
        if (counts) out.push_back(e);
    }
    return out;
}

namespace {
// Entries from (well-known role bit, permissions) pairs (plain numbers: an initializer list of
// NodeIds trips GCC 12's -Wmaybe-uninitialized).
std::vector<RolePermissionType> entries(std::initializer_list<std::pair<std::size_t, UInt32>> l) {
    std::vector<RolePermissionType> out;
    out.reserve(l.size());
    for (const auto& [bit, p] : l) {
        RolePermissionType e;
        e.roleId = wellKnown(bit);
        e.permissions = p;
        out.push_back(std::move(e));
    }
    return out;
}
}  // namespace

PermissionDefaults pnpRolePolicy() {
    using namespace permission;
    constexpr UInt32 observe = Browse | ReadRolePermissions | Read | ReceiveEvents | ReadHistory;
    constexpr UInt32 operate = observe | Write | Call;
    constexpr UInt32 configure = operate | WriteAttribute | WriteHistorizing;
    // Bits of kWellKnownRoles.
    enum : std::size_t {
        Anonymous,
        AuthenticatedUser,
        Observer,
        Operator,
        Engineer,
        Supervisor,
        ConfigureAdmin,
        SecurityAdmin
    };

    PermissionDefaults d;
    // Every namespace but 0: the skills and the devices' models.
    d.serverDefault = entries({{Anonymous, observe},
                               {AuthenticatedUser, observe},
                               {Observer, observe},
                               {Operator, operate},
                               {Engineer, configure},
                               {Supervisor, configure},
                               {ConfigureAdmin, configure},
                               {SecurityAdmin, observe}});
    // Namespace 0: the standard Server object's methods (GetMonitoredItems, ResendData,
    // ConditionRefresh, ...) are for every client.
    d.namespaceDefaults.emplace_back(
        0, entries({{Anonymous, observe | Call}, {AuthenticatedUser, observe | Call}}));
    // Certificate management (OPC 10000-12 §7.10): SecurityAdmin only, encrypted channel only.
    const auto admin = entries(
        {{Anonymous, observe}, {AuthenticatedUser, observe}, {SecurityAdmin, observe | Call}});
    for (UInt32 method : {
             13737u,  // ServerConfiguration.UpdateCertificate
             12737u,  // CreateSigningRequest
             12740u,  // ApplyChanges
             12777u,  // GetRejectedList
             25708u,  // CancelChanges
             25709u,  // ResetToServerDefaults
             // DefaultApplicationGroup.TrustList: Open .. RemoveCertificate
             12647u,
             12650u,
             12652u,
             12655u,
             12657u,
             12660u,
             12663u,
             12666u,
             12668u,
             12670u,
             // DefaultUserTokenGroup.TrustList
             14129u,
             14132u,
             14134u,
             14137u,
             14139u,
             14142u,
             14145u,
             14148u,
             14151u,
             14153u,
         }) {
        std::pair<NodeId, std::vector<RolePermissionType>> rule;
        rule.first = NodeId(0, method);
        rule.second = admin;
        d.nodes.push_back(std::move(rule));
    }
    d.encryptionRequired.push_back(wellKnown(SecurityAdmin));
    return d;
}

}  // namespace pnp::ua::server
