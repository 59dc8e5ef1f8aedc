"use strict";
// Shared definition of the pnp demo namespace, used by node_server.js (to build
// the same address space as `pnp ua serve`) and node_client.js (to test it).
//
// Spec (must match the C++ server):
//   - demo namespace URI "urn:pnp:demo" (index looked up from NamespaceArray)
//   - Object  ns=<demo>;s=Demo  (BrowseName "Demo", Organizes from ObjectsFolder i=85)
//   - Variables ns=<demo>;s=Scalar.<T> (ValueRank -1) and s=Array.<T> (ValueRank 1)
//     for every built-in type T below, AccessLevel CurrentRead|CurrentWrite
//   - Methods ns=<demo>;s=Demo.Echo (Data:ByteString -> Data:ByteString)
//             ns=<demo>;s=Demo.Add  (a:Int32, b:Int32 -> sum:Int32)

const {
    DataType,
    Variant,
    VariantArrayType,
    NodeIdType,
    ExpandedNodeId,
    QualifiedName,
    LocalizedText,
    DataValue,
    DiagnosticInfo,
    StatusCodes,
    Range,
    coerceNodeId,
} = require("node-opcua");

const DEMO_NS_URI = "urn:pnp:demo";

// Helper: a Range{low,high} (ns0 DataType i=884, binary encoding i=886).
const range = (low, high) => new Range({ low, high });

// Each entry:
//   name         built-in type name (the T in Scalar.T / Array.T)
//   dataType     node-opcua DataType enum value used in the Variant
//   typeNodeId   numeric ns0 id of the variable's DataType attribute
//   scalar()     non-default scalar test value
//   array()      non-default 1-D array test value
//   scalarDefault() / arrayDefault()   initial values (node_server.js only)
//
// Values are factories so every use gets a fresh object.
const TYPES = [
    {
        name: "Boolean", dataType: DataType.Boolean, typeNodeId: 1,
        scalar: () => true, array: () => [true, false, true],
        scalarDefault: () => false,
    },
    {
        name: "SByte", dataType: DataType.SByte, typeNodeId: 2,
        scalar: () => -42, array: () => [-128, 0, 127],
        scalarDefault: () => 0,
    },
    {
        name: "Byte", dataType: DataType.Byte, typeNodeId: 3,
        scalar: () => 200, array: () => [0, 1, 255],
        scalarDefault: () => 0,
    },
    {
        name: "Int16", dataType: DataType.Int16, typeNodeId: 4,
        scalar: () => -1234, array: () => [-32768, 0, 32767],
        scalarDefault: () => 0,
    },
    {
        name: "UInt16", dataType: DataType.UInt16, typeNodeId: 5,
        scalar: () => 54321, array: () => [0, 1, 65535],
        scalarDefault: () => 0,
    },
    {
        name: "Int32", dataType: DataType.Int32, typeNodeId: 6,
        scalar: () => -123456789, array: () => [-2147483648, 0, 2147483647],
        scalarDefault: () => 0,
    },
    {
        name: "UInt32", dataType: DataType.UInt32, typeNodeId: 7,
        scalar: () => 4000000000, array: () => [0, 1, 4294967295],
        scalarDefault: () => 0,
    },
    {
        // node-opcua represents 64-bit integers as [high32, low32]
        name: "Int64", dataType: DataType.Int64, typeNodeId: 8,
        scalar: () => [0x12345678, 0x9abcdef0],
        array: () => [[0xffffffff, 0xfffffffb] /* -5 */, [0, 0], [0x7fffffff, 0xffffffff]],
        scalarDefault: () => [0, 0],
    },
    {
        name: "UInt64", dataType: DataType.UInt64, typeNodeId: 9,
        scalar: () => [0xfedcba98, 0x76543210],
        array: () => [[0, 0], [0, 1], [0xffffffff, 0xffffffff]],
        scalarDefault: () => [0, 0],
    },
    {
        // values exactly representable as float32
        name: "Float", dataType: DataType.Float, typeNodeId: 10,
        scalar: () => 3.5, array: () => [-2.25, 0.5, 1024.75],
        scalarDefault: () => 0,
    },
    {
        name: "Double", dataType: DataType.Double, typeNodeId: 11,
        scalar: () => Math.PI, array: () => [1.5, -1e300, 6.02214076e23],
        scalarDefault: () => 0,
    },
    {
        name: "String", dataType: DataType.String, typeNodeId: 12,
        scalar: () => "h\u00e9llo \u2713 pnp", array: () => ["a", "", "\u00fc\u00f1\u00ed"],
        scalarDefault: () => "",
    },
    {
        // millisecond precision (JS Date); OPC UA DateTime is 100 ns ticks
        name: "DateTime", dataType: DataType.DateTime, typeNodeId: 13,
        scalar: () => new Date("2024-05-06T07:08:09.123Z"),
        array: () => [new Date("2001-01-01T00:00:00.000Z"), new Date("2030-12-31T23:59:59.999Z")],
        scalarDefault: () => new Date("1601-01-01T00:00:00.000Z"),
    },
    {
        name: "Guid", dataType: DataType.Guid, typeNodeId: 14,
        scalar: () => "72962B91-FA75-4AE6-8D28-B404DC7DAF63",
        array: () => ["00000000-0000-0000-0000-000000000001", "0123ABCD-4567-89EF-0123-456789ABCDEF"],
        scalarDefault: () => "00000000-0000-0000-0000-000000000000",
    },
    {
        name: "ByteString", dataType: DataType.ByteString, typeNodeId: 15,
        scalar: () => Buffer.from([0x00, 0x01, 0x02, 0xfe, 0xff]),
        array: () => [Buffer.from("abc"), Buffer.from([0]), Buffer.from([0xde, 0xad, 0xbe, 0xef])],
        scalarDefault: () => Buffer.alloc(0),
    },
    {
        name: "XmlElement", dataType: DataType.XmlElement, typeNodeId: 16,
        scalar: () => "<pnp a=\"1\">demo</pnp>", array: () => ["<a/>", "<b>x</b>"],
        scalarDefault: () => "",
    },
    {
        name: "NodeId", dataType: DataType.NodeId, typeNodeId: 17,
        scalar: () => coerceNodeId("ns=1;s=pnp.Scalar"),
        array: () => [
            coerceNodeId("i=2253"),
            coerceNodeId("ns=1;s=hello"),
            coerceNodeId("ns=1;g=72962B91-FA75-4AE6-8D28-B404DC7DAF63"),
            coerceNodeId("ns=1;b=AQID"),
            coerceNodeId("ns=3;i=70000"),
        ],
        scalarDefault: () => coerceNodeId("i=0"),
    },
    {
        name: "ExpandedNodeId", dataType: DataType.ExpandedNodeId, typeNodeId: 18,
        scalar: () => new ExpandedNodeId(NodeIdType.NUMERIC, 1234, 0, "urn:pnp:other", 0),
        array: () => [
            new ExpandedNodeId(NodeIdType.NUMERIC, 85, 0, null, 0),
            new ExpandedNodeId(NodeIdType.STRING, "x.y", 1, null, 2),
        ],
        scalarDefault: () => new ExpandedNodeId(NodeIdType.NUMERIC, 0, 0, null, 0),
    },
    {
        name: "StatusCode", dataType: DataType.StatusCode, typeNodeId: 19,
        scalar: () => StatusCodes.BadOutOfRange,
        array: () => [StatusCodes.Good, StatusCodes.UncertainInitialValue, StatusCodes.BadTimeout],
        scalarDefault: () => StatusCodes.Good,
    },
    {
        name: "QualifiedName", dataType: DataType.QualifiedName, typeNodeId: 20,
        scalar: () => new QualifiedName({ namespaceIndex: 1, name: "Qn" }),
        array: () => [new QualifiedName({ namespaceIndex: 0, name: "A" }), new QualifiedName({ namespaceIndex: 1, name: "B" })],
        scalarDefault: () => new QualifiedName({ namespaceIndex: 0, name: "" }),
    },
    {
        name: "LocalizedText", dataType: DataType.LocalizedText, typeNodeId: 21,
        scalar: () => new LocalizedText({ locale: "en-US", text: "hello" }),
        array: () => [new LocalizedText({ locale: "de", text: "hallo" }), new LocalizedText({ text: "no locale" })],
        scalarDefault: () => new LocalizedText({ text: "" }),
    },
    {
        // Payload: Range{low,high}; variable DataType is Structure (i=22)
        name: "ExtensionObject", dataType: DataType.ExtensionObject, typeNodeId: 22,
        scalar: () => range(-1.5, 99.25),
        array: () => [range(0, 1), range(-10, 10)],
        scalarDefault: () => range(0, 0),
    },
    {
        name: "DataValue", dataType: DataType.DataValue, typeNodeId: 23,
        scalar: () => new DataValue({
            value: { dataType: DataType.Double, value: 1.25 },
            statusCode: StatusCodes.UncertainLastUsableValue,
            sourceTimestamp: new Date("2024-01-02T03:04:05.678Z"),
        }),
        array: () => [
            new DataValue({ value: { dataType: DataType.Int32, value: 7 } }),
            new DataValue({ value: { dataType: DataType.String, value: "dv" }, statusCode: StatusCodes.BadNoData }),
        ],
        scalarDefault: () => new DataValue({}),
    },
    {
        // Variable DataType BaseDataType (i=24). A scalar Variant cannot contain a
        // Variant, so the scalar test value is any concrete type (Double);
        // the array is a Variant[] with mixed element types.
        name: "Variant", dataType: DataType.Variant, typeNodeId: 24,
        scalarVariant: () => new Variant({ dataType: DataType.Double, value: 2.5 }),
        array: () => [
            new Variant({ dataType: DataType.Int32, value: 1 }),
            new Variant({ dataType: DataType.String, value: "two" }),
            new Variant({ dataType: DataType.Boolean, value: true }),
        ],
        scalarDefaultVariant: () => new Variant({ dataType: DataType.Int32, value: 0 }),
    },
    {
        name: "DiagnosticInfo", dataType: DataType.DiagnosticInfo, typeNodeId: 25,
        scalar: () => new DiagnosticInfo({
            symbolicId: 3, localizedText: 5, additionalInfo: "info", innerStatusCode: StatusCodes.BadTimeout,
        }),
        array: () => [new DiagnosticInfo({ symbolicId: 1 }), new DiagnosticInfo({ additionalInfo: "x" })],
        scalarDefault: () => new DiagnosticInfo({}),
    },
];

function scalarVariant(t) {
    if (t.scalarVariant) return t.scalarVariant();
    return new Variant({ dataType: t.dataType, arrayType: VariantArrayType.Scalar, value: t.scalar() });
}

function arrayVariant(t) {
    return new Variant({ dataType: t.dataType, arrayType: VariantArrayType.Array, value: t.array() });
}

function scalarDefaultVariant(t) {
    if (t.scalarDefaultVariant) return t.scalarDefaultVariant();
    return new Variant({ dataType: t.dataType, arrayType: VariantArrayType.Scalar, value: t.scalarDefault() });
}

function arrayDefaultVariant(t) {
    return new Variant({ dataType: t.dataType, arrayType: VariantArrayType.Array, value: [] });
}

module.exports = {
    DEMO_NS_URI,
    TYPES,
    scalarVariant,
    arrayVariant,
    scalarDefaultVariant,
    arrayDefaultVariant,
};
