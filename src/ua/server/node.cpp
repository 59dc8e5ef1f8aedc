#include "ua/server/node.hpp"

#include <algorithm>
#include <cstring>

namespace pnp::ua::server {

StringPool::StringPool() { views_.emplace_back(); }

StrId StringPool::intern(std::string_view s) {
    if (s.empty()) return 0;
    // Index the strings added since the last call (statics included) so that equal strings
    // share one id.
    for (; indexedUpTo_ < views_.size(); ++indexedUpTo_)
        index_.emplace(views_[indexedUpTo_], static_cast<StrId>(indexedUpTo_));
    auto it = index_.find(s);
    if (it != index_.end()) return it->second;
    const std::string& copy = owned_.emplace_back(s);
    views_.emplace_back(copy);
    auto id = static_cast<StrId>(views_.size() - 1);
    index_.emplace(views_.back(), id);
    indexedUpTo_ = views_.size();
    return id;
}

std::size_t StringPool::bytesUsed() const {
    std::size_t n = views_.capacity() * sizeof(std::string_view);
    for (const auto& s : owned_) n += sizeof(std::string) + (s.size() > 15 ? s.capacity() : 0);
    n += index_.size() * (sizeof(std::string_view) + sizeof(StrId) + 2 * sizeof(void*));
    n += index_.bucket_count() * sizeof(void*);
    return n;
}

RefList& RefList::operator=(RefList&& o) noexcept {
    if (this != &o) {
        release();
        data_ = o.data_;
        size_ = o.size_;
        cap_ = o.cap_;
        o.data_ = nullptr;
        o.size_ = o.cap_ = 0;
    }
    return *this;
}

void RefList::push_back(const Ref& r) {
    if (size_ == cap_ || cap_ == 0) {
        std::uint32_t cap = std::max<std::uint32_t>(4, size_ + size_ / 2 + 1);
        Ref* p = new Ref[cap];
        if (size_ != 0) std::memcpy(p, data_, size_ * sizeof(Ref));
        release();
        data_ = p;
        cap_ = cap;
    }
    data_[size_++] = r;
}

bool RefList::erase(const Ref& r) {
    for (std::uint32_t i = 0; i < size_; ++i) {
        if (data_[i] == r) {
            // Shifting within a borrowed slice is fine: the slice belongs to this node alone.
            std::memmove(data_ + i, data_ + i + 1, (size_ - i - 1) * sizeof(Ref));
            --size_;
            return true;
        }
    }
    return false;
}

}  // namespace pnp::ua::server
