// A pseudo-terminal pair standing in for a serial line: the simulator keeps the master side,
// the adapter opens the slave's path as it would /dev/ttyUSB0.
#include <fcntl.h>
#include <stdlib.h>
#include <termios.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <system_error>

#include "modbus/modbus.hpp"

namespace pnp::modbus {

namespace {

[[noreturn]] void fail(const char* what) {
    throw std::system_error(errno, std::generic_category(), what);
}

}  // namespace

PseudoTerminal::PseudoTerminal() {
    master_ = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
    if (master_ < 0) fail("posix_openpt");
    try {
        if (grantpt(master_) != 0) fail("grantpt");
        if (unlockpt(master_) != 0) fail("unlockpt");
        std::array<char, 128> name{};
        if (const int e = ptsname_r(master_, name.data(), name.size()); e != 0) {
            errno = e;
            fail("ptsname_r");
        }
        path_ = name.data();
        // Held open for the simulator's lifetime: without any slave fd open the master reads
        // EIO (hang-up) between two adapters, and the line settings would be forgotten.
        slaveKeepAlive_ = ::open(path_.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
        if (slaveKeepAlive_ < 0) fail("open pty slave");
        // Raw bytes both ways: no echo, no line editing, no CR/LF translation, 8 bits.
        termios tio{};
        if (tcgetattr(slaveKeepAlive_, &tio) != 0) fail("tcgetattr");
        cfmakeraw(&tio);
        cfsetispeed(&tio, B115200);
        cfsetospeed(&tio, B115200);
        if (tcsetattr(slaveKeepAlive_, TCSANOW, &tio) != 0) fail("tcsetattr");
        const int flags = fcntl(master_, F_GETFL);
        if (flags < 0 || fcntl(master_, F_SETFL, flags | O_NONBLOCK) < 0) fail("fcntl");
    } catch (...) {
        if (slaveKeepAlive_ >= 0) ::close(slaveKeepAlive_);
        ::close(master_);
        throw;
    }
}

PseudoTerminal::~PseudoTerminal() {
    if (slaveKeepAlive_ >= 0) ::close(slaveKeepAlive_);
    if (master_ >= 0) ::close(master_);
}

int PseudoTerminal::masterFd() const { return master_; }

const std::string& PseudoTerminal::path() const { return path_; }

}  // namespace pnp::modbus
