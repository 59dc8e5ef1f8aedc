// The transports against an independent master: libmodbus (Debian's) over a pseudo-terminal
// (RtuSlave) and over loopback TCP (TcpServer), plus raw bytes for what libmodbus never sends.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <modbus.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <memory>
#include <thread>

#include "modbus_helpers.hpp"

namespace pnp::modbus::test {
namespace {

using namespace std::chrono_literals;

struct ModbusDeleter {
    void operator()(modbus_t* ctx) const {
        modbus_close(ctx);
        modbus_free(ctx);
    }
};
using Context = std::unique_ptr<modbus_t, ModbusDeleter>;

Context rtuMaster(const std::string& path, int slave) {
    Context ctx(modbus_new_rtu(path.c_str(), 115200, 'N', 8, 1));
    if (!ctx) return ctx;
    modbus_set_slave(ctx.get(), slave);
    modbus_set_response_timeout(ctx.get(), 1, 0);
    if (modbus_connect(ctx.get()) != 0) {
        ADD_FAILURE() << "modbus_connect " << path << ": " << modbus_strerror(errno);
        return nullptr;
    }
    return ctx;
}

Context tcpMaster(std::uint16_t port, int unit) {
    Context ctx(modbus_new_tcp("127.0.0.1", port));
    if (!ctx) return ctx;
    modbus_set_slave(ctx.get(), unit);
    modbus_set_response_timeout(ctx.get(), 1, 0);
    if (modbus_connect(ctx.get()) != 0) {
        ADD_FAILURE() << "modbus_connect 127.0.0.1:" << port << ": " << modbus_strerror(errno);
        return nullptr;
    }
    return ctx;
}

// --- RTU on a pseudo-terminal

struct RtuFixture : ::testing::Test {
    PseudoTerminal pty;
    MemoryRegisters registers;
    RtuSlave slave{pty.masterFd(), RtuSlaveConfig{9, 115200}, registers};
    void SetUp() override { slave.start(); }
};

TEST_F(RtuFixture, PathIsAPseudoTerminal) {
    EXPECT_EQ(pty.path().rfind("/dev/pts/", 0), 0u) << pty.path();
    EXPECT_GE(pty.masterFd(), 0);
}

TEST_F(RtuFixture, LibmodbusReadsAndWrites) {
    Context ctx = rtuMaster(pty.path(), 9);
    ASSERT_TRUE(ctx);
    const std::uint16_t values[3] = {0x0102, 0x0304, 0xFFFF};
    ASSERT_EQ(modbus_write_registers(ctx.get(), 0x10, 3, values), 3) << modbus_strerror(errno);
    std::uint16_t back[3] = {};
    ASSERT_EQ(modbus_read_registers(ctx.get(), 0x10, 3, back), 3) << modbus_strerror(errno);
    EXPECT_EQ(back[0], 0x0102);
    EXPECT_EQ(back[1], 0x0304);
    EXPECT_EQ(back[2], 0xFFFF);
    ASSERT_EQ(modbus_write_register(ctx.get(), 0x05, 0x1234), 1) << modbus_strerror(errno);
    EXPECT_EQ(registers.holding(0x05), 0x1234);
    std::uint16_t input[4] = {};
    ASSERT_EQ(modbus_read_input_registers(ctx.get(), 0x1002, 4, input), 4);
    EXPECT_EQ(input[0], 0xA002);
    EXPECT_EQ(input[3], 0xA005);
    const std::uint16_t write[1] = {0x7777};
    std::uint16_t read[2] = {};
    ASSERT_EQ(modbus_write_and_read_registers(ctx.get(), 0x40, 1, write, 0x40, 2, read), 2)
        << modbus_strerror(errno);
    EXPECT_EQ(read[0], 0x7777);
    EXPECT_EQ(slave.stats().frames, 5u);
}

TEST_F(RtuFixture, LibmodbusSeesExceptions) {
    Context ctx = rtuMaster(pty.path(), 9);
    ASSERT_TRUE(ctx);
    std::uint16_t value = 0;
    EXPECT_EQ(modbus_read_registers(ctx.get(), 0x0200, 1, &value), -1);
    EXPECT_EQ(errno, EMBXILADD);
    EXPECT_EQ(modbus_read_input_registers(ctx.get(), 0x0000, 1, &value), -1);
    EXPECT_EQ(errno, EMBXILADD);
    EXPECT_EQ(modbus_write_register(ctx.get(), 0, 0xDEAD), -1);
    EXPECT_EQ(errno, EMBXILVAL);
    EXPECT_EQ(modbus_write_register(ctx.get(), 0, 0xFA11), -1);
    EXPECT_EQ(errno, EMBXSFAIL);
    // Coils: not a function of a register device.
    std::uint8_t bits[1] = {};
    EXPECT_EQ(modbus_read_bits(ctx.get(), 0, 1, bits), -1);
    EXPECT_EQ(errno, EMBXILFUN);
    // Still served afterwards.
    EXPECT_EQ(modbus_read_registers(ctx.get(), 0, 1, &value), 1);
}

TEST_F(RtuFixture, WrongSlaveAndUnansweringDeviceTimeOut) {
    Context other = rtuMaster(pty.path(), 10);
    ASSERT_TRUE(other);
    modbus_set_response_timeout(other.get(), 0, 200000);
    std::uint16_t value = 0;
    EXPECT_EQ(modbus_read_registers(other.get(), 0, 1, &value), -1);
    EXPECT_EQ(errno, ETIMEDOUT);
    other.reset();

    Context ctx = rtuMaster(pty.path(), 9);
    ASSERT_TRUE(ctx);
    modbus_set_response_timeout(ctx.get(), 0, 200000);
    registers.on = false;
    EXPECT_EQ(modbus_read_registers(ctx.get(), 0, 1, &value), -1);
    EXPECT_EQ(errno, ETIMEDOUT);
    registers.on = true;
    EXPECT_EQ(modbus_read_registers(ctx.get(), 0, 1, &value), 1) << modbus_strerror(errno);
    const RtuStats s = slave.stats();
    EXPECT_EQ(s.otherSlave, 1u);
    EXPECT_EQ(s.notAnswering, 1u);
}

TEST_F(RtuFixture, RawFramesBadCrcAndBroadcast) {
    SerialPeer peer(pty.path());
    ASSERT_TRUE(peer.ok());
    Bytes bad = rtuFrame(9, fromHex("03 00 00 00 01"));
    bad[6] ^= 0xFF;
    EXPECT_TRUE(peer.exchange(bad, 7, 150ms).empty());
    EXPECT_TRUE(peer.exchange(rtuFrame(0, fromHex("06 00 08 00 63")), 8, 150ms).empty());
    EXPECT_EQ(registers.holding(8), 0x63);
    // (Slices of one frame are tested with explicit times in rtu_test.cpp: over a pty, a
    // preempted writer may leave a real gap > t3.5 between two writes, which ends a frame.)
    ASSERT_TRUE(peer.write(rtuFrame(9, fromHex("03 00 08 00 01"))));
    EXPECT_EQ(toHex(peer.read(7, 1000ms)), toHex(rtuFrame(9, fromHex("03 02 00 63"))));
    const RtuStats s = slave.stats();
    EXPECT_EQ(s.badCrc, 1u);
    EXPECT_EQ(s.broadcasts, 1u);
    EXPECT_EQ(s.frames, 1u);
}

TEST_F(RtuFixture, StopsPromptlyAndRestarts) {
    const auto begin = std::chrono::steady_clock::now();
    slave.stop();
    EXPECT_LT(std::chrono::steady_clock::now() - begin, 500ms);
    slave.start();
    Context ctx = rtuMaster(pty.path(), 9);
    ASSERT_TRUE(ctx);
    std::uint16_t value = 0;
    EXPECT_EQ(modbus_read_registers(ctx.get(), 0, 1, &value), 1) << modbus_strerror(errno);
}

// --- TCP on loopback

// A raw TCP client for what libmodbus never sends.
class RawClient {
  public:
    explicit RawClient(std::uint16_t port) {
        fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(port);
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
    }
    ~RawClient() { ::close(fd_); }
    RawClient(const RawClient&) = delete;
    RawClient& operator=(const RawClient&) = delete;
    bool connected() const { return connected_; }
    bool send(const Bytes& b) {
        return ::send(fd_, b.data(), b.size(), MSG_NOSIGNAL) == static_cast<ssize_t>(b.size());
    }
    // Up to `count` bytes within `timeout`; `closed` says whether the server closed.
    Bytes receive(std::size_t count, std::chrono::milliseconds timeout, bool* closed = nullptr) {
        Bytes out;
        const auto end = std::chrono::steady_clock::now() + timeout;
        for (int i = 0; i < 1000 && out.size() < count; ++i) {
            const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                end - std::chrono::steady_clock::now());
            if (left.count() <= 0) break;
            pollfd p{fd_, POLLIN, 0};
            if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) break;
            std::array<std::uint8_t, 512> buffer{};
            const ssize_t got =
                ::recv(fd_, buffer.data(), std::min(buffer.size(), count - out.size()), 0);
            if (got <= 0) {
                if (closed) *closed = true;
                break;
            }
            out.insert(out.end(), buffer.begin(), buffer.begin() + got);
        }
        return out;
    }

  private:
    int fd_ = -1;
    bool connected_ = false;
};

TcpServerConfig loopback(std::uint16_t port = 0) {
    TcpServerConfig config;
    config.bindAddress = "127.0.0.1";
    config.port = port;
    return config;
}

TcpServerConfig threeClientsUnit9() {
    TcpServerConfig config = loopback();
    config.maxConnections = 3;
    config.unitId = 9;
    return config;
}

struct TcpFixture : ::testing::Test {
    MemoryRegisters registers;
    TcpServer server{threeClientsUnit9(), registers};
    void SetUp() override { server.start(); }
};

TEST_F(TcpFixture, LibmodbusReadsAndWrites) {
    ASSERT_NE(server.port(), 0);
    Context ctx = tcpMaster(server.port(), 9);
    ASSERT_TRUE(ctx);
    const std::uint16_t values[2] = {0xBEEF, 0x0042};
    ASSERT_EQ(modbus_write_registers(ctx.get(), 0x20, 2, values), 2) << modbus_strerror(errno);
    std::uint16_t back[2] = {};
    ASSERT_EQ(modbus_read_registers(ctx.get(), 0x20, 2, back), 2) << modbus_strerror(errno);
    EXPECT_EQ(back[0], 0xBEEF);
    EXPECT_EQ(back[1], 0x0042);
    ASSERT_EQ(modbus_write_register(ctx.get(), 0x21, 7), 1);
    std::uint16_t input[2] = {};
    ASSERT_EQ(modbus_read_input_registers(ctx.get(), 0x10FE, 2, input), 2);
    EXPECT_EQ(input[1], 0xA0FF);
    std::uint16_t value = 0;
    EXPECT_EQ(modbus_read_input_registers(ctx.get(), 0x10FF, 2, input), -1);
    EXPECT_EQ(errno, EMBXILADD);
    EXPECT_EQ(modbus_write_register(ctx.get(), 0, 0xDEAD), -1);
    EXPECT_EQ(errno, EMBXILVAL);
    EXPECT_EQ(modbus_read_registers(ctx.get(), 0x21, 1, &value), 1);
    EXPECT_EQ(value, 7);
}

TEST_F(TcpFixture, OtherUnitGetsGatewayException) {
    Context ctx = tcpMaster(server.port(), 5);
    ASSERT_TRUE(ctx);
    std::uint16_t value = 0;
    EXPECT_EQ(modbus_read_registers(ctx.get(), 0, 1, &value), -1);
    EXPECT_EQ(errno, EMBXGTAR);
}

TEST_F(TcpFixture, MalformedHeaderClosesOnlyThatConnection) {
    Context good = tcpMaster(server.port(), 9);
    ASSERT_TRUE(good);
    std::uint16_t value = 0;
    ASSERT_EQ(modbus_read_registers(good.get(), 0, 1, &value), 1);
    for (const char* header : {"00 01 00 01 00 06 09 03 00 00 00 01",     // protocol 1
                               "00 01 00 00 00 01 09",                    // length 1
                               "00 01 00 00 01 00 09 03 00 00 00 01"}) {  // length 256
        RawClient bad(server.port());
        ASSERT_TRUE(bad.connected());
        ASSERT_TRUE(bad.send(fromHex(header)));
        bool closed = false;
        EXPECT_TRUE(bad.receive(1, 1000ms, &closed).empty()) << header;
        EXPECT_TRUE(closed) << header;
        ASSERT_EQ(modbus_read_registers(good.get(), 0, 1, &value), 1) << header;
    }
}

TEST_F(TcpFixture, PipelinedAndSplitRequestsAnsweredInOrder) {
    RawClient client(server.port());
    ASSERT_TRUE(client.connected());
    // Two requests in one segment, then one split inside its header.
    ASSERT_TRUE(
        client.send(fromHex("12 34 00 00 00 06 09 06 00 01 00 2A "
                            "12 35 00 00 00 06 09 03 00 01 00 01 "
                            "12 36 00")));
    ASSERT_TRUE(client.send(fromHex("00 00 06 09 04 10 00 00 01")));
    EXPECT_EQ(toHex(client.receive(12 + 11 + 11, 1000ms)),
              "12 34 00 00 00 06 09 06 00 01 00 2A "
              "12 35 00 00 00 05 09 03 02 00 2A "
              "12 36 00 00 00 05 09 04 02 A0 00");
}

TEST_F(TcpFixture, ConnectionsBeyondTheLimitAreClosed) {
    RawClient a(server.port()), b(server.port()), c(server.port());
    ASSERT_TRUE(a.send(fromHex("00 01 00 00 00 06 09 03 00 00 00 01")));
    ASSERT_EQ(a.receive(11, 1000ms).size(), 11u);  // a is accepted by now
    ASSERT_TRUE(b.send(fromHex("00 01 00 00 00 06 09 03 00 00 00 01")));
    ASSERT_EQ(b.receive(11, 1000ms).size(), 11u);
    ASSERT_TRUE(c.send(fromHex("00 01 00 00 00 06 09 03 00 00 00 01")));
    ASSERT_EQ(c.receive(11, 1000ms).size(), 11u);
    RawClient d(server.port());
    bool closed = false;
    d.send(fromHex("00 01 00 00 00 06 09 03 00 00 00 01"));
    EXPECT_TRUE(d.receive(11, 1000ms, &closed).empty());
    EXPECT_TRUE(closed);
}

TEST_F(TcpFixture, UnansweringDeviceTimesOutInLibmodbus) {
    Context ctx = tcpMaster(server.port(), 9);
    ASSERT_TRUE(ctx);
    modbus_set_response_timeout(ctx.get(), 0, 200000);
    registers.on = false;
    std::uint16_t value = 0;
    EXPECT_EQ(modbus_read_registers(ctx.get(), 0, 1, &value), -1);
    EXPECT_EQ(errno, ETIMEDOUT);
    registers.on = true;
    EXPECT_EQ(modbus_read_registers(ctx.get(), 0, 1, &value), 1) << modbus_strerror(errno);
}

TEST(ModbusTcpServer, PortTakenThrows) {
    MemoryRegisters registers;
    TcpServer first(loopback(), registers);
    first.start();
    TcpServer second(loopback(first.port()), registers);
    EXPECT_THROW(second.start(), std::system_error);
    TcpServerConfig bad = loopback();
    bad.bindAddress = "not an address";
    TcpServer nonsense(bad, registers);
    EXPECT_THROW(nonsense.start(), std::system_error);
}

}  // namespace
}  // namespace pnp::modbus::test
