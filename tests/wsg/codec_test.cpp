// The WSG codec: the manual's example frames byte for byte, round trips, the stream decoder fed
// byte by byte, with garbage, bad checksums and oversized frames.
#include <gtest/gtest.h>

#include <cstdint>
#include <vector>

#include "wsg/protocol.hpp"

namespace pnp::wsg {
namespace {

using Bytes = std::vector<std::uint8_t>;

// The example frames of the WSG Command Set Reference Manual (section "Communicating with the
// WSG Grippers"): commands and acknowledges with their checksums.
const std::vector<Bytes> kManualFrames = {
    {0xAA, 0xAA, 0xAA, 0x01, 0x00, 0x00, 0xE8, 0x10},              // id 1, no payload
    {0xAA, 0xAA, 0xAA, 0x01, 0x02, 0x00, 0x12, 0x34, 0x6D, 0x66},  // id 1, 12 34
    {0xAA, 0xAA, 0xAA, 0x20, 0x02, 0x00, 0x00, 0x00, 0xB3, 0xFD},  // homing: E_SUCCESS
    {0xAA, 0xAA, 0xAA, 0x90, 0x02, 0x00, 0x0E, 0x00, 0xFD, 0x02},  // 0x90: E_CMD_UNKNOWN
    {0xAA, 0xAA, 0xAA, 0x30, 0x06, 0x00, 0x00, 0x00, 0x00, 0x00, 0x16, 0x43, 0xDC, 0xCB},
    {0xAA, 0xAA, 0xAA, 0x21, 0x02, 0x00, 0x1A, 0x00, 0x67, 0xCB},  // pre-position: pending
    {0xAA, 0xAA, 0xAA, 0x21, 0x02, 0x00, 0x00, 0x00, 0x28, 0x04},  // pre-position: done
};

TEST(WsgCodec, ChecksumOfTheManualsFrames) {
    for (const Bytes& f : kManualFrames) {
        const std::span body(f.data(), f.size() - 2);
        const std::uint16_t crc = checksum(body);
        EXPECT_EQ(crc & 0xFF, f[f.size() - 2]);
        EXPECT_EQ(crc >> 8, f[f.size() - 1]);
        EXPECT_EQ(checksum(f), 0) << "over the whole frame the CRC is 0";
    }
}

TEST(WsgCodec, EncodesTheManualsFramesByteForByte) {
    EXPECT_EQ(encodeFrame(0x01, {}), kManualFrames[0]);
    EXPECT_EQ(encodeFrame(0x01, Bytes{0x12, 0x34}), kManualFrames[1]);
    EXPECT_EQ(encodeResponse(0x20, Status::kSuccess), kManualFrames[2]);
    EXPECT_EQ(encodeResponse(0x90, Status::kCmdUnknown), kManualFrames[3]);
    EXPECT_EQ(encodeResponse(0x30, Status::kSuccess, floatPayload(150.0f)), kManualFrames[4]);
    EXPECT_EQ(encodeResponse(0x21, Status::kCmdPending), kManualFrames[5]);
    EXPECT_EQ(encodeResponse(0x21, Status::kSuccess), kManualFrames[6]);
}

TEST(WsgCodec, CommandPayloads) {
    // Pre-position: flags, width 50 mm (0x42480000), speed 100 mm/s (0x42C80000).
    EXPECT_EQ(prePositionPayload(move_flag::kStopOnBlock, 50.0f, 100.0f),
              (Bytes{0x02, 0x00, 0x00, 0x48, 0x42, 0x00, 0x00, 0xC8, 0x42}));
    EXPECT_EQ(graspPayload(40.0f, 10.0f), (Bytes{0x00, 0x00, 0x20, 0x42, 0x00, 0x00, 0x20, 0x41}));
    EXPECT_EQ(acknowledgeFastStopPayload(), (Bytes{0x61, 0x63, 0x6B}));
    EXPECT_EQ(homingPayload(), (Bytes{0x00}));
    const Bytes grasp = encodeCommand(Command::kGrasp, graspPayload(40.0f, 10.0f));
    ASSERT_EQ(grasp.size(), 16u);
    EXPECT_EQ(grasp[3], 0x25);
    EXPECT_EQ(grasp[4], 8);
    EXPECT_EQ(grasp[5], 0);
    EXPECT_EQ(checksum(grasp), 0);
}

TEST(WsgCodec, NamesOfCommandsStatusesAndStates) {
    EXPECT_EQ(commandName(0x25), "GRASP PART");
    EXPECT_EQ(commandName(0x99), "UNKNOWN");
    EXPECT_TRUE(knownCommand(0x50));
    EXPECT_FALSE(knownCommand(0x90));
    EXPECT_EQ(statusName(Status::kCmdPending), "E_CMD_PENDING");
    EXPECT_EQ(static_cast<int>(Status::kCmdPending), 26);
    EXPECT_EQ(statusName(Status::kAxisBlocked), "E_AXIS_BLOCKED");
    EXPECT_EQ(statusName(std::uint16_t{999}), "E_UNKNOWN");
    EXPECT_EQ(graspingStateName(GraspingState::kNoPartFound), "NO PART FOUND");
    EXPECT_EQ(graspingStateName(std::uint8_t{8}), "UNKNOWN");
}

TEST(WsgCodec, ValuesRoundTrip) {
    const SystemInformation info{1, 2, 0x4213, 0x01020304};
    const Bytes encoded = encodeSystemInformation(info);
    EXPECT_EQ(encoded, (Bytes{1, 2, 0x13, 0x42, 0x04, 0x03, 0x02, 0x01}));
    const auto back = parseSystemInformation(encoded);
    ASSERT_TRUE(back);
    EXPECT_EQ(back->type, 1);
    EXPECT_EQ(back->hardwareRevision, 2);
    EXPECT_EQ(back->firmware, 0x4213);
    EXPECT_EQ(back->serialNumber, 0x01020304u);
    EXPECT_EQ(firmwareString(0x4213), "4.2.1.3");
    EXPECT_EQ(deviceTypeName(1), "WSG 50");
    EXPECT_FALSE(parseSystemInformation(Bytes{1, 2, 3}));

    const GraspingStatistics s{7, 2, 1};
    const auto sb = parseGraspingStatistics(encodeGraspingStatistics(s));
    ASSERT_TRUE(sb);
    EXPECT_EQ(sb->total, 7u);
    EXPECT_EQ(sb->noPart, 2);
    EXPECT_EQ(sb->lostPart, 1);

    EXPECT_EQ(getFloat(floatPayload(-12.5f), 0), -12.5f);
    EXPECT_FALSE(getFloat(Bytes{1, 2, 3}, 0));
    EXPECT_FALSE(getU16(Bytes{1}, 0));
    EXPECT_FALSE(getU32(Bytes{1, 2, 3, 4}, 5));
}

TEST(WsgCodec, RefusesToEncodeAnOversizedPayload) {
    EXPECT_THROW(encodeFrame(0x01, Bytes(kMaxPayload + 1, 0)), std::length_error);
    EXPECT_NO_THROW(encodeFrame(0x01, Bytes(kMaxPayload, 0)));
}

TEST(WsgCodec, DecoderFedByteByByte) {
    Bytes stream;
    for (const Bytes& f : kManualFrames) stream.insert(stream.end(), f.begin(), f.end());
    Decoder d;
    std::vector<Frame> frames;
    for (std::uint8_t b : stream) {
        for (Frame& f : d.feed(std::span(&b, 1))) frames.push_back(std::move(f));
    }
    ASSERT_EQ(frames.size(), kManualFrames.size());
    for (std::size_t i = 0; i < frames.size(); ++i) {
        EXPECT_EQ(frames[i].error, FrameError::kNone);
        EXPECT_EQ(frames[i].id, kManualFrames[i][3]);
        EXPECT_EQ(frames[i].payload.size(), kManualFrames[i][4]);
    }
    EXPECT_EQ(d.discardedBytes(), 0u);
    EXPECT_EQ(d.buffered(), 0u);
    const auto r = parseResponse(frames[4]);
    ASSERT_TRUE(r);
    EXPECT_TRUE(r->ok());
    EXPECT_EQ(getFloat(r->values, 0), 150.0f);
    EXPECT_TRUE(parseResponse(frames[5])->pending());
}

TEST(WsgCodec, DecoderSkipsGarbageAndResynchronises) {
    Bytes stream = {0x00, 0xAA, 0x13, 0xAA, 0xAA, 0x55};  // garbage, partial preambles
    stream.insert(stream.end(), kManualFrames[2].begin(), kManualFrames[2].end());
    stream.insert(stream.end(), {0xAA, 0xAA});  // a lone preamble byte pair
    stream.insert(stream.end(), kManualFrames[6].begin(), kManualFrames[6].end());
    Decoder d;
    const auto frames = d.feed(stream);
    // The AA AA before the second frame make a run of five: its last three are the preamble.
    ASSERT_EQ(frames.size(), 2u);
    EXPECT_EQ(frames[0].error, FrameError::kNone);
    EXPECT_EQ(frames[0].id, 0x20);
    EXPECT_EQ(frames[1].error, FrameError::kNone);
    EXPECT_EQ(frames[1].id, 0x21);
    EXPECT_EQ(d.discardedBytes(), 8u);
    EXPECT_EQ(d.checksumErrors(), 0u);
}

TEST(WsgCodec, DecoderReportsABadChecksumAndCarriesOn) {
    Bytes bad = kManualFrames[1];
    bad[6] ^= 0x01;  // a payload bit flipped
    Bytes stream = bad;
    stream.insert(stream.end(), kManualFrames[0].begin(), kManualFrames[0].end());
    Decoder d;
    const auto frames = d.feed(stream);
    ASSERT_EQ(frames.size(), 2u);
    EXPECT_EQ(frames[0].error, FrameError::kChecksum);
    EXPECT_EQ(frames[0].id, 0x01);
    EXPECT_FALSE(parseResponse(frames[0]));
    EXPECT_EQ(frames[1].error, FrameError::kNone);
    EXPECT_EQ(d.checksumErrors(), 1u);
}

TEST(WsgCodec, DecoderBoundsThePayloadSize) {
    // Size 0xFFFF: reported, not buffered; the frame after it still decodes.
    Bytes stream = {0xAA, 0xAA, 0xAA, 0x25, 0xFF, 0xFF, 0x01, 0x02};
    stream.insert(stream.end(), kManualFrames[0].begin(), kManualFrames[0].end());
    Decoder d;
    const auto frames = d.feed(stream);
    ASSERT_EQ(frames.size(), 2u);
    EXPECT_EQ(frames[0].error, FrameError::kTooLarge);
    EXPECT_EQ(frames[0].id, 0x25);
    EXPECT_EQ(frames[1].error, FrameError::kNone);
    EXPECT_EQ(d.oversizedFrames(), 1u);
    EXPECT_LE(d.buffered(), kMaxFrameSize);
}

TEST(WsgCodec, DecoderBufferStaysBoundedOnEndlessGarbage) {
    Decoder d;
    Bytes junk(4096);
    for (std::size_t i = 0; i < junk.size(); ++i) junk[i] = static_cast<std::uint8_t>(i * 7 + 1);
    for (int i = 0; i < 100; ++i) {
        for (const Frame& f : d.feed(junk)) EXPECT_NE(f.error, FrameError::kNone);
        EXPECT_LE(d.buffered(), kMaxFrameSize);
    }
    // All AA: a preamble whose size field (AA AA = 43690) is too large, again and again.
    const Bytes allAa(3000, 0xAA);
    d.feed(allAa);
    EXPECT_LE(d.buffered(), kMaxFrameSize);
}

}  // namespace
}  // namespace pnp::wsg
