// Dynamic structure codec (see structure_codec.hpp).
#include "ua/server/structure_codec.hpp"

#include <stdexcept>

namespace pnp::ua::server {

namespace {

// Calls f.template operator()<T>() with the C++ type that holds built-in type b.
template <class F>
decltype(auto) withBuiltin(BuiltinType b, F&& f) {
    switch (b) {
        case BuiltinType::Boolean:
            return f.template operator()<Boolean>();
        case BuiltinType::SByte:
            return f.template operator()<SByte>();
        case BuiltinType::Byte:
            return f.template operator()<Byte>();
        case BuiltinType::Int16:
            return f.template operator()<Int16>();
        case BuiltinType::UInt16:
            return f.template operator()<UInt16>();
        case BuiltinType::Int32:
            return f.template operator()<Int32>();
        case BuiltinType::UInt32:
            return f.template operator()<UInt32>();
        case BuiltinType::Int64:
            return f.template operator()<Int64>();
        case BuiltinType::UInt64:
            return f.template operator()<UInt64>();
        case BuiltinType::Float:
            return f.template operator()<Float>();
        case BuiltinType::Double:
            return f.template operator()<Double>();
        case BuiltinType::String:
            return f.template operator()<String>();
        case BuiltinType::DateTime:
            return f.template operator()<DateTime>();
        case BuiltinType::Guid:
            return f.template operator()<Guid>();
        case BuiltinType::ByteString:
            return f.template operator()<ByteString>();
        case BuiltinType::XmlElement:
            return f.template operator()<XmlElement>();
        case BuiltinType::NodeId:
            return f.template operator()<NodeId>();
        case BuiltinType::ExpandedNodeId:
            return f.template operator()<ExpandedNodeId>();
        case BuiltinType::StatusCode:
            return f.template operator()<StatusCode>();
        case BuiltinType::QualifiedName:
            return f.template operator()<QualifiedName>();
        case BuiltinType::LocalizedText:
            return f.template operator()<LocalizedText>();
        case BuiltinType::ExtensionObject:
            return f.template operator()<ExtensionObject>();
        case BuiltinType::DataValue:
            return f.template operator()<DataValue>();
        case BuiltinType::DiagnosticInfo:
            return f.template operator()<DiagnosticInfo>();
        default:
            break;
    }
    throw std::invalid_argument("no built-in type " + std::string(toString(b)));
}

class Encoder {
  public:
    Encoder(BinaryEncoder& e, const StructureLayoutLookup& lookup) : e_(e), lookup_(lookup) {}

    void structure(const StructureLayout& layout, const StructureValue& value, int depth) {
        if (depth > 32) throw std::invalid_argument("structures nested too deeply");
        const auto& fields = layout.fields;
        if (layout.form == StructureLayout::Form::Union) {
            for (std::size_t i = 0; i < fields.size(); ++i) {
                const Variant* v = value.field(fields[i].name);
                if (v != nullptr && !v->isEmpty()) {
                    e_.number<UInt32>(static_cast<UInt32>(i + 1));
                    field(fields[i], *v, depth);
                    return;
                }
            }
            e_.number<UInt32>(0);
            return;
        }
        if (layout.form == StructureLayout::Form::WithOptionalFields) {
            UInt32 mask = 0;
            int bit = 0;
            for (const auto& f : fields) {
                if (!f.isOptional) continue;
                if (bit == 32) throw std::invalid_argument("more than 32 optional fields");
                const Variant* v = value.field(f.name);
                if (v != nullptr && !v->isEmpty()) mask |= UInt32{1} << bit;
                ++bit;
            }
            e_.number<UInt32>(mask);
        }
        static const Variant kAbsent;
        for (const auto& f : fields) {
            const Variant* v = value.field(f.name);
            if (f.isOptional && layout.form == StructureLayout::Form::WithOptionalFields &&
                (v == nullptr || v->isEmpty()))
                continue;
            field(f, v != nullptr ? *v : kAbsent, depth);
        }
    }

  private:
    [[noreturn]] static void mismatch(const StructureFieldLayout& f) {
        throw std::invalid_argument("field " + f.name + ": value does not fit DataType " +
                                    f.dataType.toString());
    }

    void field(const StructureFieldLayout& f, const Variant& v, int depth) {
        if (f.kind == StructureFieldLayout::Kind::Variant) {
            if (f.valueRank >= 1) {
                // An array of Variants: a one-dimensional array value is split into elements.
                const auto* items = v.array<Variant>();
                if (items == nullptr && !v.isEmpty()) mismatch(f);
                encode(e_, items != nullptr ? *items : std::vector<Variant>{});
            } else {
                encode(e_, v);
            }
            return;
        }
        if (f.kind == StructureFieldLayout::Kind::Structure) {
            auto nested = lookup_ ? lookup_(f.dataType) : nullptr;
            if (!nested) mismatch(f);
            auto one = [&](const ExtensionObject* x) {
                if (x == nullptr || x->empty()) {
                    structure(*nested, {}, depth + 1);
                } else if (x->encoding != ExtensionObject::Encoding::Binary) {
                    mismatch(f);
                } else {
                    e_.raw(x->body.data(), x->body.size());
                }
            };
            if (f.valueRank >= 1) {
                const auto* items = v.array<ExtensionObject>();
                if (items == nullptr && !v.isEmpty()) mismatch(f);
                if (items == nullptr) {
                    e_.number<Int32>(-1);
                    return;
                }
                e_.number<Int32>(static_cast<Int32>(items->size()));
                for (const auto& x : *items) one(&x);
            } else {
                if (!v.isEmpty() && v.scalar<ExtensionObject>() == nullptr) mismatch(f);
                one(v.scalar<ExtensionObject>());
            }
            return;
        }
        const BuiltinType b = f.kind == StructureFieldLayout::Kind::ExtensionObject
                                  ? BuiltinType::ExtensionObject
                                  : f.builtin;
        withBuiltin(b, [&]<class T>() {
            if (f.valueRank >= 1) {
                const auto* items = v.array<T>();
                if (items == nullptr && !v.isEmpty()) mismatch(f);
                if (items == nullptr) {
                    e_.number<Int32>(-1);
                } else {
                    encode(e_, *items);
                }
            } else {
                const T* x = v.scalar<T>();
                if (x == nullptr && !v.isEmpty()) mismatch(f);
                encode(e_, x != nullptr ? *x : T{});
            }
        });
    }

    BinaryEncoder& e_;
    const StructureLayoutLookup& lookup_;
};

class Decoder {
  public:
    Decoder(BinaryDecoder& d, const StructureLayoutLookup& lookup) : d_(d), lookup_(lookup) {}

    StructureValue structure(const StructureLayout& layout) {
        BinaryDecoder::Nested guard(d_);
        StructureValue out;
        const auto& fields = layout.fields;
        out.fields.reserve(fields.size());
        if (layout.form == StructureLayout::Form::Union) {
            const UInt32 chosen = d_.number<UInt32>();
            if (chosen > fields.size()) BinaryDecoder::fail("union switch field out of range");
            for (std::size_t i = 0; i < fields.size(); ++i)
                out.fields.emplace_back(fields[i].name,
                                        i + 1 == chosen ? field(fields[i]) : Variant());
            return out;
        }
        UInt32 mask = 0xFFFFFFFFu;
        if (layout.form == StructureLayout::Form::WithOptionalFields) mask = d_.number<UInt32>();
        int bit = 0;
        for (const auto& f : fields) {
            bool present = true;
            if (f.isOptional && layout.form == StructureLayout::Form::WithOptionalFields) {
                if (bit == 32) BinaryDecoder::fail("more than 32 optional fields");
                present = ((mask >> bit++) & 1u) != 0;
            }
            out.fields.emplace_back(f.name, present ? field(f) : Variant());
        }
        return out;
    }

  private:
    Variant field(const StructureFieldLayout& f) {
        if (f.kind == StructureFieldLayout::Kind::Variant) {
            if (f.valueRank >= 1) {
                std::vector<Variant> items;
                decode(d_, items);
                return Variant(std::move(items));
            }
            Variant v;
            decode(d_, v);
            return v;
        }
        if (f.kind == StructureFieldLayout::Kind::Structure) {
            auto nested = lookup_ ? lookup_(f.dataType) : nullptr;
            if (!nested) BinaryDecoder::fail("no layout for DataType " + f.dataType.toString());
            auto one = [&] {
                const Byte* start = d_.position();
                structure(*nested);
                ExtensionObject x;
                x.typeId = nested->binaryEncoding;
                x.encoding = ExtensionObject::Encoding::Binary;
                x.body.assign(reinterpret_cast<const char*>(start),
                              static_cast<std::size_t>(d_.position() - start));
                return x;
            };
            if (f.valueRank >= 1) {
                const std::size_t n = d_.arrayLength(1);
                std::vector<ExtensionObject> items;
                items.reserve(n);
                for (std::size_t i = 0; i < n; ++i) items.push_back(one());
                return Variant(std::move(items));
            }
            return Variant(one());
        }
        const BuiltinType b = f.kind == StructureFieldLayout::Kind::ExtensionObject
                                  ? BuiltinType::ExtensionObject
                                  : f.builtin;
        return withBuiltin(b, [&]<class T>() -> Variant {
            if (f.valueRank >= 1) {
                std::vector<T> items;
                decode(d_, items);
                return Variant(std::move(items));
            }
            T x{};
            decode(d_, x);
            return Variant(std::move(x));
        });
    }

    BinaryDecoder& d_;
    const StructureLayoutLookup& lookup_;
};

}  // namespace

std::string encodeStructure(const StructureLayout& layout, const StructureValue& value,
                            const StructureLayoutLookup& lookup) {
    Buffer b;
    BinaryEncoder e(b);
    Encoder(e, lookup).structure(layout, value, 0);
    return std::string(reinterpret_cast<const char*>(b.data()), b.size());
}

StructureValue decodeStructure(const StructureLayout& layout, const Byte* body, std::size_t size,
                               const StructureLayoutLookup& lookup, const DecodeLimits& limits) {
    BinaryDecoder d(body, size, limits);
    StructureValue v = Decoder(d, lookup).structure(layout);
    if (d.remaining() != 0) BinaryDecoder::fail("structure body has trailing bytes");
    return v;
}

Variant arrayOf(BuiltinType type, std::vector<Variant> scalars) {
    return withBuiltin(type, [&]<class T>() {
        std::vector<T> out;
        out.reserve(scalars.size());
        for (Variant& v : scalars) {
            const T* x = v.scalar<T>();
            if (x == nullptr)
                throw std::invalid_argument("array element is not a " +
                                            std::string(toString(type)));
            out.push_back(*x);
        }
        return Variant(std::move(out));
    });
}

Variant defaultValueOf(BuiltinType type) {
    if (type == BuiltinType::Null || type == BuiltinType::Variant) return Variant();
    return withBuiltin(type, []<class T>() { return Variant(T{}); });
}

}  // namespace pnp::ua::server
