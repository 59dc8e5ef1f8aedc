// Text form of RelativePaths (OPC 10000-4 Annex A.2), used by Client::resolve().
//
//   /2:Demo/2:Scalar&.Int32   "/"  follows HierarchicalReferences (and subtypes), forward
//   .3:Prop                   "."  follows Aggregates (and subtypes), forward
//   <HasComponent>1:X         "<RefType>" a named reference type (and subtypes)
//   <#Organizes>X             "#"  without subtypes
//   <!HasChild>X              "!"  inverse
//   <i=47>X, <ns=1;i=5>X      a reference type given by its NodeId (an extension)
//
// A browse name is "Name", "<index>:Name" or "<namespace uri>:Name" (the prefix ends at the
// last unescaped ':'; URIs are looked up with the resolver). Reserved characters
// / . < > : # ! & inside names are escaped with '&' ("Scalar&.Int32").
#pragma once

#include <functional>
#include <string_view>

#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::client {

// Maps a namespace URI to its index, or throws.
using NamespaceResolver = std::function<UInt16(std::string_view uri)>;

// Throws Error(BadSyntaxError) when the text is malformed, Error(BadNoMatch) for an unknown
// reference type name, Error(BadNotSupported) for a URI prefix without a resolver.
RelativePath parseRelativePath(std::string_view text, const NamespaceResolver& resolver = {});

// The NodeId of a well-known ns0 reference type by its BrowseName ("HasComponent"), or a
// null NodeId.
NodeId referenceTypeByName(std::string_view name);

}  // namespace pnp::ua::client
