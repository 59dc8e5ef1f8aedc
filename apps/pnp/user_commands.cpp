// The users of a pnp server on the command line (src/ua/server/user_store.hpp):
//   pnp user [--users FILE] add NAME --role Operator [--role ...] [--password-stdin]
//   pnp user [--users FILE] remove NAME | list | passwd NAME [--password-stdin] |
//            roles NAME --role ... | roles (the well-known roles)
// FILE defaults to $PNP_USERS, else ${XDG_DATA_HOME:-$HOME/.local/share}/pnp/users. A
// password is read from stdin (--password-stdin, one line) or prompted for without echo;
// it is never printed, logged or stored (only its PBKDF2 hash).
#include <termios.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <filesystem>
#include <functional>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "commands.hpp"
#include "output.hpp"
#include "ua/pki/pki.hpp"
#include "ua/server/roles.hpp"
#include "ua/server/user_store.hpp"

namespace pnp::cli {

namespace {

struct UserCliOptions {
    std::string file;
    std::string name;
    std::vector<std::string> roles;
    bool passwordStdin = false;
    std::string cert;  // add --cert: an X.509 user, known by its certificate's thumbprint
    unsigned iterations = ua::server::UserStore::kDefaultIterations;
};

// One line from stdin, or a prompt on the terminal without echo.
std::string readPassword(bool fromStdin, const char* prompt) {
    std::string line;
    if (fromStdin || !::isatty(STDIN_FILENO)) {
        if (!std::getline(std::cin, line)) throw std::runtime_error("no password on stdin");
        if (!line.empty() && line.back() == '\r') line.pop_back();
        return line;
    }
    termios old{};
    ::tcgetattr(STDIN_FILENO, &old);
    termios quiet = old;
    quiet.c_lflag &= ~static_cast<tcflag_t>(ECHO);
    std::cerr << prompt << std::flush;
    ::tcsetattr(STDIN_FILENO, TCSANOW, &quiet);
    std::getline(std::cin, line);
    ::tcsetattr(STDIN_FILENO, TCSANOW, &old);
    std::cerr << "\n";
    return line;
}

std::string newPassword(bool fromStdin) {
    std::string a = readPassword(fromStdin, "password: ");
    if (!fromStdin && ::isatty(STDIN_FILENO)) {
        std::string b = readPassword(false, "again: ");
        if (a != b) throw std::runtime_error("the passwords differ");
    }
    return a;
}

std::vector<ua::NodeId> parseRoles(const std::vector<std::string>& names) {
    std::vector<ua::NodeId> out;
    for (const auto& n : names) {
        auto r = ua::server::parseRole(n);
        if (!r) throw std::runtime_error("unknown role '" + n + "' (see `pnp user roles`)");
        out.push_back(*r);
    }
    return out;
}

ua::server::UserStore loadOrEmpty(const std::string& file) {
    if (!std::filesystem::exists(file)) return {};
    return ua::server::UserStore::load(file);
}

std::string rolesOf(const ua::server::UserRecord& u) {
    std::string s;
    for (const auto& r : u.roles) s += (s.empty() ? "" : ",") + ua::server::roleName(r);
    return s.empty() ? "-" : s;
}

}  // namespace

std::function<int()> addUserCommands(CLI::App& app) {
    auto o = std::make_shared<UserCliOptions>();
    auto* cmd =
        app.add_subcommand("user", "the users of a pnp server (names, password hashes, roles)");
    cmd->add_option("--users", o->file,
                    "the user file (default: $PNP_USERS or ~/.local/share/pnp/users)");
    cmd->require_subcommand(1);
    auto* add = cmd->add_subcommand("add", "add a user with a password, or --cert: an X.509 user");
    add->add_option("name", o->name, "user name (A-Z a-z 0-9 . _ @ -)")->required();
    add->add_option("--role", o->roles, "a role (Observer, Operator, Engineer, ...); repeatable");
    add->add_flag("--password-stdin", o->passwordStdin, "read the password from stdin");
    add->add_option("--cert", o->cert,
                    "the user's X.509 certificate (DER or PEM): no password, the user signs "
                    "with the certificate's key");
    add->add_option("--iterations", o->iterations, "PBKDF2 iterations")->capture_default_str();
    auto* remove = cmd->add_subcommand("remove", "remove a user");
    remove->add_option("name", o->name)->required();
    auto* list = cmd->add_subcommand("list", "list the users and their roles");
    auto* passwd = cmd->add_subcommand("passwd", "set a user's password");
    passwd->add_option("name", o->name)->required();
    passwd->add_flag("--password-stdin", o->passwordStdin, "read the password from stdin");
    passwd->add_option("--iterations", o->iterations, "PBKDF2 iterations")->capture_default_str();
    auto* roles = cmd->add_subcommand(
        "roles", "set a user's roles (with NAME and --role), or list the well-known roles");
    roles->add_option("name", o->name);
    roles->add_option("--role", o->roles, "a role; repeatable (none: no extra role)");

    return [=]() -> int {
        if (!*cmd) return -1;
        const std::string file = o->file.empty() ? ua::server::UserStore::defaultPath() : o->file;
        try {
            if (*roles && o->name.empty()) {
                for (const auto& r : ua::server::kWellKnownRoles)
                    std::cout << r.name << "\tns=0;i=" << r.id << "\n";
                return kExitOk;
            }
            auto store = loadOrEmpty(file);
            if (*list) {
                for (const auto& u : store.users())
                    std::cout << u.name << "\t" << rolesOf(u) << "\t"
                              << (u.isCertificateUser() ? "x509 " + u.thumbprint : "password")
                              << "\n";
                return kExitOk;
            }
            if (*add) {
                if (store.find(o->name)) throw std::runtime_error("user '" + o->name + "' exists");
                if (!o->cert.empty())
                    store.addCertificateUser(o->name,
                                             ua::pki::Certificate::load(o->cert).thumbprintHex(),
                                             parseRoles(o->roles));
                else
                    store.addUser(o->name, newPassword(o->passwordStdin), parseRoles(o->roles),
                                  o->iterations);
            } else if (*passwd) {
                if (!store.find(o->name)) throw std::runtime_error("no user '" + o->name + "'");
                store.setPassword(o->name, newPassword(o->passwordStdin), o->iterations);
            } else if (*remove) {
                if (!store.remove(o->name)) throw std::runtime_error("no user '" + o->name + "'");
            } else if (*roles) {
                store.setRoles(o->name, parseRoles(o->roles));
            }
            store.save(file);
            std::cerr << "pnp user: " << file << " updated\n";
            return kExitOk;
        } catch (const std::exception& e) {
            std::cerr << "error: " << e.what() << "\n";
            return kExitUsage;
        }
    };
}

}  // namespace pnp::cli
