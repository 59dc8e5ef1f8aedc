#include "fill_builtins.hpp"

#include "ua/types/ns0_types.hpp"

namespace pnp::ua::testgen {

void fill(Boolean& v) { v = true; }
void fill(SByte& v) { v = -5; }
void fill(Byte& v) { v = 0xA5; }
void fill(Int16& v) { v = -1234; }
void fill(UInt16& v) { v = 0xBEEF; }
void fill(Int32& v) { v = -123456; }
void fill(UInt32& v) { v = 0xDEADBEEF; }
void fill(Int64& v) { v = -1234567890123LL; }
void fill(UInt64& v) { v = 0xFEEDFACECAFEBEEFULL; }
void fill(Float& v) { v = 1.5f; }
void fill(Double& v) { v = -2.25; }
void fill(String& v) { v = "str\xC3\xA4"; }
void fill(DateTime& v) { v = DateTime{132000000000000000LL}; }
void fill(Guid& v) {
    v = Guid{0x72962B91, 0xFA75, 0x4AE6, {0x8D, 0x28, 0xB4, 0x04, 0xDC, 0x7D, 0xAF, 0x63}};
}
void fill(ByteString& v) { v = ByteString(std::string("\x00\x01\xFF", 3)); }
void fill(XmlElement& v) { v = XmlElement{"<a>1</a>"}; }
void fill(NodeId& v) { v = NodeId(2, "Demo.Node"); }
void fill(ExpandedNodeId& v) { v = ExpandedNodeId(NodeId(3, 4242), "urn:test", 1); }
void fill(StatusCode& v) { v = StatusCode{0x80340000}; }
void fill(QualifiedName& v) { v = QualifiedName{1, "Name"}; }
void fill(LocalizedText& v) { v = LocalizedText("en", "Text"); }

void fill(ExtensionObject& v) {
    Range r;
    r.low = -1.5;
    r.high = 99.0;
    v = toExtensionObject(r);
}

void fill(DataValue& v) {
    v = DataValue(Variant(Int32{7}));
    v.status = StatusCode{0x40000000};
    v.sourceTimestamp = DateTime{132000000000000001LL};
    v.sourcePicoseconds = 10;
    v.serverTimestamp = DateTime{132000000000000002LL};
    v.serverPicoseconds = 20;
}

void fill(Variant& v) { v = Variant(String("variant")); }

void fill(DiagnosticInfo& v) {
    v = DiagnosticInfo{};
    v.symbolicId = 1;
    v.localizedText = 2;
    v.additionalInfo = "info";
    v.innerStatusCode = StatusCode{0x80010000};
}

}  // namespace pnp::ua::testgen
