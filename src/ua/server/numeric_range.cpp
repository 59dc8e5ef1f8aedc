#include "ua/server/numeric_range.hpp"

#include <charconv>
#include <type_traits>

#include "ua/types/status_codes.hpp"

namespace pnp::ua::server {

namespace {

constexpr StatusCode kGood{};

template <class T>
struct IsVector : std::false_type {};
template <class T>
struct IsVector<std::vector<T>> : std::true_type {
    using Element = T;
};

template <class T>
constexpr bool kIsByteSequence = std::is_same_v<T, String> || std::is_same_v<T, ByteString>;

std::string_view bytesOf(const String& s) { return s; }
std::string_view bytesOf(const ByteString& s) { return s.view(); }
void setBytes(String& s, std::string_view v) { s.assign(v); }
void setBytes(ByteString& s, std::string_view v) { s = ByteString(v); }
// dst with `count` bytes at `at` replaced by src (ByteStrings are immutable: a new value).
template <class S>
void replaceBytes(S& dst, std::size_t at, std::size_t count, std::string_view src) {
    std::string b(bytesOf(dst));
    b.replace(at, count, src);
    setBytes(dst, b);
}

bool parseIndex(std::string_view s, UInt32& out) {
    if (s.empty()) return false;
    for (char c : s)
        if (c < '0' || c > '9') return false;
    auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
    return ec == std::errc() && p == s.data() + s.size();
}

// Substring of a byte sequence for one dimension. false: lower bound beyond the data.
template <class S>
bool sliceBytes(const S& in, const NumericRange::Dimension& d, S& out) {
    std::string_view b = bytesOf(in);
    if (d.min >= b.size()) return false;
    std::size_t n = std::min<std::size_t>(d.count(), b.size() - d.min);
    setBytes(out, b.substr(d.min, n));
    return true;
}

// Shape of an array value: its ArrayDimensions, or {length} for a one-dimensional array.
bool shapeOf(const Variant& v, std::size_t length, std::vector<std::size_t>& shape) {
    const auto& dims = v.arrayDimensions();
    shape.clear();
    if (dims.size() <= 1) {
        shape.push_back(length);
        return true;
    }
    std::size_t product = 1;
    for (Int32 d : dims) {
        if (d < 0) return false;
        shape.push_back(static_cast<std::size_t>(d));
        product *= static_cast<std::size_t>(d);
    }
    return product == length;
}

// Calls f(flatIndex) for every element of the (clamped) block in row-major order (the last
// dimension varies fastest, Part 6 §5.2.2.16). Returns the block's shape; false when a
// lower bound is outside the array.
template <class F>
bool forEachInBlock(const std::vector<std::size_t>& shape,
                    const std::vector<NumericRange::Dimension>& range,
                    std::vector<std::size_t>& blockShape, bool clamp, F&& f) {
    const std::size_t rank = shape.size();
    blockShape.assign(rank, 0);
    for (std::size_t i = 0; i < rank; ++i) {
        if (range[i].min >= shape[i]) return false;
        std::size_t hi = range[i].max;
        if (hi >= shape[i]) {
            if (!clamp) return false;
            hi = shape[i] - 1;
        }
        blockShape[i] = hi - range[i].min + 1;
    }
    std::vector<std::size_t> idx(rank, 0);
    while (true) {
        std::size_t flat = 0;
        for (std::size_t i = 0; i < rank; ++i) flat = flat * shape[i] + range[i].min + idx[i];
        f(flat);
        std::size_t d = rank;
        while (d > 0) {
            --d;
            if (++idx[d] < blockShape[d]) break;
            idx[d] = 0;
            if (d == 0) return true;
        }
        if (rank == 0) return true;
    }
}

template <class T>
StatusCode readArray(const Variant& v, const std::vector<T>& arr,
                     const std::vector<NumericRange::Dimension>& range, Variant& out) {
    std::vector<std::size_t> shape;
    if (!shapeOf(v, arr.size(), shape)) return status::BadIndexRangeNoData;
    const bool bytes = kIsByteSequence<T>;
    std::size_t rank = shape.size();
    bool inner = false;  // one extra dimension indexing the bytes of each element
    if (range.size() == rank + 1 && bytes)
        inner = true;
    else if (range.size() != rank)
        return status::BadIndexRangeNoData;
    std::vector<T> result;
    std::vector<std::size_t> block;
    bool ok = forEachInBlock(shape, range, block, true,
                             [&](std::size_t flat) { result.push_back(arr[flat]); });
    if (!ok) return status::BadIndexRangeNoData;
    if constexpr (kIsByteSequence<T>) {
        if (inner) {
            const auto& d = range.back();
            for (auto& e : result) {
                T cut;
                if (!sliceBytes(e, d, cut)) cut = T{};
                e = std::move(cut);
            }
        }
    }
    out = Variant();
    out.setArray(std::move(result));
    if (rank > 1) {
        std::vector<Int32> dims;
        for (auto b : block) dims.push_back(static_cast<Int32>(b));
        out.setArrayDimensions(std::move(dims));
    }
    return kGood;
}

template <class T>
StatusCode writeArray(Variant& target, std::vector<T>& arr,
                      const std::vector<NumericRange::Dimension>& range, const Variant& source) {
    const std::vector<T>* src = source.array<T>();
    std::vector<std::size_t> shape;
    if (!shapeOf(target, arr.size(), shape)) return status::BadIndexRangeNoData;
    const std::size_t rank = shape.size();
    if constexpr (kIsByteSequence<T>) {
        if (range.size() == rank + 1) {
            // Replace bytes inside each selected element.
            if (src == nullptr) return status::BadTypeMismatch;
            std::vector<std::size_t> block;
            std::vector<std::size_t> flats;
            if (!forEachInBlock(shape, range, block, false,
                                [&](std::size_t f) { flats.push_back(f); }))
                return status::BadIndexRangeNoData;
            if (src->size() != flats.size()) return status::BadIndexRangeNoData;
            const auto& d = range.back();
            for (std::size_t i = 0; i < flats.size(); ++i) {
                std::string_view dst = bytesOf(arr[flats[i]]);
                std::string_view s = bytesOf((*src)[i]);
                if (d.max >= dst.size() || s.size() != d.count())
                    return status::BadIndexRangeNoData;
            }
            for (std::size_t i = 0; i < flats.size(); ++i)
                replaceBytes(arr[flats[i]], d.min, d.count(), bytesOf((*src)[i]));
            return kGood;
        }
    }
    if (src == nullptr) return status::BadTypeMismatch;
    if (range.size() != rank) return status::BadIndexRangeNoData;
    std::vector<std::size_t> block;
    std::vector<std::size_t> flats;
    if (!forEachInBlock(shape, range, block, false, [&](std::size_t f) { flats.push_back(f); }))
        return status::BadIndexRangeNoData;
    if (src->size() != flats.size()) return status::BadIndexRangeNoData;
    const auto& sdims = source.arrayDimensions();
    if (sdims.size() > 1) {
        if (sdims.size() != block.size()) return status::BadIndexRangeNoData;
        for (std::size_t i = 0; i < block.size(); ++i)
            if (static_cast<std::size_t>(sdims[i]) != block[i]) return status::BadIndexRangeNoData;
    }
    for (std::size_t i = 0; i < flats.size(); ++i) arr[flats[i]] = (*src)[i];
    return kGood;
}

}  // namespace

std::optional<NumericRange> NumericRange::parse(std::string_view text) {
    std::vector<Dimension> dims;
    if (text.empty()) return NumericRange{};
    std::size_t pos = 0;
    while (true) {
        std::size_t comma = text.find(',', pos);
        std::string_view part = text.substr(
            pos, comma == std::string_view::npos ? std::string_view::npos : comma - pos);
        Dimension d;
        std::size_t colon = part.find(':');
        if (colon == std::string_view::npos) {
            if (!parseIndex(part, d.min)) return std::nullopt;
            d.max = d.min;
        } else {
            if (!parseIndex(part.substr(0, colon), d.min) ||
                !parseIndex(part.substr(colon + 1), d.max) || d.min >= d.max)
                return std::nullopt;
        }
        dims.push_back(d);
        if (comma == std::string_view::npos) break;
        pos = comma + 1;
    }
    return NumericRange(std::move(dims));
}

std::string NumericRange::toString() const {
    std::string s;
    for (std::size_t i = 0; i < dims_.size(); ++i) {
        if (i) s += ',';
        s += std::to_string(dims_[i].min);
        if (dims_[i].max != dims_[i].min) {
            s += ':';
            s += std::to_string(dims_[i].max);
        }
    }
    return s;
}

StatusCode readRange(const Variant& value, const NumericRange& range, Variant& out) {
    if (range.empty()) {
        out = value;
        return kGood;
    }
    const auto& dims = range.dimensions();
    if (value.isScalar()) {
        if (dims.size() != 1) return status::BadIndexRangeNoData;
        if (const String* s = value.scalar<String>()) {
            String cut;
            if (!sliceBytes(*s, dims[0], cut)) return status::BadIndexRangeNoData;
            out = Variant(std::move(cut));
            return kGood;
        }
        if (const ByteString* b = value.scalar<ByteString>()) {
            ByteString cut;
            if (!sliceBytes(*b, dims[0], cut)) return status::BadIndexRangeNoData;
            out = Variant(std::move(cut));
            return kGood;
        }
        return status::BadIndexRangeNoData;
    }
    if (!value.isArray()) return status::BadIndexRangeNoData;
    return std::visit(
        [&](const auto& stored) -> StatusCode {
            using S = std::decay_t<decltype(stored)>;
            if constexpr (IsVector<S>::value) {
                return readArray(value, stored, dims, out);
            } else {
                return status::BadIndexRangeNoData;
            }
        },
        value.storage());
}

StatusCode writeRange(Variant& target, const NumericRange& range, const Variant& source) {
    if (range.empty()) {
        target = source;
        return kGood;
    }
    const auto& dims = range.dimensions();
    if (target.isScalar()) {
        if (dims.size() != 1) return status::BadIndexRangeNoData;
        auto replace = [&](auto& dst, const auto* src) -> StatusCode {
            if (src == nullptr) return status::BadTypeMismatch;
            std::string_view d = bytesOf(dst);
            std::string_view s = bytesOf(*src);
            if (dims[0].max >= d.size() || s.size() != dims[0].count())
                return status::BadIndexRangeNoData;
            replaceBytes(dst, dims[0].min, dims[0].count(), s);
            return kGood;
        };
        auto& st = target.storage();
        if (auto* s = std::get_if<String>(&st)) return replace(*s, source.scalar<String>());
        if (auto* b = std::get_if<ByteString>(&st)) return replace(*b, source.scalar<ByteString>());
        return status::BadIndexRangeNoData;
    }
    if (!target.isArray()) return status::BadIndexRangeNoData;
    if (!source.isArray() && !(source.isScalar() && (source.type() == BuiltinType::String ||
                                                     source.type() == BuiltinType::ByteString)))
        return status::BadTypeMismatch;
    if (source.type() != target.type()) return status::BadTypeMismatch;
    return std::visit(
        [&](auto& stored) -> StatusCode {
            using S = std::decay_t<decltype(stored)>;
            if constexpr (IsVector<S>::value) {
                return writeArray(target, stored, dims, source);
            } else {
                return status::BadIndexRangeNoData;
            }
        },
        target.storage());
}

}  // namespace pnp::ua::server
