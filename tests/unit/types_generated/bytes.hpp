// Byte buffers written out in a test, and decoding a whole buffer as one value.
#pragma once

#include <initializer_list>

#include "ua/types/binary.hpp"

namespace pnp::ua::testgen {

inline Buffer bytes(std::initializer_list<int> v) {
    Buffer b;
    for (int x : v) b.push_back(static_cast<Byte>(x));
    return b;
}

template <class T>
T decodeAll(const Buffer& b) {
    return decodeFromBuffer<T>(b.data(), b.size());
}

}  // namespace pnp::ua::testgen
