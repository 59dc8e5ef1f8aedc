// Buffer: the growable byte array every encoded message lives in.
//
// Why not std::vector<Byte>: the encoder appends a few bytes at a time (a UInt32, a length
// prefix), and std::vector can only grow its size through resize()/insert(), whose
// out-of-line reallocation path keeps them from being inlined — about 40 instructions per
// field. Buffer::append(n) is a bounds check and an add. Grown bytes are left uninitialised
// (they are about to be overwritten by the encoder or by recv()), so a 32 KiB payload is not
// written twice. Otherwise it behaves like std::vector<Byte> (the subset this code base uses).
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <initializer_list>
#include <iterator>
#include <new>
#include <utility>
#include <vector>

namespace pnp::ua {

class Buffer {
  public:
    using value_type = std::uint8_t;
    using size_type = std::size_t;
    using difference_type = std::ptrdiff_t;
    using reference = value_type&;
    using const_reference = const value_type&;
    using pointer = value_type*;
    using const_pointer = const value_type*;
    using iterator = value_type*;
    using const_iterator = const value_type*;

    Buffer() noexcept = default;
    // n bytes, uninitialised.
    explicit Buffer(size_type n) { resize(n); }
    Buffer(size_type n, value_type v) { resize(n, v); }
    Buffer(std::initializer_list<value_type> v) { assign(v.begin(), v.end()); }
    template <class It, class = typename std::iterator_traits<It>::iterator_category>
    Buffer(It first, It last) {
        assign(first, last);
    }
    Buffer(const Buffer& o) { assign(o.begin(), o.end()); }
    Buffer(Buffer&& o) noexcept
        : data_(std::exchange(o.data_, nullptr)),
          size_(std::exchange(o.size_, 0)),
          capacity_(std::exchange(o.capacity_, 0)) {}
    Buffer& operator=(const Buffer& o) {
        if (this != &o) assign(o.begin(), o.end());
        return *this;
    }
    Buffer& operator=(Buffer&& o) noexcept {
        if (this != &o) {
            std::free(data_);
            data_ = std::exchange(o.data_, nullptr);
            size_ = std::exchange(o.size_, 0);
            capacity_ = std::exchange(o.capacity_, 0);
        }
        return *this;
    }
    Buffer& operator=(std::initializer_list<value_type> v) {
        assign(v.begin(), v.end());
        return *this;
    }
    ~Buffer() { std::free(data_); }

    pointer data() noexcept { return data_; }
    const_pointer data() const noexcept { return data_; }
    size_type size() const noexcept { return size_; }
    size_type capacity() const noexcept { return capacity_; }
    bool empty() const noexcept { return size_ == 0; }
    iterator begin() noexcept { return data_; }
    iterator end() noexcept { return data_ + size_; }
    const_iterator begin() const noexcept { return data_; }
    const_iterator end() const noexcept { return data_ + size_; }
    const_iterator cbegin() const noexcept { return data_; }
    const_iterator cend() const noexcept { return data_ + size_; }
    reference operator[](size_type i) noexcept { return data_[i]; }
    const_reference operator[](size_type i) const noexcept { return data_[i]; }
    reference front() noexcept { return data_[0]; }
    const_reference front() const noexcept { return data_[0]; }
    reference back() noexcept { return data_[size_ - 1]; }
    const_reference back() const noexcept { return data_[size_ - 1]; }

    // Grows the size by n (uninitialised bytes) and returns where they start. The fast path
    // of every encoder write.
    pointer append(size_type n) {
        if (capacity_ - size_ < n) grow(size_ + n);
        pointer p = data_ + size_;
        size_ += n;
        return p;
    }

    void reserve(size_type n) {
        if (n > capacity_) reallocate(n);
    }
    // New bytes are uninitialised.
    void resize(size_type n) {
        if (n > capacity_) reallocate(std::max(n, capacity_ * 2));
        size_ = n;
    }
    void resize(size_type n, value_type v) {
        size_type old = size_;
        resize(n);
        if (n > old) std::memset(data_ + old, v, n - old);
    }
    void clear() noexcept { size_ = 0; }
    void push_back(value_type v) { *append(1) = v; }

    template <class It>
    void assign(It first, It last) {
        clear();
        insert(end(), first, last);
    }
    template <class It, class = typename std::iterator_traits<It>::iterator_category>
    iterator insert(const_iterator pos, It first, It last) {
        const size_type at = static_cast<size_type>(pos - data_);
        const auto n = static_cast<size_type>(std::distance(first, last));
        if (n == 0) return data_ + at;
        if constexpr (std::is_pointer_v<It>) {
            // The source may lie inside this buffer: copy it out before reallocating.
            const auto a = reinterpret_cast<std::uintptr_t>(first);
            const auto b = reinterpret_cast<std::uintptr_t>(data_);
            if (a >= b && a < b + size_) {
                const std::vector<value_type> copy(first, last);
                return insert(pos, copy.begin(), copy.end());
            }
        }
        append(n);
        std::memmove(data_ + at + n, data_ + at, size_ - n - at);
        std::copy(first, last, data_ + at);
        return data_ + at;
    }
    iterator insert(const_iterator pos, value_type v) { return insert(pos, &v, &v + 1); }
    iterator insert(const_iterator pos, std::initializer_list<value_type> v) {
        return insert(pos, v.begin(), v.end());
    }
    iterator erase(const_iterator first, const_iterator last) noexcept {
        const auto at = static_cast<size_type>(first - data_);
        const auto n = static_cast<size_type>(last - first);
        std::memmove(data_ + at, data_ + at + n, size_ - at - n);
        size_ -= n;
        return data_ + at;
    }
    iterator erase(const_iterator pos) noexcept { return erase(pos, pos + 1); }

    friend bool operator==(const Buffer& a, const Buffer& b) noexcept {
        return a.size_ == b.size_ && (a.size_ == 0 || std::memcmp(a.data_, b.data_, a.size_) == 0);
    }

  private:
    // Room for at least `needed` bytes, at least doubling (amortised O(1) appends).
    void grow(size_type needed) { reallocate(std::max(needed, capacity_ * 2)); }
    void reallocate(size_type n) {
        void* p = std::realloc(data_, n == 0 ? 1 : n);
        if (p == nullptr) throw std::bad_alloc();
        data_ = static_cast<pointer>(p);
        capacity_ = n;
    }

    pointer data_ = nullptr;
    size_type size_ = 0;
    size_type capacity_ = 0;
};

}  // namespace pnp::ua
