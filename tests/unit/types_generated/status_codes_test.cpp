#include "ua/types/status_codes.hpp"

#include <gtest/gtest.h>

#include <algorithm>

namespace pnp::ua {
namespace {

TEST(StatusCodes, WellKnownValues) {
    EXPECT_EQ(status::Good.value, 0x00000000u);
    EXPECT_EQ(status::Uncertain.value, 0x40000000u);
    EXPECT_EQ(status::Bad.value, 0x80000000u);
    EXPECT_EQ(status::BadDecodingError.value, 0x80070000u);
    EXPECT_EQ(status::BadEncodingLimitsExceeded.value, 0x80080000u);
    EXPECT_EQ(status::BadNodeIdUnknown.value, 0x80340000u);
    EXPECT_EQ(status::BadTimeout.value, 0x800A0000u);
    EXPECT_EQ(status::GoodMoreData.value, 0x00A60000u);
    EXPECT_EQ(status::UncertainLastUsableValue.value, 0x40900000u);
    static_assert(status::BadDecodingError.isBad());
    static_assert(status::UncertainLastUsableValue.isUncertain());
}

TEST(StatusCodes, Names) {
    EXPECT_EQ(status::BadNodeIdUnknown.name(), "BadNodeIdUnknown");
    EXPECT_EQ(status::Good.name(), "Good");
    EXPECT_EQ(StatusCode{0x80340000}.toString(), "BadNodeIdUnknown (0x80340000)");
    EXPECT_EQ(StatusCode{0}.toString(), "Good (0x00000000)");
    // Info bits do not hide the code.
    EXPECT_EQ(StatusCode{0x00000480}.name(), "Good");
    EXPECT_EQ(StatusCode{0x00000480}.toString(), "Good (0x00000480)");
    // Unknown codes print as hex only.
    EXPECT_EQ(StatusCode{0x80FF0000}.name(), "");
    EXPECT_EQ(StatusCode{0x80FF0000}.toString(), "0x80FF0000");
}

TEST(StatusCodes, Table) {
    auto all = allStatusCodes();
    ASSERT_EQ(all.size(), kStatusCodeCount);
    EXPECT_GT(all.size(), 250u);
    EXPECT_TRUE(std::is_sorted(all.begin(), all.end(),
                               [](const auto& a, const auto& b) { return a.value < b.value; }));
    for (const auto& e : all) {
        EXPECT_EQ(e.value & 0xFFFFu, 0u) << e.name;
        EXPECT_EQ(StatusCode{e.value}.name(), e.name);
        EXPECT_EQ(statusCodeFromName(e.name), StatusCode{e.value});
    }
    const StatusCodeInfo* info = findStatusCode(status::BadDecodingError);
    ASSERT_NE(info, nullptr);
    EXPECT_FALSE(info->description.empty());
    EXPECT_EQ(statusCodeFromName("NoSuchCode"), std::nullopt);
}

}  // namespace
}  // namespace pnp::ua
