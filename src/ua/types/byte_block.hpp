// ByteBlock: a reference-counted block of bytes (header and bytes in one allocation).
//
// Why: a connection receives into one; a large ByteString decoded from a message can then
// keep a reference to its bytes where they were received instead of copying them (see
// ByteString::shared and BinaryDecoder::shareFrom). The owner of the block (the receive
// buffer) reuses its memory only while it holds the last reference (unique()); otherwise
// it takes a new block and leaves the old one to the values that still point into it.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <new>
#include <utility>

namespace pnp::ua {

class ByteBlock {
  public:
    // A block of `capacity` uninitialised bytes with one reference (the caller's).
    static ByteBlock* create(std::size_t capacity) {
        void* p = std::malloc(sizeof(ByteBlock) + (capacity == 0 ? 1 : capacity));
        if (p == nullptr) throw std::bad_alloc();
        return new (p) ByteBlock(capacity);
    }
    ByteBlock(const ByteBlock&) = delete;
    ByteBlock& operator=(const ByteBlock&) = delete;

    std::uint8_t* data() noexcept { return reinterpret_cast<std::uint8_t*>(this + 1); }
    const std::uint8_t* data() const noexcept {
        return reinterpret_cast<const std::uint8_t*>(this + 1);
    }
    std::size_t capacity() const noexcept { return capacity_; }

    void ref() noexcept { refs_.fetch_add(1, std::memory_order_relaxed); }
    void unref() noexcept {
        // acq_rel: whatever another holder read from the bytes happens before the free (or
        // before the owner, seeing unique(), writes into them again).
        if (refs_.fetch_sub(1, std::memory_order_acq_rel) == 1) {
            this->~ByteBlock();
            std::free(this);
        }
    }
    // True when the caller's reference is the only one.
    bool unique() const noexcept { return refs_.load(std::memory_order_acquire) == 1; }

  private:
    explicit ByteBlock(std::size_t capacity) : capacity_(capacity) {}
    ~ByteBlock() = default;

    std::atomic<std::size_t> refs_{1};
    std::size_t capacity_;
};
static_assert(sizeof(ByteBlock) % alignof(std::max_align_t) == 0,
              "the bytes after the header are aligned for any type");

// An owning reference to a ByteBlock (RAII, like an intrusive shared pointer).
class ByteBlockRef {
  public:
    ByteBlockRef() noexcept = default;
    explicit ByteBlockRef(std::size_t capacity) : b_(ByteBlock::create(capacity)) {}
    ByteBlockRef(const ByteBlockRef& o) noexcept : b_(o.b_) {
        if (b_ != nullptr) b_->ref();
    }
    ByteBlockRef(ByteBlockRef&& o) noexcept : b_(std::exchange(o.b_, nullptr)) {}
    ByteBlockRef& operator=(ByteBlockRef o) noexcept {
        std::swap(b_, o.b_);
        return *this;
    }
    ~ByteBlockRef() {
        if (b_ != nullptr) b_->unref();
    }

    ByteBlock* get() const noexcept { return b_; }
    ByteBlock* operator->() const noexcept { return b_; }
    explicit operator bool() const noexcept { return b_ != nullptr; }

  private:
    ByteBlock* b_ = nullptr;
};

}  // namespace pnp::ua
