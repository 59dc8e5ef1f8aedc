#!/usr/bin/env python3
"""Build-time NodeSet2 compiler for pnp (Python 3 standard library only).

Turns an official UANodeSet XML file (e.g. Opc.Ua.NodeSet2.xml) into a compact binary blob
and emits it as a C++ source file that is compiled into pnp_ua_server. At start-up the
server decodes the blob into its address space (src/ua/server/nodeset_loader.cpp).

Blob format ("PNPNSET" version 1). All integers are LEB128 varints unless stated;
"svarint" is zig-zag encoded. String references are indexes into the string table
(index 0 is always the empty string).

    magic      8 bytes  "PNPNSET1"
    valuesAt   4 bytes  little-endian offset of the values section from the blob start
    nodeCount  varint
    refCount   varint
    namespaces varint count, then count x (varint length, UTF-8 bytes)   [0] = UA namespace
    strings    varint count, then count x (varint length, UTF-8 bytes)
    nodes      nodeCount x node
    references refCount x (source node index, reference type node index, target node index)
    values     the encoded Values and DataTypeDefinitions, referenced by (offset, length)
               from the node records: kept apart so that start-up reads only the compact
               node and reference sections and the values are touched when first read

    node:
      nodeClass  byte   (Part 3 NodeClass value: 1 Object, 2 Variable, 4 Method, ...)
      nodeId     cnid   (compact NodeId, below)
      browseName varint namespace index, varint string
      displayName varint locale string, varint text string
      flags      varint
          0x0001 has description (varint locale, varint text follow)
          0x0002 has write masks (varint writeMask, varint userWriteMask follow)
          0x0004 isAbstract          0x0008 symmetric        0x0010 containsNoLoops
          0x0020 historizing         0x0040 executable       0x0080 userExecutable
          0x0100 has value           0x0200 has inverseName  0x0400 has definition
          0x0800 has arrayDimensions 0x1000 has minimumSamplingInterval
      per node class:
        Object, View:   byte eventNotifier
        Variable:       cnid dataType, svarint valueRank, byte accessLevel,
                        byte userAccessLevel, [f64 minimumSamplingInterval],
                        [varint n, n x varint arrayDimensions], [value]
        VariableType:   cnid dataType, svarint valueRank, [arrayDimensions], [value]
        ReferenceType:  [varint locale, varint text]  (inverseName)
        DataType:       [value]  (DataTypeDefinition)
      value: varint offset into the values section, varint length. Values are the OPC UA
      Binary encoding (Part 6 §5.2) of a Variant, DataTypeDefinitions that of an
      ExtensionObject, so the C++ side decodes them with its regular codec.

    cnid (compact NodeId): byte kind, then
        0: numeric in namespace 0     varint id
        1: numeric                    varint ns, varint id
        2: string                     varint ns, varint string
        3: guid                       varint ns, 16 bytes (OPC UA binary Guid)
        4: opaque                     varint ns, varint length, bytes

References are de-duplicated: a NodeSet may list a reference on both of its ends; the
blob holds each one once, forward, and the loader links both directions.
"""

import argparse
import base64
import datetime
import re
import struct
import sys
import time
import uuid
import xml.etree.ElementTree as ET

NS_NODESET = "{http://opcfoundation.org/UA/2011/03/UANodeSet.xsd}"
UA_URI = "http://opcfoundation.org/UA/"

NODE_CLASSES = {
    "UAObject": 1,
    "UAVariable": 2,
    "UAMethod": 4,
    "UAObjectType": 8,
    "UAVariableType": 16,
    "UAReferenceType": 32,
    "UADataType": 64,
    "UAView": 128,
}

BUILTIN = {
    "Boolean": 1, "SByte": 2, "Byte": 3, "Int16": 4, "UInt16": 5, "Int32": 6, "UInt32": 7,
    "Int64": 8, "UInt64": 9, "Float": 10, "Double": 11, "String": 12, "DateTime": 13,
    "Guid": 14, "ByteString": 15, "XmlElement": 16, "NodeId": 17, "ExpandedNodeId": 18,
    "StatusCode": 19, "QualifiedName": 20, "LocalizedText": 21, "ExtensionObject": 22,
    "DataValue": 23, "Variant": 24, "DiagnosticInfo": 25,
}
BUILTIN_NAME = {v: k for k, v in BUILTIN.items()}

# ns=0 DataType node ids that the compiler relies on.
DT_STRUCTURE = 22
DT_BASEDATATYPE = 24
DT_ENUMERATION = 29
HAS_SUBTYPE = 45
HAS_ENCODING = 38

class CompileError(Exception):
    pass


def local(tag):
    return tag.split("}", 1)[1] if "}" in tag else tag


# ---------------------------------------------------------------------------------------
# Node ids
# ---------------------------------------------------------------------------------------
NODEID_RE = re.compile(r"^(?:ns=(\d+);)?([isgb])=(.*)$", re.S)


class NodeId:
    __slots__ = ("ns", "kind", "value")

    def __init__(self, ns, kind, value):
        self.ns = ns
        self.kind = kind  # 'i', 's', 'g', 'b'
        self.value = value

    @staticmethod
    def parse(text):
        m = NODEID_RE.match(text.strip())
        if not m:
            raise CompileError("invalid NodeId %r" % text)
        ns = int(m.group(1) or 0)
        kind = m.group(2)
        v = m.group(3)
        if kind == "i":
            v = int(v)
        elif kind == "g":
            v = uuid.UUID(v)
        elif kind == "b":
            v = base64.b64decode(v)
        return NodeId(ns, kind, v)

    def key(self):
        return (self.ns, self.kind, self.value)

    def __eq__(self, o):
        return isinstance(o, NodeId) and self.key() == o.key()

    def __hash__(self):
        return hash(self.key())

    def __repr__(self):
        p = "ns=%d;" % self.ns if self.ns else ""
        return "%s%s=%s" % (p, self.kind, self.value)

    def is_null(self):
        return self.ns == 0 and self.kind == "i" and self.value == 0


NULL_NODEID = NodeId(0, "i", 0)


# ---------------------------------------------------------------------------------------
# OPC UA Binary encoding (Part 6 §5.2) of the built-in types
# ---------------------------------------------------------------------------------------
class Bin:
    def __init__(self):
        self.b = bytearray()

    def u8(self, v):
        self.b += struct.pack("<B", v)

    def i8(self, v):
        self.b += struct.pack("<b", v)

    def u16(self, v):
        self.b += struct.pack("<H", v)

    def i16(self, v):
        self.b += struct.pack("<h", v)

    def u32(self, v):
        self.b += struct.pack("<I", v)

    def i32(self, v):
        self.b += struct.pack("<i", v)

    def u64(self, v):
        self.b += struct.pack("<Q", v)

    def i64(self, v):
        self.b += struct.pack("<q", v)

    def f32(self, v):
        self.b += struct.pack("<f", v)

    def f64(self, v):
        self.b += struct.pack("<d", v)

    def string(self, s):
        # Null strings / arrays are written as empty ones: the C++ codec does not tell them
        # apart, so the blob holds exactly what it re-encodes.
        if s is None:
            self.i32(0)
            return
        data = s.encode("utf-8") if isinstance(s, str) else bytes(s)
        self.i32(len(data))
        self.b += data

    def guid(self, g):
        self.b += g.bytes_le

    def nodeid(self, n):
        if n.kind == "i":
            if n.ns == 0 and n.value <= 0xFF:
                self.u8(0)
                self.u8(n.value)
            elif n.ns <= 0xFF and n.value <= 0xFFFF:
                self.u8(1)
                self.u8(n.ns)
                self.u16(n.value)
            else:
                self.u8(2)
                self.u16(n.ns)
                self.u32(n.value)
        elif n.kind == "s":
            self.u8(3)
            self.u16(n.ns)
            self.string(n.value)
        elif n.kind == "g":
            self.u8(4)
            self.u16(n.ns)
            self.guid(n.value)
        else:
            self.u8(5)
            self.u16(n.ns)
            self.string(n.value)

    def localized_text(self, locale, text):
        mask = (1 if locale else 0) | (2 if text else 0)
        self.u8(mask)
        if locale:
            self.string(locale)
        if text:
            self.string(text)

    def qualified_name(self, ns, name):
        self.u16(ns)
        self.string(name)


def parse_bool(s):
    s = (s or "").strip().lower()
    if s in ("true", "1"):
        return True
    if s in ("false", "0", ""):
        return False
    raise CompileError("invalid Boolean %r" % s)


def parse_datetime_ticks(s):
    s = s.strip()
    if not s:
        return 0
    m = re.match(r"^(\d{4})-(\d{2})-(\d{2})T(\d{2}):(\d{2}):(\d{2})(\.\d+)?(Z|[+-]\d{2}:\d{2})?$", s)
    if not m:
        raise CompileError("invalid DateTime %r" % s)
    y, mo, d, h, mi, se = (int(m.group(i)) for i in range(1, 7))
    frac = m.group(7) or ""
    tz = m.group(8) or "Z"
    dt = datetime.datetime(y, mo, d, h, mi, se, tzinfo=datetime.timezone.utc)
    if tz != "Z":
        sign = 1 if tz[0] == "+" else -1
        dt -= sign * datetime.timedelta(hours=int(tz[1:3]), minutes=int(tz[4:6]))
    epoch = datetime.datetime(1601, 1, 1, tzinfo=datetime.timezone.utc)
    delta = dt - epoch
    ticks = (delta.days * 86400 + delta.seconds) * 10_000_000
    if frac:
        ticks += int((frac[1:] + "0000000")[:7])
    return ticks


# ---------------------------------------------------------------------------------------
# The NodeSet model
# ---------------------------------------------------------------------------------------
class Node:
    __slots__ = (
        "cls", "tag", "nodeid", "browse_ns", "browse_name", "display", "description",
        "write_mask", "user_write_mask", "attrs", "value_xml", "definition_xml", "inverse_name",
        "refs", "index",
    )


class NodeSet:
    def __init__(self, path):
        self.path = path
        root = ET.parse(path).getroot()
        self.namespace_uris = [UA_URI]
        uris = root.find(NS_NODESET + "NamespaceUris")
        if uris is not None:
            self.namespace_uris += [u.text.strip() for u in uris]
        self.aliases = {}
        aliases = root.find(NS_NODESET + "Aliases")
        if aliases is not None:
            for a in aliases:
                self.aliases[a.get("Alias")] = a.text.strip()
        self.nodes = []
        self.by_id = {}
        for el in root:
            tag = local(el.tag)
            if tag not in NODE_CLASSES:
                continue
            self.nodes.append(self._parse_node(el, tag))
        for i, n in enumerate(self.nodes):
            n.index = i
            if n.nodeid in self.by_id:
                raise CompileError("duplicate NodeId %r" % n.nodeid)
            self.by_id[n.nodeid] = n
        self._collect_references()
        self.by_browse = {}
        for n in self.nodes:
            if n.cls == 64:
                self.by_browse.setdefault(n.browse_name, n)

    def nodeid(self, text):
        text = text.strip()
        return NodeId.parse(self.aliases.get(text, text))

    def _parse_node(self, el, tag):
        n = Node()
        n.tag = tag
        n.cls = NODE_CLASSES[tag]
        n.nodeid = self.nodeid(el.get("NodeId"))
        bn = el.get("BrowseName")
        m = re.match(r"^(\d+):(.*)$", bn, re.S)
        n.browse_ns, n.browse_name = (int(m.group(1)), m.group(2)) if m else (0, bn)
        n.display = None
        n.description = None
        n.inverse_name = None
        dn = el.find(NS_NODESET + "DisplayName")
        if dn is not None:
            n.display = (dn.get("Locale") or "", dn.text or "")
        else:
            n.display = ("", n.browse_name)
        d = el.find(NS_NODESET + "Description")
        if d is not None:
            n.description = (d.get("Locale") or "", d.text or "")
        inv = el.find(NS_NODESET + "InverseName")
        if inv is not None:
            n.inverse_name = (inv.get("Locale") or "", inv.text or "")
        n.write_mask = int(el.get("WriteMask", "0"))
        n.user_write_mask = int(el.get("UserWriteMask", "0"))
        n.attrs = dict(el.attrib)
        v = el.find(NS_NODESET + "Value")
        n.value_xml = v
        n.definition_xml = el.find(NS_NODESET + "Definition")
        n.refs = []
        refs = el.find(NS_NODESET + "References")
        if refs is not None:
            for r in refs:
                fwd = parse_bool(r.get("IsForward", "true"))
                n.refs.append((self.nodeid(r.get("ReferenceType")), fwd, self.nodeid(r.text)))
        return n

    def _collect_references(self):
        """De-duplicated forward references (source, type, target) in document order."""
        seen = set()
        self.references = []
        for n in self.nodes:
            for rtype, fwd, target in n.refs:
                key = (n.nodeid, rtype, target) if fwd else (target, rtype, n.nodeid)
                if key in seen:
                    continue
                seen.add(key)
                self.references.append(key)
        self.supertype = {}
        self.encodings = {}  # DataType NodeId -> {encoding browse name: encoding NodeId}
        self.encoding_owner = {}  # encoding NodeId -> DataType NodeId
        for src, rtype, dst in self.references:
            if rtype == NodeId(0, "i", HAS_SUBTYPE):
                self.supertype[dst] = src
            elif rtype == NodeId(0, "i", HAS_ENCODING):
                enc = self.by_id.get(dst)
                if enc is not None:
                    self.encodings.setdefault(src, {})[enc.browse_name] = dst
                    self.encoding_owner[dst] = src

    # ---- DataType helpers ---------------------------------------------------------------
    def is_subtype(self, t, base):
        seen = 0
        while t is not None and seen < 64:
            if t == base:
                return True
            t = self.supertype.get(t)
            seen += 1
        return False

    def builtin_of(self, t):
        """The built-in type id that encodes values of DataType t (None for structures)."""
        seen = 0
        while t is not None and seen < 64:
            if t.ns == 0 and t.kind == "i":
                if t.value == DT_ENUMERATION:
                    return BUILTIN["Int32"]
                if 1 <= t.value <= 25 and t.value not in (DT_STRUCTURE, DT_BASEDATATYPE):
                    return t.value
                if t.value == DT_STRUCTURE:
                    return None
                if t.value == DT_BASEDATATYPE:
                    return BUILTIN["Variant"]
            t = self.supertype.get(t)
            seen += 1
        raise CompileError("cannot find the built-in type of DataType %r" % t)

    def binary_encoding(self, dt):
        enc = self.encodings.get(dt, {}).get("Default Binary")
        if enc is None:
            raise CompileError("DataType %r has no Default Binary encoding" % dt)
        return enc

    def datatype_by_name(self, name):
        n = self.by_browse.get(name)
        if n is None:
            raise CompileError("unknown DataType %r" % name)
        return n

    def structure_fields(self, dt):
        """All fields of a structure DataType, inherited first: list of (name, dtype, rank, optional)."""
        chain = []
        t = dt
        while t is not None and not (t.ns == 0 and t.kind == "i" and t.value == DT_STRUCTURE):
            chain.append(t)
            t = self.supertype.get(t)
        fields = []
        for t in reversed(chain):
            node = self.by_id.get(t)
            if node is None or node.definition_xml is None:
                continue
            for f in node.definition_xml:
                fields.append((
                    f.get("Name"),
                    self.nodeid(f.get("DataType", "i=24")),
                    int(f.get("ValueRank", "-1")),
                    parse_bool(f.get("IsOptional", "false")),
                ))
        return fields

    def is_union(self, dt):
        node = self.by_id.get(dt)
        return (node is not None and node.definition_xml is not None and
                parse_bool(node.definition_xml.get("IsUnion", "false")))


# ---------------------------------------------------------------------------------------
# XML values (Part 6 §5.3) -> OPC UA Binary
# ---------------------------------------------------------------------------------------
class ValueEncoder:
    def __init__(self, ns):
        self.ns = ns

    def children(self, el):
        if el is None:
            return []
        return [c for c in el if isinstance(c.tag, str)]

    def child(self, el, name):
        for c in self.children(el):
            if local(c.tag) == name:
                return c
        return None

    def text(self, el, name, default=""):
        c = self.child(el, name)
        return default if c is None or c.text is None else c.text

    def builtin(self, out, type_id, el):
        """Encodes the scalar built-in value held by XML element el."""
        name = BUILTIN_NAME[type_id]
        txt = (el.text or "").strip() if el is not None else ""
        if name == "Boolean":
            out.u8(1 if parse_bool(txt) else 0)
        elif name in ("SByte", "Byte", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64"):
            v = int(txt or "0")
            {"SByte": out.i8, "Byte": out.u8, "Int16": out.i16, "UInt16": out.u16,
             "Int32": out.i32, "UInt32": out.u32, "Int64": out.i64, "UInt64": out.u64}[name](v)
        elif name == "Float":
            out.f32(float(txt or "0"))
        elif name == "Double":
            out.f64(float(txt or "0"))
        elif name == "String":
            out.string(el.text if el is not None and el.text is not None else None)
        elif name == "DateTime":
            out.i64(parse_datetime_ticks(txt))
        elif name == "Guid":
            s = self.text(el, "String", txt).strip()
            out.guid(uuid.UUID(s) if s else uuid.UUID(int=0))
        elif name == "ByteString":
            out.string(base64.b64decode(re.sub(r"\s+", "", txt)) if txt else None)
        elif name == "XmlElement":
            inner = "".join(ET.tostring(c, encoding="unicode") for c in self.children(el))
            out.string(inner)
        elif name == "NodeId":
            ident = self.text(el, "Identifier").strip()
            out.nodeid(self.ns.nodeid(ident) if ident else NULL_NODEID)
        elif name == "ExpandedNodeId":
            ident = self.text(el, "Identifier").strip()
            out.nodeid(self.ns.nodeid(ident) if ident else NULL_NODEID)
        elif name == "StatusCode":
            out.u32(int(self.text(el, "Code", "0").strip() or "0", 0))
        elif name == "QualifiedName":
            out.qualified_name(int(self.text(el, "NamespaceIndex", "0").strip() or "0"),
                               self.text(el, "Name"))
        elif name == "LocalizedText":
            out.localized_text(self.text(el, "Locale").strip(), self.text(el, "Text"))
        elif name == "ExtensionObject":
            self.extension_object(out, el)
        elif name == "Variant":
            inner = self.child(el, "Value")
            vals = self.children(inner) if inner is not None else []
            if not vals:
                out.u8(0)
            else:
                self.variant(out, vals[0])
        else:
            raise CompileError("unsupported built-in type %s in a value" % name)

    def extension_object(self, out, el):
        if el is None:
            out.nodeid(NULL_NODEID)
            out.u8(0)
            return
        tid = self.text(el, "TypeId") if self.child(el, "TypeId") is None else \
            self.text(self.child(el, "TypeId"), "Identifier")
        body = self.child(el, "Body")
        if not tid.strip() or body is None or not self.children(body):
            out.nodeid(NULL_NODEID)
            out.u8(0)
            return
        type_id = self.ns.nodeid(tid)
        dt = self.ns.encoding_owner.get(type_id, type_id)
        struct_el = self.children(body)[0]
        if dt not in self.ns.by_id:
            dt = self.ns.datatype_by_name(local(struct_el.tag)).nodeid
        out.nodeid(self.ns.binary_encoding(dt))
        out.u8(1)
        inner = Bin()
        self.structure(inner, dt, struct_el)
        out.string(bytes(inner.b))

    def structure(self, out, dt, el):
        fields = self.ns.structure_fields(dt)
        if self.ns.is_union(dt):
            for i, (fname, ftype, rank, _opt) in enumerate(fields):
                c = self.child(el, fname)
                if c is not None:
                    out.u32(i + 1)
                    self.field(out, ftype, rank, c)
                    return
            out.u32(0)
            return
        optional = [f for f in fields if f[3]]
        if optional:
            mask = 0
            bit = 0
            for fname, _t, _r, opt in fields:
                if opt:
                    if self.child(el, fname) is not None:
                        mask |= 1 << bit
                    bit += 1
            out.u32(mask)
        for fname, ftype, rank, opt in fields:
            c = self.child(el, fname)
            if opt and c is None:
                continue
            self.field(out, ftype, rank, c)

    def field(self, out, ftype, rank, el):
        if rank >= 1:
            items = self.children(el) if el is not None else []
            if el is None:
                out.i32(0)
                return
            out.i32(len(items))
            for it in items:
                self.scalar(out, ftype, it)
        else:
            self.scalar(out, ftype, el)

    def scalar(self, out, ftype, el):
        b = self.ns.builtin_of(ftype)
        if b is None:
            # A structure field: nested encoding, or an ExtensionObject for abstract types.
            node = self.ns.by_id.get(ftype)
            abstract = node is not None and parse_bool(node.attrs.get("IsAbstract", "false"))
            if abstract:
                self.extension_object(out, el)
            else:
                self.structure(out, ftype, el if el is not None else ET.Element("x"))
            return
        if b == BUILTIN["Variant"]:
            vals = self.children(el) if el is not None else []
            if not vals:
                out.u8(0)
            else:
                self.variant(out, vals[0])
            return
        if b == BUILTIN["Int32"] and self.ns.is_subtype(ftype, NodeId(0, "i", DT_ENUMERATION)):
            txt = (el.text or "").strip() if el is not None else "0"
            m = re.match(r"^.*_(-?\d+)$", txt)
            out.i32(int(m.group(1)) if m else int(txt or "0"))
            return
        self.builtin(out, b, el)

    def variant(self, out, el):
        """Encodes the XML value element (e.g. <Int32>, <ListOfString>) as a Variant."""
        name = local(el.tag)
        if name.startswith("ListOf"):
            elem = name[6:]
            if elem not in BUILTIN:
                raise CompileError("unsupported value type %s" % name)
            t = BUILTIN[elem]
            items = self.children(el)
            out.u8(t | 0x80)
            out.i32(len(items))
            for it in items:
                self.builtin(out, t, it)
            return
        if name == "Matrix":
            dims = [int(x.text) for x in self.children(self.child(el, "Dimensions"))]
            elements = self.children(self.child(el, "Elements"))
            if not elements:
                out.u8(0)
                return
            t = BUILTIN[local(elements[0].tag)]
            out.u8(t | 0xC0)
            out.i32(len(elements))
            for it in elements:
                self.builtin(out, t, it)
            out.i32(len(dims))
            for d in dims:
                out.i32(d)
            return
        if name not in BUILTIN:
            raise CompileError("unsupported value type %s" % name)
        t = BUILTIN[name]
        out.u8(t)
        self.builtin(out, t, el)


# ---------------------------------------------------------------------------------------
# DataTypeDefinition attribute (StructureDefinition / EnumDefinition)
# ---------------------------------------------------------------------------------------
def encode_definition(ns, node):
    dt = node.nodeid
    d = node.definition_xml
    is_enum = ns.is_subtype(dt, NodeId(0, "i", DT_ENUMERATION)) or \
        parse_bool(d.get("IsOptionSet", "false"))
    body = Bin()
    if is_enum:
        fields = list(d)
        body.i32(len(fields))
        for f in fields:
            # EnumField: Value (Int64), DisplayName, Description, Name
            body.i64(int(f.get("Value", "0")))
            dn = f.find(NS_NODESET + "DisplayName")
            body.localized_text((dn.get("Locale") or "") if dn is not None else "",
                                dn.text if dn is not None else f.get("Name"))
            de = f.find(NS_NODESET + "Description")
            body.localized_text((de.get("Locale") or "") if de is not None else "",
                                de.text if de is not None else "")
            body.string(f.get("Name"))
        enc_dt = ns.datatype_by_name("EnumDefinition").nodeid
    else:
        abstract = parse_bool(node.attrs.get("IsAbstract", "false"))
        enc = NULL_NODEID if abstract else ns.encodings.get(dt, {}).get("Default Binary", NULL_NODEID)
        body.nodeid(enc)
        body.nodeid(ns.supertype.get(dt, NodeId(0, "i", DT_STRUCTURE)))
        # StructureType: Structure 0, WithOptionalFields 1, Union 2,
        # WithSubtypedValues 3, UnionWithSubtypedValues 4.
        chain_fields = []
        t = dt
        chain = []
        while t is not None and not (t.ns == 0 and t.kind == "i" and t.value == DT_STRUCTURE):
            chain.append(t)
            t = ns.supertype.get(t)
        for t in reversed(chain):
            n = ns.by_id.get(t)
            if n is not None and n.definition_xml is not None:
                chain_fields += list(n.definition_xml)
        union = parse_bool(d.get("IsUnion", "false")) or ns.is_subtype(dt, NodeId(0, "i", 12756))
        optional = any(parse_bool(f.get("IsOptional", "false")) for f in chain_fields)
        subtyped = any(parse_bool(f.get("AllowSubTypes", "false")) for f in chain_fields)
        if union:
            stype = 4 if subtyped else 2
        elif subtyped:
            stype = 3
        else:
            stype = 1 if optional else 0
        body.i32(stype)
        body.i32(len(chain_fields))
        for f in chain_fields:
            body.string(f.get("Name"))
            de = f.find(NS_NODESET + "Description")
            body.localized_text((de.get("Locale") or "") if de is not None else "",
                                de.text if de is not None else "")
            body.nodeid(ns.nodeid(f.get("DataType", "i=24")))
            body.i32(int(f.get("ValueRank", "-1")))
            ad = f.get("ArrayDimensions")
            if ad:
                dims = [int(x) for x in ad.split(",")]
                body.i32(len(dims))
                for x in dims:
                    body.u32(x)
            else:
                body.i32(0)
            body.u32(int(f.get("MaxStringLength", "0")))
            # In a structure with subtyped values the flag says that the field allows
            # subtypes (OPC 10000-3 §8.51).
            body.u8(1 if parse_bool(f.get("IsOptional", "false")) or
                    parse_bool(f.get("AllowSubTypes", "false")) else 0)
        enc_dt = ns.datatype_by_name("StructureDefinition").nodeid
    out = Bin()
    out.nodeid(ns.binary_encoding(enc_dt))
    out.u8(1)
    out.string(bytes(body.b))
    return bytes(out.b)


# ---------------------------------------------------------------------------------------
# Blob writer
# ---------------------------------------------------------------------------------------
class Blob:
    def __init__(self):
        self.b = bytearray()

    def varint(self, v):
        if v < 0:
            raise CompileError("negative varint")
        while True:
            byte = v & 0x7F
            v >>= 7
            if v:
                self.b.append(byte | 0x80)
            else:
                self.b.append(byte)
                return

    def svarint(self, v):
        self.varint((v << 1) ^ (v >> 63) if v < 0 else v << 1)

    def byte(self, v):
        self.b.append(v & 0xFF)

    def bytes_(self, data):
        self.varint(len(data))
        self.b += data


class Strings:
    def __init__(self):
        self.index = {"": 0}
        self.items = [""]

    def __call__(self, s):
        s = s or ""
        i = self.index.get(s)
        if i is None:
            i = len(self.items)
            self.index[s] = i
            self.items.append(s)
        return i


def write_cnid(blob, strings, n):
    if n.kind == "i":
        if n.ns == 0:
            blob.byte(0)
            blob.varint(n.value)
        else:
            blob.byte(1)
            blob.varint(n.ns)
            blob.varint(n.value)
    elif n.kind == "s":
        blob.byte(2)
        blob.varint(n.ns)
        blob.varint(strings(n.value))
    elif n.kind == "g":
        blob.byte(3)
        blob.varint(n.ns)
        blob.b += n.value.bytes_le
    else:
        blob.byte(4)
        blob.varint(n.ns)
        blob.bytes_(n.value)


def compile_nodeset(ns):
    strings = Strings()
    venc = ValueEncoder(ns)
    body = Blob()
    values = bytearray()

    def add_value(data):
        body.varint(len(values))
        body.varint(len(data))
        values.extend(data)

    stats = {"values": 0, "definitions": 0}
    for n in ns.nodes:
        a = n.attrs
        body.byte(n.cls)
        write_cnid(body, strings, n.nodeid)
        body.varint(n.browse_ns)
        body.varint(strings(n.browse_name))
        body.varint(strings(n.display[0]))
        body.varint(strings(n.display[1]))
        flags = 0
        if n.description is not None and (n.description[0] or n.description[1]):
            flags |= 0x0001
        if n.write_mask or n.user_write_mask:
            flags |= 0x0002
        if parse_bool(a.get("IsAbstract", "false")):
            flags |= 0x0004
        if parse_bool(a.get("Symmetric", "false")):
            flags |= 0x0008
        if parse_bool(a.get("ContainsNoLoops", "false")):
            flags |= 0x0010
        if parse_bool(a.get("Historizing", "false")):
            flags |= 0x0020
        if parse_bool(a.get("Executable", "true")):
            flags |= 0x0040
        if parse_bool(a.get("UserExecutable", "true")):
            flags |= 0x0080
        value = None
        if n.cls in (2, 16) and n.value_xml is not None:
            vals = [c for c in n.value_xml if isinstance(c.tag, str)]
            if vals:
                out = Bin()
                venc.variant(out, vals[0])
                value = bytes(out.b)
                flags |= 0x0100
        if n.cls == 32 and n.inverse_name is not None:
            flags |= 0x0200
        definition = None
        if n.cls == 64 and n.definition_xml is not None:
            definition = encode_definition(ns, n)
            flags |= 0x0400
        dims = []
        if n.cls in (2, 16) and a.get("ArrayDimensions"):
            dims = [int(x) for x in a["ArrayDimensions"].split(",")]
            flags |= 0x0800
        min_sampling = float(a.get("MinimumSamplingInterval", "0"))
        if n.cls == 2 and min_sampling != 0:
            flags |= 0x1000
        body.varint(flags)
        if flags & 0x0001:
            body.varint(strings(n.description[0]))
            body.varint(strings(n.description[1]))
        if flags & 0x0002:
            body.varint(n.write_mask)
            body.varint(n.user_write_mask)
        if n.cls in (1, 128):
            body.byte(int(a.get("EventNotifier", "0")))
        elif n.cls in (2, 16):
            write_cnid(body, strings, ns.nodeid(a.get("DataType", "i=24")))
            body.svarint(int(a.get("ValueRank", "-1")))
            if n.cls == 2:
                body.byte(int(a.get("AccessLevel", "1")))
                body.byte(int(a.get("UserAccessLevel", a.get("AccessLevel", "1"))))
                if flags & 0x1000:
                    body.b += struct.pack("<d", min_sampling)
            if dims:
                body.varint(len(dims))
                for d in dims:
                    body.varint(d)
            if value is not None:
                add_value(value)
                stats["values"] += 1
        elif n.cls == 32:
            if flags & 0x0200:
                body.varint(strings(n.inverse_name[0]))
                body.varint(strings(n.inverse_name[1]))
        elif n.cls == 64:
            if definition is not None:
                add_value(definition)
                stats["definitions"] += 1
    refs = Blob()
    count = 0
    for src, rtype, dst in ns.references:
        s = ns.by_id.get(src)
        r = ns.by_id.get(rtype)
        t = ns.by_id.get(dst)
        if s is None or r is None or t is None:
            # Only nodes of this NodeSet can be referenced by index; a NodeSet that extends
            # another one would need NodeId references (not needed for namespace 0).
            raise CompileError("reference %r -%r-> %r leaves the NodeSet" % (src, rtype, dst))
        refs.varint(s.index)
        refs.varint(r.index)
        refs.varint(t.index)
        count += 1
    head = Blob()
    head.b += b"PNPNSET1"
    head.b += b"\0\0\0\0"  # valuesAt, patched below
    head.varint(len(ns.nodes))
    head.varint(count)
    head.varint(len(ns.namespace_uris))
    for u in ns.namespace_uris:
        head.bytes_(u.encode("utf-8"))
    head.varint(len(strings.items))
    for s in strings.items:
        head.bytes_(s.encode("utf-8"))
    stats["nodes"] = len(ns.nodes)
    stats["references"] = count
    stats["strings"] = len(strings.items)
    values_at = len(head.b) + len(body.b) + len(refs.b)
    head.b[8:12] = struct.pack("<I", values_at)
    return bytes(head.b + body.b + refs.b + values), stats


def cpp_literal(data, width=96):
    """Splits data into C++ narrow string literal lines (octal escapes, 3 digits)."""
    lines = []
    cur = []
    n = 0
    for byte in data:
        c = chr(byte)
        if 0x20 <= byte < 0x7F and c not in '"\\?':
            cur.append(c)
            n += 1
        else:
            cur.append("\\%03o" % byte)
            n += 4
        if n >= width:
            lines.append('"' + "".join(cur) + '"')
            cur = []
            n = 0
    if cur:
        lines.append('"' + "".join(cur) + '"')
    return "\n    ".join(lines) if lines else '""'


def emit_cpp(path, symbol, namespace, blob, source_name, stats):
    with open(path, "w", encoding="utf-8") as f:
        f.write("// Generated by tools/nodeset_compiler/nodeset_compiler.py from %s.\n" % source_name)
        f.write("// Do not edit. %(nodes)d nodes, %(references)d references, %(strings)d strings.\n" % stats)
        f.write("#include <cstddef>\n\n")
        f.write("namespace %s {\n\n" % namespace)
        f.write("extern const unsigned char %s[];\n" % symbol)
        f.write("extern const std::size_t %sSize;\n" % symbol)
        f.write("extern const std::size_t %sNodeCount;\n\n" % symbol)
        # A string literal compiles much faster than a brace list of numbers.
        f.write("alignas(16) const unsigned char %s[] =\n    %s;\n" % (symbol, cpp_literal(blob)))
        f.write("const std::size_t %sSize = %d;\n" % (symbol, len(blob)))
        f.write("const std::size_t %sNodeCount = %d;\n\n" % (symbol, stats["nodes"]))
        f.write("}  // namespace %s\n" % namespace)


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--input", required=True, help="UANodeSet XML file")
    ap.add_argument("--output", required=True, help="C++ source file to write")
    ap.add_argument("--blob", help="also write the raw blob to this file")
    ap.add_argument("--symbol", default="kNs0Blob")
    ap.add_argument("--namespace", default="pnp::ua::server::generated")
    args = ap.parse_args(argv)
    t0 = time.time()
    try:
        ns = NodeSet(args.input)
        blob, stats = compile_nodeset(ns)
    except CompileError as e:
        print("nodeset_compiler: %s: %s" % (args.input, e), file=sys.stderr)
        return 1
    emit_cpp(args.output, args.symbol, args.namespace, blob, args.input.split("/")[-1], stats)
    if args.blob:
        with open(args.blob, "wb") as f:
            f.write(blob)
    print("nodeset_compiler: %d nodes, %d references, %d values, %d definitions, %d bytes (%.2fs)"
          % (stats["nodes"], stats["references"], stats["values"], stats["definitions"],
             len(blob), time.time() - t0))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
