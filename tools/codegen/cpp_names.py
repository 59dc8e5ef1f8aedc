"""C++ naming rules of the generated code (documented in tools/codegen/README.md)."""

from __future__ import annotations

import re

CPP_KEYWORDS = frozenset(
    """
    alignas alignof and and_eq asm auto bitand bitor bool break case catch char char8_t char16_t
    char32_t class compl concept const consteval constexpr constinit const_cast continue
    co_await co_return co_yield decltype default delete do double dynamic_cast else enum
    explicit export extern false float for friend goto if inline int long mutable namespace new
    noexcept not not_eq nullptr operator or or_eq private protected public register
    reinterpret_cast requires return short signed sizeof static static_assert static_cast struct
    switch template this thread_local throw true try typedef typeid typename union unsigned using
    virtual void volatile wchar_t while xor xor_eq final override import module
    """.split()
)

# Macros of the C/C++ standard library that an identifier must not spell.
STD_MACROS = frozenset(
    "NULL EOF TRUE FALSE DOMAIN OVERFLOW UNDERFLOW errno assert stdin stdout stderr "
    "INFINITY NAN EDOM ERANGE SIGINT".split()
)

# Identifiers of namespace pnp::ua declared by the hand-written headers (ua/types/*.hpp).
# A generated DataType with one of these names gets a suffix (see type_name()).
RESERVED_UA_NAMES = frozenset(
    """
    Boolean SByte Byte Int16 UInt16 Int32 UInt32 Int64 UInt64 Float Double String DateTime Guid
    ByteString XmlElement NodeId ExpandedNodeId StatusCode QualifiedName LocalizedText
    ExtensionObject DataValue Variant DiagnosticInfo BuiltinType BuiltinTypeOf IdType Box
    DecodeLimits DecodeError Buffer BinaryEncoder BinaryDecoder DataTypeInfo DataTypeCodec
    detail status ns0 kBuiltinTypeCount toString encode decode toJson
    """.split()
)


def is_identifier(s: str) -> bool:
    return re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", s) is not None and "__" not in s


def safe(s: str) -> str:
    """Makes an identifier out of s: invalid characters become '_', keywords get a '_'."""
    s = re.sub(r"[^A-Za-z0-9_]", "_", s)
    s = re.sub(r"_+", "_", s)
    if not s or s[0].isdigit():
        s = "N" + s
    if s.startswith("_"):
        s = "N" + s
    if s in CPP_KEYWORDS or s in STD_MACROS:
        s += "_"
    return s


def field_name(xml_name: str) -> str:
    """Structure field: the XML name with its first letter lower-cased ("RequestHeader" ->
    "requestHeader"); C++ keywords get a trailing '_' ("Default" -> "default_")."""
    s = safe(xml_name)
    s = s[0].lower() + s[1:]
    if s in CPP_KEYWORDS or s in STD_MACROS:
        s += "_"
    return s


def type_name(symbolic: str, kind: str) -> str:
    """DataType: its SymbolicName (ThreeDVector) or BrowseName. A name already taken by the
    hand-written built-in types (IdType) gets the suffix 'Enum' for enumerations, 'DataType'
    otherwise (ns0 IdType -> IdTypeEnum)."""
    s = safe(symbolic)
    if s in RESERVED_UA_NAMES:
        s += "Enum" if kind == "enum" else "DataType"
    return s


def enumerator_name(xml_name: str) -> str:
    return safe(xml_name)


def option_bits_namespace(type_cpp_name: str) -> str:
    """Option sets over integers: `using AccessLevelType = Byte;` and the bit masks in
    `namespace AccessLevelTypeBits { inline constexpr Byte CurrentRead = 0x1; ... }`."""
    return type_cpp_name + "Bits"


def cpp_string(s: str) -> str:
    """A C++ string literal (ASCII, escaped)."""
    out = []
    for ch in s:
        o = ord(ch)
        if ch == "\\":
            out.append("\\\\")
        elif ch == '"':
            out.append('\\"')
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif 32 <= o < 127:
            out.append(ch)
        elif o < 0x80:
            out.append(f"\\x{o:02x}")
        else:
            # UTF-8 bytes, as octal escapes so that following hex digits cannot merge.
            out.extend(f"\\{b:03o}" for b in ch.encode("utf-8"))
    return '"' + "".join(out) + '"'


def comment_text(s: str, limit: int = 300) -> str:
    """One line of text safe to put into a // comment."""
    s = " ".join(s.split())
    s = s.encode("ascii", "replace").decode("ascii")
    if len(s) > limit:
        s = s[: limit - 3].rstrip() + "..."
    return s.replace("\\", "/")  # a trailing backslash would continue the comment
