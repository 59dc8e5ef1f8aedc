"""Loads the namespace-0 information model used by the code generator.

Inputs (all read from the installed npm packages, never copied into the repository):

* Opc.Ua.NodeSet2.xml (node-opcua-nodesets): the primary source. Every node of namespace 0, the
  DataType hierarchy, the DataTypeDefinitions (fields, enum values, option sets) and the
  HasEncoding references that give the "Default Binary" encoding ids.
* Opc.Ua.Types.bsd (node-opcua-nodesets): since 1.05 the official Opc.Ua.NodeSet2.xml no longer
  holds the service DataTypes (ReadRequest, RequestHeader, ...); the OPC Foundation ships them
  in Opc.Ua.NodeSet2.Services.xml, which node-opcua-nodesets does not include. Their binary
  layout is taken from the official binary schema instead, for the DataTypes the NodeSet2 lacks.
* opcua_node_ids.ts (node-opcua-constants): the official NodeIds.csv table as a TypeScript enum.
  Gives the NodeIds of the DataTypes / encodings that only the schema describes, and the
  ns0_ids.hpp constants of nodes the NodeSet2 does not contain.
* _generated_status_codes.ts (node-opcua-status-code): the official StatusCode.csv table.

Everything here is deterministic: no dict/set iteration order leaks into the output.
"""

from __future__ import annotations

import re
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from typing import Dict, List, Optional

NS_NODESET = "http://opcfoundation.org/UA/2011/03/UANodeSet.xsd"
NS_BSD = "http://opcfoundation.org/BinarySchema/"

# Well-known DataType ids (OPC 10000-6 Table 1 and OPC 10000-5).
BOOLEAN, SBYTE, BYTE, INT16, UINT16, INT32, UINT32, INT64, UINT64 = range(1, 10)
FLOAT, DOUBLE, STRING, DATETIME, GUID, BYTESTRING, XMLELEMENT = range(10, 17)
NODEID, EXPANDEDNODEID, STATUSCODE, QUALIFIEDNAME, LOCALIZEDTEXT = range(17, 22)
STRUCTURE, DATAVALUE, BASEDATATYPE, DIAGNOSTICINFO = 22, 23, 24, 25
NUMBER, INTEGER, UINTEGER, ENUMERATION = 26, 27, 28, 29
DECIMAL = 50
OPTIONSET = 12755
UNION = 12756

# Built-in DataTypes and the C++ type that holds them (see ua/types/builtin.hpp).
BUILTIN_CPP = {
    BOOLEAN: "Boolean",
    SBYTE: "SByte",
    BYTE: "Byte",
    INT16: "Int16",
    UINT16: "UInt16",
    INT32: "Int32",
    UINT32: "UInt32",
    INT64: "Int64",
    UINT64: "UInt64",
    FLOAT: "Float",
    DOUBLE: "Double",
    STRING: "String",
    DATETIME: "DateTime",
    GUID: "Guid",
    BYTESTRING: "ByteString",
    XMLELEMENT: "XmlElement",
    NODEID: "NodeId",
    EXPANDEDNODEID: "ExpandedNodeId",
    STATUSCODE: "StatusCode",
    QUALIFIEDNAME: "QualifiedName",
    LOCALIZEDTEXT: "LocalizedText",
    STRUCTURE: "ExtensionObject",
    DATAVALUE: "DataValue",
    BASEDATATYPE: "Variant",
    DIAGNOSTICINFO: "DiagnosticInfo",
    # Abstract simple types: a field of such a type holds any subtype, so it is a Variant
    # (OPC 10000-6 §5.2.7, fields with abstract DataTypes).
    NUMBER: "Variant",
    INTEGER: "Variant",
    UINTEGER: "Variant",
    # A field typed with the abstract Enumeration holds the Int32 value of any enumeration.
    ENUMERATION: "Int32",
}

INTEGER_IDS = {SBYTE, BYTE, INT16, UINT16, INT32, UINT32, INT64, UINT64}

# Names of the binary schema (Opc.Ua.Types.bsd) for the built-in types.
BSD_BUILTIN = {
    "opc:Boolean": BOOLEAN,
    "opc:SByte": SBYTE,
    "opc:Byte": BYTE,
    "opc:Int16": INT16,
    "opc:UInt16": UINT16,
    "opc:Int32": INT32,
    "opc:UInt32": UINT32,
    "opc:Int64": INT64,
    "opc:UInt64": UINT64,
    "opc:Float": FLOAT,
    "opc:Double": DOUBLE,
    "opc:String": STRING,
    "opc:CharArray": STRING,
    "opc:DateTime": DATETIME,
    "opc:Guid": GUID,
    "opc:ByteString": BYTESTRING,
    "ua:XmlElement": XMLELEMENT,
    "ua:NodeId": NODEID,
    "ua:ExpandedNodeId": EXPANDEDNODEID,
    "ua:StatusCode": STATUSCODE,
    "ua:QualifiedName": QUALIFIEDNAME,
    "ua:LocalizedText": LOCALIZEDTEXT,
    "ua:ExtensionObject": STRUCTURE,
    "ua:DataValue": DATAVALUE,
    "ua:Variant": BASEDATATYPE,
    "ua:DiagnosticInfo": DIAGNOSTICINFO,
}


class ModelError(Exception):
    pass


def warn(msg: str) -> None:
    print(f"codegen: warning: {msg}", file=sys.stderr)


@dataclass
class Field:
    name: str  # as in the DataTypeDefinition ("RequestHeader")
    type_id: int  # DataType NodeId (ns=0)
    value_rank: int = -1
    optional: bool = False
    allow_subtypes: bool = False
    enum_value: Optional[int] = None  # enumerations / option sets only
    description: str = ""


@dataclass
class DataType:
    id: int
    browse_name: str
    symbolic_name: str  # identifier-safe name (SymbolicName if given, else BrowseName)
    parent: Optional[int]
    is_abstract: bool
    source: str  # "nodeset" or "bsd"
    fields: List[Field] = field(default_factory=list)
    has_definition: bool = False
    is_option_set: bool = False
    encodings: Dict[str, int] = field(default_factory=dict)  # "Binary"/"Xml"/"Json" -> id
    description: str = ""
    # The OPC UA Part that specifies it (from the NodeSet2's Documentation link); 4 for the
    # service DataTypes of Opc.Ua.Types.bsd; None when unknown.
    part: Optional[int] = None
    # Filled by Model.classify():
    kind: str = ""  # builtin | abstract | simple | enum | optionset | struct | union | skip
    cpp_name: str = ""


@dataclass
class StatusCodeEntry:
    name: str
    value: int
    description: str


# Internal ids of the test fixture's DataTypes (ns=1;i=N -> FIXTURE_BASE + N).
FIXTURE_BASE = 0x7F000000


def _parse_node_id(text: str, aliases: Dict[str, str], fixture: bool = False) -> Optional[int]:
    """ns=0 numeric NodeIds (and ns=1 ones of the test fixture); anything else returns None."""
    text = aliases.get(text.strip(), text.strip())
    m = re.fullmatch(r"i=(\d+)", text)
    if m:
        return int(m.group(1))
    m = re.fullmatch(r"ns=1;i=(\d+)", text)
    if m and fixture:
        return FIXTURE_BASE + int(m.group(1))
    return None


def _strip_ns(browse_name: str) -> str:
    m = re.fullmatch(r"(\d+):(.*)", browse_name)
    return m.group(2) if m else browse_name


class Model:
    def __init__(self) -> None:
        self.datatypes: Dict[int, DataType] = {}
        self.node_names: Dict[int, str] = {}  # ns0 id -> NodeIds.csv style symbol
        self.node_origin: Dict[int, str] = {}  # "nodeset" / "table"
        # ns0 id -> NodeClass (Object, Variable, Method, ObjectType, VariableType, DataType,
        # ReferenceType, View)
        self.node_class: Dict[int, str] = {}
        self.status_codes: List[StatusCodeEntry] = []
        self.notes: List[str] = []  # human-readable remarks, emitted into the headers
        self.nodeset_version = ""

    # ---- NodeSet2 ------------------------------------------------------------------------
    def load_nodeset(self, path: str, fixture: bool = False) -> None:
        """Loads the ns0 NodeSet2, or (fixture=True) a test NodeSet2 whose ns=1 DataTypes
        build on namespace 0."""
        root = ET.parse(path).getroot()
        ns = {"u": NS_NODESET}
        model = root.find("u:Models/u:Model", ns)
        if model is not None and not fixture:
            self.nodeset_version = model.get("Version", "")
        aliases = {}
        al = root.find("u:Aliases", ns)
        if al is not None:
            for a in al:
                aliases[a.get("Alias")] = (a.text or "").strip()
        has_subtype = _parse_node_id("HasSubtype", aliases) or 45
        has_encoding = _parse_node_id("HasEncoding", aliases) or 38

        nodes = {}
        order = []
        for el in root:
            nid = el.get("NodeId")
            if nid is None:
                continue
            num = _parse_node_id(nid, {}, fixture)
            if num is None or (fixture and num < FIXTURE_BASE):
                raise ModelError(f"unexpected NodeId {nid} in the namespace-0 NodeSet")
            nodes[num] = el
            order.append(num)

        # References, normalised to forward direction: (source, type, target).
        encoding_of = {}  # encoding object -> DataType
        parent_type = {}  # subtype -> supertype
        for num in order:
            refs = nodes[num].find("u:References", ns)
            if refs is None:
                continue
            for r in refs:
                rt = _parse_node_id(r.get("ReferenceType", ""), aliases)
                target = _parse_node_id(r.text or "", aliases, fixture)
                if target is None:
                    continue
                forward = r.get("IsForward", "true").lower() != "false"
                src, dst = (num, target) if forward else (target, num)
                if rt == has_encoding:
                    encoding_of[dst] = src
                elif rt == has_subtype:
                    parent_type[dst] = src

        # Node names as in NodeIds.csv: SymbolicName (or BrowseName) of the node, prefixed by
        # its parent's name for instances, "<DataType>_Encoding_<SymbolicName>" for encodings.
        def symbol(el) -> str:
            return el.get("SymbolicName") or _strip_ns(el.get("BrowseName", ""))

        names: Dict[int, str] = {}

        def name_of(num: int, depth: int = 0) -> str:
            if num in names:
                return names[num]
            if depth > 64:
                raise ModelError(f"parent cycle at i={num}")
            el = nodes[num]
            if num in encoding_of and encoding_of[num] in nodes:
                n = name_of(encoding_of[num], depth + 1) + "_Encoding_" + symbol(el)
            elif el.get("ParentNodeId"):
                parent = _parse_node_id(el.get("ParentNodeId"), aliases)
                if parent is None or parent not in nodes:
                    n = symbol(el)
                else:
                    n = name_of(parent, depth + 1) + "_" + symbol(el)
            else:
                n = symbol(el)
            names[num] = n
            return n

        for num in order:
            if not fixture:
                self.node_names[num] = name_of(num)
                self.node_origin[num] = "nodeset"
                self.node_class[num] = nodes[num].tag.rsplit("}", 1)[-1].removeprefix("UA")

        # DataTypes.
        for num in order:
            el = nodes[num]
            if el.tag != f"{{{NS_NODESET}}}UADataType":
                continue
            browse = _strip_ns(el.get("BrowseName"))
            doc = el.find("u:Description", ns)
            dt = DataType(
                id=num,
                browse_name=browse,
                symbolic_name=el.get("SymbolicName") or browse,
                parent=parent_type.get(num),
                is_abstract=el.get("IsAbstract", "false").lower() == "true",
                source="fixture" if fixture else "nodeset",
                description=(doc.text or "").strip() if doc is not None else "",
            )
            link = el.find("u:Documentation", ns)
            m = re.search(r"/Part(\d+)/", (link.text or "") if link is not None else "")
            dt.part = int(m.group(1)) if m else None
            d = el.find("u:Definition", ns)
            if d is not None:
                dt.has_definition = True
                dt.is_option_set = d.get("IsOptionSet", "false").lower() == "true"
                if d.get("IsUnion", "false").lower() == "true" and dt.parent != UNION:
                    # Older NodeSets flag unions on the definition only.
                    dt.parent = UNION
                for f in d.findall("u:Field", ns):
                    type_text = f.get("DataType")
                    tid = (BASEDATATYPE if type_text is None
                           else _parse_node_id(type_text, aliases, fixture))
                    if tid is None:
                        raise ModelError(f"{browse}.{f.get('Name')}: non-ns0 DataType {type_text}")
                    fd = f.find("u:Description", ns)
                    dt.fields.append(
                        Field(
                            name=f.get("Name"),
                            type_id=tid,
                            value_rank=int(f.get("ValueRank", "-1")),
                            optional=f.get("IsOptional", "false").lower() == "true",
                            allow_subtypes=f.get("AllowSubTypes", "false").lower() == "true",
                            enum_value=int(f.get("Value")) if f.get("Value") is not None else None,
                            description=(fd.text or "").strip() if fd is not None else "",
                        )
                    )
            self.datatypes[num] = dt

        for enc, dtid in encoding_of.items():
            if dtid in self.datatypes and enc in nodes:
                b = nodes[enc].get("BrowseName", "")
                kind = {"Default Binary": "Binary", "Default XML": "Xml", "Default JSON": "Json"}.get(b)
                if kind:
                    self.datatypes[dtid].encodings[kind] = enc

    # ---- NodeIds table (node-opcua-constants) -------------------------------------------------
    def load_node_id_table(self, path: str) -> Dict[str, int]:
        """Returns name -> id of the NodeIds table; adds the ids the NodeSet2 lacks."""
        text = open(path, encoding="utf-8").read()
        table: Dict[str, int] = {}
        by_category: Dict[str, Dict[str, int]] = {}
        for m in re.finditer(r"export\s+enum\s+(\w+)\s*\{(.*?)\}", text, re.S):
            cat = by_category.setdefault(m.group(1), {})
            for k, v in re.findall(r"(\w+)\s*=\s*(\d+)\s*,?", m.group(2)):
                cat[k] = int(v)
                table[k] = int(v)
        # Sanity checks: fail loudly if the package changes its format.
        for k, v in (("ReadRequest", 629), ("ReadRequest_Encoding_DefaultBinary", 631),
                     ("ObjectsFolder", 85), ("HasComponent", 47), ("Server_ServerStatus", 2256)):
            if table.get(k) != v:
                raise ModelError(f"{path}: expected {k}={v}, found {table.get(k)}")
        self.node_id_table = table
        self.node_id_categories = by_category
        # Cross-check the names computed from the NodeSet against the table.
        ids_to_names: Dict[int, List[str]] = {}
        for k, v in sorted(table.items()):
            ids_to_names.setdefault(v, []).append(k)
        mismatches = 0
        for num, nm in sorted(self.node_names.items()):
            if num in ids_to_names and nm not in ids_to_names[num]:
                mismatches += 1
                warn(f"i={num}: NodeSet name {nm} differs from the NodeIds table {ids_to_names[num]}")
        added = 0
        class_of_category = {f"{c}Ids": c for c in (
            "Object", "Variable", "Method", "ObjectType", "VariableType", "DataType",
            "ReferenceType", "View")}
        for num in sorted(ids_to_names):
            if num not in self.node_names:
                self.node_names[num] = ids_to_names[num][0]
                self.node_origin[num] = "table"
                for cat, entries in by_category.items():
                    if entries.get(ids_to_names[num][0]) == num and cat in class_of_category:
                        self.node_class[num] = class_of_category[cat]
                        break
                else:
                    raise ModelError(f"i={num} ({ids_to_names[num][0]}): no NodeClass in {path}")
                added += 1
        self.notes.append(
            f"{added} node ids come from the NodeIds table only (not in the NodeSet2); "
            f"{mismatches} name mismatches between NodeSet2 and the table"
        )
        return table

    # ---- binary schema supplement ---------------------------------------------------------
    def load_bsd_supplement(self, path: str, table: Dict[str, int]) -> None:
        """Adds the DataTypes the NodeSet2 lacks (the services) from Opc.Ua.Types.bsd."""
        root = ET.parse(path).getroot()
        ns = {"o": NS_BSD}
        known = {dt.symbolic_name for dt in self.datatypes.values()}
        known |= {dt.browse_name for dt in self.datatypes.values()}
        data_type_ids = self.node_id_categories.get("DataTypeIds", {})
        object_ids = self.node_id_categories.get("ObjectIds", {})

        elements = []
        for el in root:
            tag = el.tag.split("}")[-1]
            if tag not in ("StructuredType", "EnumeratedType"):
                continue
            name = el.get("Name")
            if name in known:
                continue
            if name not in data_type_ids:
                # Encoding helpers of the schema itself (NodeIdType, Variant, ...).
                self.notes.append(f"schema type {name} skipped: no DataType NodeId")
                continue
            elements.append((tag, name, el))

        new_names = {name: data_type_ids[name] for _, name, _ in elements}
        base_names = set()
        for tag, name, el in elements:
            bt = el.get("BaseType")
            if bt and bt.startswith("tns:"):
                base_names.add(bt[4:])

        def resolve(type_name: str) -> int:
            if type_name in BSD_BUILTIN:
                return BSD_BUILTIN[type_name]
            if type_name.startswith("tns:"):
                n = type_name[4:]
                if n in new_names:
                    return new_names[n]
                for dt in self.datatypes.values():
                    if dt.symbolic_name == n or dt.browse_name == n:
                        return dt.id
            raise ModelError(f"{path}: unknown type {type_name}")

        for tag, name, el in elements:
            num = data_type_ids[name]
            doc = el.find("o:Documentation", ns)
            dt = DataType(
                id=num,
                browse_name=name,
                symbolic_name=name,
                parent=None,
                is_abstract=False,
                source="bsd",
                has_definition=True,
                part=4,
                description=(doc.text or "").strip() if doc is not None else "",
            )
            if tag == "EnumeratedType":
                dt.is_option_set = el.get("IsOptionSet", "false").lower() == "true"
                bits = int(el.get("LengthInBits", "32"))
                if dt.is_option_set:
                    dt.parent = {8: BYTE, 16: UINT16, 32: UINT32, 64: UINT64}[bits]
                else:
                    dt.parent = ENUMERATION
                for v in el.findall("o:EnumeratedValue", ns):
                    value = int(v.get("Value"))
                    if dt.is_option_set:
                        # The schema gives masks, the NodeSet2 bit numbers: store bit numbers.
                        if value == 0 or value & (value - 1):
                            continue  # "None" / combined values are not single bits
                        value = value.bit_length() - 1
                    dt.fields.append(Field(name=v.get("Name"), type_id=INT32, enum_value=value))
            else:
                bt = el.get("BaseType") or "ua:ExtensionObject"
                dt.parent = STRUCTURE if bt == "ua:ExtensionObject" else resolve(bt)
                raw = el.findall("o:Field", ns)
                length_fields = {f.get("LengthField") for f in raw if f.get("LengthField")}
                for f in raw:
                    if f.get("SwitchField") or f.get("TypeName") == "opc:Bit":
                        raise ModelError(f"{path}: {name} uses switch fields; not supported")
                    if f.get("Name") in length_fields:
                        continue
                    dt.fields.append(
                        Field(
                            name=f.get("Name"),
                            type_id=resolve(f.get("TypeName")),
                            value_rank=1 if f.get("LengthField") else -1,
                        )
                    )
                # The schema has no IsAbstract: a field-less base of other types is abstract
                # (HistoryReadDetails, NotificationData, ...).
                dt.is_abstract = not dt.fields and name in base_names
                for kind, suffix in (("Binary", "DefaultBinary"), ("Xml", "DefaultXml"),
                                     ("Json", "DefaultJson")):
                    enc = object_ids.get(f"{name}_Encoding_{suffix}")
                    if enc is not None:
                        dt.encodings[kind] = enc
            if num in self.datatypes:
                raise ModelError(f"{name}: DataType i={num} defined twice")
            self.datatypes[num] = dt
        self.notes.append(
            f"{len(elements)} DataTypes come from Opc.Ua.Types.bsd (absent from the NodeSet2)"
        )

    # ---- status codes -------------------------------------------------------------------
    def load_status_codes(self, path: str) -> None:
        text = open(path, encoding="utf-8").read()
        pattern = re.compile(
            r'name:\s*"(\w+)"\s*,\s*value:\s*(0x[0-9a-fA-F]+|\d+)\s*,\s*description:\s*"((?:[^"\\]|\\.)*)"',
            re.S,
        )
        seen = {}
        for name, value, desc in pattern.findall(text):
            v = int(value, 0)
            if name in seen:
                if seen[name] != v:
                    raise ModelError(f"status code {name} defined twice")
                continue
            seen[name] = v
            desc = desc.replace('\\"', '"').replace("\\'", "'")
            self.status_codes.append(StatusCodeEntry(name, v, desc))
        for name, v in (("Good", 0), ("BadDecodingError", 0x80070000), ("BadNodeIdUnknown", 0x80340000)):
            if seen.get(name) != v:
                raise ModelError(f"{path}: expected {name}={v:#x}")
        self.status_codes.sort(key=lambda s: (s.value, s.name))

    # ---- classification -------------------------------------------------------------------
    def ancestors(self, num: int) -> List[int]:
        out = []
        cur = self.datatypes[num].parent if num in self.datatypes else None
        while cur is not None:
            if cur in out:
                raise ModelError(f"subtype cycle at i={num}")
            out.append(cur)
            cur = self.datatypes[cur].parent if cur in self.datatypes else None
        return out

    def is_structure(self, num: int) -> bool:
        return num == STRUCTURE or STRUCTURE in self.ancestors(num)

    def builtin_base(self, num: int) -> Optional[int]:
        """The concrete built-in type a simple DataType derives from (Duration -> Double)."""
        for a in [num] + self.ancestors(num):
            if a in BUILTIN_CPP and a not in (NUMBER, INTEGER, UINTEGER, ENUMERATION, BASEDATATYPE):
                return a
        return None

    def classify(self) -> None:
        for num in sorted(self.datatypes):
            dt = self.datatypes[num]
            anc = self.ancestors(num)
            if num in BUILTIN_CPP or num in (STRUCTURE, BASEDATATYPE):
                dt.kind = "builtin"
            elif num == DECIMAL:
                dt.kind = "skip"  # no C++ representation yet (see notes)
                self.notes.append("Decimal (i=50) is not generated: no built-in representation")
            elif ENUMERATION in anc:
                dt.kind = "abstract" if dt.is_abstract else "enum"
            elif STRUCTURE in anc:
                if dt.is_abstract:
                    dt.kind = "abstract"
                elif UNION in anc:
                    dt.kind = "union"
                else:
                    dt.kind = "struct"
            else:
                base = self.builtin_base(num)
                if base is None:
                    dt.kind = "skip"
                elif dt.is_option_set and base in INTEGER_IDS:
                    dt.kind = "optionset"
                else:
                    dt.kind = "simple"  # includes abstract ones such as Image: an alias is harmless
            if dt.kind in ("struct", "union") and not dt.has_definition:
                raise ModelError(f"{dt.browse_name}: structure without a definition")

    def resolve_inherited_fields(self) -> None:
        """A StructureDefinition should list the inherited fields first (OPC 10000-3 §8.49);
        most NodeSet2 subtypes do, a few (EnumField) list only their own fields: those get
        the base's fields prepended. Compared by name, since schema types use base types."""
        done = set()
        prepended = []

        def resolve(dt: DataType) -> None:
            if dt.id in done:
                return
            done.add(dt.id)
            base = self.datatypes.get(dt.parent) if dt.parent is not None else None
            if base is None or base.id in (STRUCTURE, UNION) or base.kind not in (
                "struct", "union", "abstract"
            ):
                return
            resolve(base)
            if not base.fields:
                return
            names = [f.name for f in base.fields]
            if [f.name for f in dt.fields[: len(names)]] == names:
                return
            if any(f.name in names for f in dt.fields):
                raise ModelError(f"{dt.browse_name}: fields overlap those of {base.browse_name}")
            dt.fields = [Field(**vars(f)) for f in base.fields] + dt.fields
            prepended.append(dt.browse_name)

        for num in sorted(self.datatypes):
            if self.datatypes[num].kind in ("struct", "union", "abstract"):
                resolve(self.datatypes[num])
        if prepended:
            self.notes.append(
                "definitions that omit inherited fields (base fields prepended): "
                + ", ".join(sorted(prepended))
            )


def load(nodeset: str, bsd: str, node_ids: str, status_codes: str,
         fixture: Optional[str] = None) -> Model:
    m = Model()
    m.load_nodeset(nodeset)
    table = m.load_node_id_table(node_ids)
    m.load_bsd_supplement(bsd, table)
    if fixture:
        m.load_nodeset(fixture, fixture=True)
    m.load_status_codes(status_codes)
    m.classify()
    m.resolve_inherited_fields()
    return m
