// Items delivered to callbacks (on a client's background thread), waited for with a
// deadline by the test's thread.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <mutex>
#include <utility>
#include <vector>

namespace pnp::testing {

template <class T>
class Inbox {
  public:
    void put(T v) {
        std::lock_guard lock(m_);
        items_.push_back(std::move(v));
        cv_.notify_all();
    }
    // Waits until pred(items) holds or the timeout passes; returns pred's last result.
    template <class Pred>
    bool waitFor(Pred pred, std::chrono::milliseconds timeout = std::chrono::milliseconds(5000)) {
        std::unique_lock lock(m_);
        return cv_.wait_for(lock, timeout, [&] { return pred(items_); });
    }
    bool waitForCount(std::size_t n,
                      std::chrono::milliseconds timeout = std::chrono::milliseconds(5000)) {
        return waitFor([n](const std::vector<T>& v) { return v.size() >= n; }, timeout);
    }
    std::vector<T> items() {
        std::lock_guard lock(m_);
        return items_;
    }

  private:
    std::mutex m_;
    std::condition_variable cv_;
    std::vector<T> items_;
};

}  // namespace pnp::testing
