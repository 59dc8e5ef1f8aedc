// Scatter-gather helpers of the two socket layers: the pieces of a chunk encoded with
// Splices (the Buffer's bytes, with the referenced runs in between) as iovecs.
#pragma once

#include <sys/socket.h>
#include <sys/uio.h>

#include <algorithm>
#include <climits>
#include <cstddef>

#include "ua/types/binary.hpp"

namespace pnp::ua::transport {

// Calls add(const Byte* p, std::size_t n) for each piece of `bytes` with `splices` woven in,
// in wire order, leaving out the first `skip` bytes and empty pieces. Stops early when add
// returns false.
template <class F>
void forEachPiece(const Buffer& bytes, const Splices& splices, std::size_t skip, F&& add) {
    auto piece = [&](const Byte* p, std::size_t n) {
        if (skip >= n) {
            skip -= n;
            return true;
        }
        p += skip;
        n -= skip;
        skip = 0;
        return add(p, n);
    };
    std::size_t from = 0;
    for (const Splice& s : splices) {
        if (!piece(bytes.data() + from, s.at - from)) return;
        if (!piece(s.data, s.size)) return;
        from = s.at;
    }
    piece(bytes.data() + from, bytes.size() - from);
}

// Drops the first n bytes of iov[0..count): returns the first iovec not completely written
// (adjusted) and decrements count accordingly.
inline iovec* advanceIovecs(iovec* iov, std::size_t& count, std::size_t n) {
    while (count > 0 && n >= iov->iov_len) {
        n -= iov->iov_len;
        ++iov;
        --count;
    }
    if (count > 0 && n > 0) {
        iov->iov_base = static_cast<Byte*>(iov->iov_base) + n;
        iov->iov_len -= n;
    }
    return iov;
}

// Writes iov[0..count) with one system call. A single piece goes through send(): the kernel
// then copies no msghdr and no iovec array in (about 0.1 us of a loopback round trip).
inline ssize_t sendPieces(int fd, iovec* iov, std::size_t count, int flags) {
    if (count == 1) return ::send(fd, iov->iov_base, iov->iov_len, flags);
    msghdr m{};
    m.msg_iov = iov;
    m.msg_iovlen = std::min<std::size_t>(count, IOV_MAX);
    return ::sendmsg(fd, &m, flags);
}

}  // namespace pnp::ua::transport
