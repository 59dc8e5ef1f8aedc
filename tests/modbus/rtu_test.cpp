// RTU framing without I/O (RtuFramer): frames fed byte by byte and in slices with the times
// they arrive, the silence that ends them, and every reason to drop one; a bounded fuzz run.
#include <gtest/gtest.h>

#include <random>

#include "modbus_helpers.hpp"

namespace pnp::modbus::test {
namespace {

using Clock = RtuFramer::Clock;
using namespace std::chrono_literals;

constexpr std::uint8_t kSlave = 9;

struct Fixture : ::testing::Test {
    MemoryRegisters registers;
    RtuFramer framer{RtuSlaveConfig{kSlave, 115200}};
    Clock::time_point t = Clock::time_point{} + 1h;

    // Feeds `bytes` in slices of `slice` bytes, `gap` apart; then lets the line go silent.
    std::vector<Bytes> feed(const Bytes& bytes, std::size_t slice, Clock::duration gap = 100us) {
        std::vector<Bytes> out;
        for (std::size_t at = 0; at < bytes.size(); at += slice) {
            const std::size_t n = std::min(slice, bytes.size() - at);
            if (auto r = framer.receive(std::span(bytes.data() + at, n), t, registers)) {
                out.push_back(*r);
            }
            t += gap;
        }
        t += framer.silence();
        if (auto r = framer.expire(t, registers)) out.push_back(*r);
        return out;
    }
};

TEST_F(Fixture, SilenceIsFixedAbove19200AndCharacterTimesBelow) {
    EXPECT_EQ(framer.silence(), std::chrono::microseconds(1750));
    EXPECT_EQ(RtuFramer(RtuSlaveConfig{1, 38400}).silence(), std::chrono::microseconds(1750));
    // 9600 baud: 3.5 characters of 11 bits = 4.01 ms.
    const auto slow = RtuFramer(RtuSlaveConfig{1, 9600}).silence();
    EXPECT_GE(slow, std::chrono::microseconds(4010));
    EXPECT_LE(slow, std::chrono::microseconds(4020));
}

TEST_F(Fixture, ByteByByteAndInSlicesGiveTheSameAnswer) {
    const Bytes request = fromHex("09 03 07 D0 00 01 85 CF");  // 0x07D0 is beyond the map
    const Bytes expected = rtuFrame(kSlave, fromHex("83 02"));
    for (std::size_t slice : {1u, 2u, 3u, 5u, 8u}) {
        const auto out = feed(request, slice);
        ASSERT_EQ(out.size(), 1u) << "slice " << slice;
        EXPECT_EQ(out[0], expected) << "slice " << slice;
    }
    const auto ok = feed(rtuFrame(kSlave, fromHex("04 10 00 00 01")), 1);
    ASSERT_EQ(ok.size(), 1u);
    EXPECT_EQ(toHex(ok[0]), toHex(rtuFrame(kSlave, fromHex("04 02 A0 00"))));
    EXPECT_EQ(framer.stats().frames, 6u);
}

TEST_F(Fixture, NoAnswerBeforeTheSilence) {
    const Bytes request = rtuFrame(kSlave, fromHex("03 00 00 00 01"));
    EXPECT_FALSE(framer.receive(request, t, registers));
    ASSERT_TRUE(framer.deadline());
    EXPECT_EQ(*framer.deadline(), t + framer.silence());
    EXPECT_FALSE(framer.expire(t + framer.silence() - 1us, registers));
    const auto r = framer.expire(t + framer.silence(), registers);
    ASSERT_TRUE(r);
    EXPECT_EQ(*r, rtuFrame(kSlave, fromHex("03 02 00 00")));
    EXPECT_FALSE(framer.deadline());
}

TEST_F(Fixture, BackToBackFramesSeparatedBySilence) {
    const Bytes a = rtuFrame(kSlave, fromHex("06 00 01 00 05"));
    const Bytes b = rtuFrame(kSlave, fromHex("03 00 01 00 01"));
    EXPECT_FALSE(framer.receive(a, t, registers));
    t += framer.silence();
    // The next frame's first bytes complete the previous one.
    const auto first = framer.receive(b, t, registers);
    ASSERT_TRUE(first);
    EXPECT_EQ(*first, a);  // FC06 echoes
    t += framer.silence();
    const auto second = framer.expire(t, registers);
    ASSERT_TRUE(second);
    EXPECT_EQ(*second, rtuFrame(kSlave, fromHex("03 02 00 05")));
}

TEST_F(Fixture, TwoFramesWithoutSilenceAreOneBadFrame) {
    Bytes both = rtuFrame(kSlave, fromHex("03 00 01 00 01"));
    const Bytes more = rtuFrame(kSlave, fromHex("03 00 02 00 01"));
    both.insert(both.end(), more.begin(), more.end());
    EXPECT_TRUE(feed(both, 4).empty());
    EXPECT_EQ(framer.stats().badCrc, 1u);
}

TEST_F(Fixture, BadCrcIsDropped) {
    Bytes request = rtuFrame(kSlave, fromHex("03 00 00 00 01"));
    request.back() ^= 0x01;
    EXPECT_TRUE(feed(request, 1).empty());
    request = rtuFrame(kSlave, fromHex("03 00 00 00 01"));
    request[3] ^= 0x40;  // a flipped data bit
    EXPECT_TRUE(feed(request, 8).empty());
    EXPECT_EQ(framer.stats().badCrc, 2u);
    EXPECT_EQ(registers.reads.load(), 0);
}

TEST_F(Fixture, OtherSlaveIsDropped) {
    EXPECT_TRUE(feed(rtuFrame(10, fromHex("03 00 00 00 01")), 8).empty());
    EXPECT_TRUE(feed(rtuFrame(247, fromHex("06 00 00 00 07")), 1).empty());
    EXPECT_EQ(framer.stats().otherSlave, 2u);
    EXPECT_EQ(registers.holding(0), 0);
}

TEST_F(Fixture, BroadcastIsExecutedWithoutAnswer) {
    EXPECT_TRUE(feed(rtuFrame(0, fromHex("06 00 03 00 2A")), 8).empty());
    EXPECT_EQ(registers.holding(3), 0x2A);
    EXPECT_EQ(framer.stats().broadcasts, 1u);
    EXPECT_EQ(framer.stats().frames, 0u);
}

TEST_F(Fixture, TooShortAndTooLongAreDropped) {
    EXPECT_TRUE(feed(fromHex("09 03 00"), 1).empty());
    EXPECT_EQ(framer.stats().tooShort, 1u);
    // 257 bytes ending in a valid CRC of the whole: still too long for a frame.
    Bytes pdu = fromHex("10 00 00 00 7D FA");
    pdu.resize(1 + 4 + 1 + 250 - 2, 0);  // makes the frame 1 + 254 + 2 = 257 bytes
    const Bytes huge = rtuFrame(kSlave, pdu);
    ASSERT_EQ(huge.size(), 257u);
    EXPECT_TRUE(feed(huge, 64).empty());
    EXPECT_EQ(framer.stats().tooLong, 1u);
    // A frame of exactly 256 bytes is taken (its PDU is wrong, so exception 03)...
    Bytes odd(253, 0);
    odd[0] = 0x03;
    const auto full = feed(rtuFrame(kSlave, odd), 256);
    ASSERT_EQ(full.size(), 1u);
    EXPECT_EQ(full[0], rtuFrame(kSlave, fromHex("83 03")));
    // ... and the longest write, FC16 of 123 registers (255 bytes), works.
    Bytes write = fromHex("10 00 00 00 7B F6");
    write.resize(6 + 246, 0);
    const Bytes longest = rtuFrame(kSlave, write);
    ASSERT_EQ(longest.size(), 255u);
    const auto out = feed(longest, 100);
    ASSERT_EQ(out.size(), 1u);
    EXPECT_EQ(out[0], rtuFrame(kSlave, fromHex("10 00 00 00 7B")));
}

TEST_F(Fixture, NotAnsweringDropsFramesForUs) {
    registers.on = false;
    EXPECT_TRUE(feed(rtuFrame(kSlave, fromHex("03 00 00 00 01")), 8).empty());
    EXPECT_EQ(framer.stats().notAnswering, 1u);
    registers.on = true;
    EXPECT_EQ(feed(rtuFrame(kSlave, fromHex("03 00 00 00 01")), 8).size(), 1u);
}

// Random bytes in random slices with random gaps: never a crash, every answer a well-formed
// frame from our address with a good CRC, the buffer never beyond 256 bytes, and afterwards a
// clean request is answered. Bounded: a fixed seed and count.
TEST_F(Fixture, FuzzRandomBytesKeepTheFramerSane) {
    std::mt19937 rng(20240522);
    std::uniform_int_distribution<int> byte(0, 255);
    std::uniform_int_distribution<int> sliceLength(1, 40);
    std::uniform_int_distribution<int> gapMicros(0, 3000);
    std::bernoulli_distribution useOurAddress(0.3);
    std::size_t answers = 0;
    for (int round = 0; round < 20000; ++round) {
        Bytes slice(static_cast<std::size_t>(sliceLength(rng)));
        for (auto& b : slice) b = static_cast<std::uint8_t>(byte(rng));
        if (useOurAddress(rng)) slice[0] = kSlave;
        // Sometimes a random PDU with a valid CRC, so answer() sees garbage too.
        if (round % 7 == 0) slice = rtuFrame(kSlave, slice);
        t += std::chrono::microseconds(gapMicros(rng));
        auto r = framer.receive(slice, t, registers);
        if (!r) r = framer.expire(t, registers);
        if (r) {
            ++answers;
            ASSERT_GE(r->size(), 5u);
            ASSERT_LE(r->size(), RtuFramer::kMaxFrame);
            EXPECT_EQ((*r)[0], kSlave);
            EXPECT_EQ(crc16(*r), 0);
        }
    }
    EXPECT_GT(answers, 0u);
    t += framer.silence();
    framer.expire(t, registers);
    const auto clean = feed(rtuFrame(kSlave, fromHex("04 10 05 00 01")), 3);
    ASSERT_EQ(clean.size(), 1u);
    EXPECT_EQ(clean[0], rtuFrame(kSlave, fromHex("04 02 A0 05")));
    const RtuStats& s = framer.stats();
    EXPECT_GT(s.badCrc, 0u);
    EXPECT_GT(s.tooLong + s.tooShort + s.otherSlave, 0u);
}

}  // namespace
}  // namespace pnp::modbus::test
