// NumericRange parsing and application (OPC 10000-4 §7.27).
#include "ua/server/numeric_range.hpp"

#include <gtest/gtest.h>

#include "ua/types/status_codes.hpp"

namespace pnp::ua::server {
namespace {

using Dim = NumericRange::Dimension;

TEST(NumericRange, Parse) {
    EXPECT_TRUE(NumericRange::parse("")->empty());
    EXPECT_EQ(NumericRange::parse("6")->dimensions(), (std::vector<Dim>{{6, 6}}));
    EXPECT_EQ(NumericRange::parse("5:7")->dimensions(), (std::vector<Dim>{{5, 7}}));
    EXPECT_EQ(NumericRange::parse("1:2,0:1")->dimensions(), (std::vector<Dim>{{1, 2}, {0, 1}}));
    EXPECT_EQ(NumericRange::parse("1,1")->dimensions(), (std::vector<Dim>{{1, 1}, {1, 1}}));
    EXPECT_EQ(NumericRange::parse("0:4294967295")->dimensions(),
              (std::vector<Dim>{{0, 4294967295u}}));
    for (const char* bad : {"7:5", "5:5", "a", "-1", "1:", ":1", "1,", ",1", "1 ", "+1", "1:2:3",
                            "4294967296", "1:2,", "0x1", "1.5"})
        EXPECT_FALSE(NumericRange::parse(bad).has_value()) << bad;
    EXPECT_EQ(NumericRange::parse("1:2,3")->toString(), "1:2,3");
}

TEST(NumericRange, ReadArrays) {
    Variant v(std::vector<Double>{0, 1, 2, 3});
    Variant out;
    EXPECT_TRUE(readRange(v, *NumericRange::parse("1:2"), out).isGood());
    EXPECT_EQ(*out.array<Double>(), (std::vector<Double>{1, 2}));
    EXPECT_TRUE(readRange(v, *NumericRange::parse("3:100"), out).isGood());
    EXPECT_EQ(*out.array<Double>(), (std::vector<Double>{3}));
    EXPECT_EQ(readRange(v, *NumericRange::parse("4"), out), status::BadIndexRangeNoData);
    EXPECT_EQ(readRange(Variant(), *NumericRange::parse("0"), out), status::BadIndexRangeNoData);
    EXPECT_EQ(readRange(Variant(std::vector<Double>{}), *NumericRange::parse("0"), out),
              status::BadIndexRangeNoData);
    Variant b(std::vector<Boolean>{true, false, true});
    EXPECT_TRUE(readRange(b, *NumericRange::parse("1:2"), out).isGood());
    EXPECT_EQ(*out.array<Boolean>(), (std::vector<Boolean>{false, true}));
    // Arrays of ByteStrings: the last dimension cuts each element.
    Variant bs(
        std::vector<ByteString>{ByteString(std::string("abc")), ByteString(std::string("d"))});
    EXPECT_TRUE(readRange(bs, *NumericRange::parse("0:1,1:2"), out).isGood());
    EXPECT_EQ((*out.array<ByteString>())[0].view(), "bc");
    EXPECT_EQ((*out.array<ByteString>())[1].view(), "");  // no data in range for that element
    // Three dimensions.
    std::vector<Int32> cube(24);
    for (int i = 0; i < 24; ++i) cube[i] = i;
    Variant c(cube);
    c.setArrayDimensions({2, 3, 4});
    EXPECT_TRUE(readRange(c, *NumericRange::parse("1,1:2,2:3"), out).isGood());
    EXPECT_EQ(*out.array<Int32>(), (std::vector<Int32>{18, 19, 22, 23}));
    EXPECT_EQ(out.arrayDimensions(), (std::vector<Int32>{1, 2, 2}));
    EXPECT_EQ(readRange(c, *NumericRange::parse("1,1"), out), status::BadIndexRangeNoData);
}

TEST(NumericRange, WriteArrays) {
    Variant v(std::vector<String>{"a", "b", "c"});
    EXPECT_TRUE(writeRange(v, *NumericRange::parse("1:2"), Variant(std::vector<String>{"x", "y"}))
                    .isGood());
    EXPECT_EQ(*v.array<String>(), (std::vector<String>{"a", "x", "y"}));
    EXPECT_EQ(writeRange(v, *NumericRange::parse("2:3"), Variant(std::vector<String>{"x", "y"})),
              status::BadIndexRangeNoData);
    EXPECT_EQ(writeRange(v, *NumericRange::parse("0"), Variant(String("z"))),
              status::BadTypeMismatch);
    EXPECT_EQ(writeRange(v, *NumericRange::parse("0"), Variant(std::vector<Int32>{1})),
              status::BadTypeMismatch);
    // Bytes inside string elements.
    Variant w(std::vector<String>{"hello", "world"});
    EXPECT_TRUE(writeRange(w, *NumericRange::parse("0:1,0"), Variant(std::vector<String>{"H", "W"}))
                    .isGood());
    EXPECT_EQ(*w.array<String>(), (std::vector<String>{"Hello", "World"}));
    // Matrix: the source must have the block's shape.
    Variant m(std::vector<Int32>{0, 0, 0, 0});
    m.setArrayDimensions({2, 2});
    Variant src(std::vector<Int32>{1, 2});
    src.setArrayDimensions({2, 1});
    EXPECT_TRUE(writeRange(m, *NumericRange::parse("0:1,1"), src).isGood());
    EXPECT_EQ(*m.array<Int32>(), (std::vector<Int32>{0, 1, 0, 2}));
    src.setArrayDimensions({1, 2});
    EXPECT_EQ(writeRange(m, *NumericRange::parse("0:1,1"), src), status::BadIndexRangeNoData);
    // Scalars other than String/ByteString have no index.
    Variant s(Int32{1});
    EXPECT_EQ(writeRange(s, *NumericRange::parse("0"), Variant(Int32{2})),
              status::BadIndexRangeNoData);
}

}  // namespace
}  // namespace pnp::ua::server
