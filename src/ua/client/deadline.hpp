// Deadlines of client calls.
//
// Every blocking call of the client takes a Deadline as its last parameter:
//   client.readValue(id);                              // config().requestTimeout from now
//   client.readValue(id, std::chrono::milliseconds(50)); // 50 ms from now
//   client.readValue(id, Clock::now() + 2s);           // absolute point in time
//   client.readValue(id, Deadline::never());
// When the deadline passes before the response arrived, the call throws
// Error(BadTimeout); the connection stays usable and the late response is discarded.
#pragma once

#include <chrono>

namespace pnp::ua::client {

using Clock = std::chrono::steady_clock;

class Deadline {
  public:
    // The default: the relevant timeout of the ClientConfig, counted from the call.
    constexpr Deadline() = default;
    // Relative to the moment of the call.
    template <class Rep, class Period>
    constexpr Deadline(std::chrono::duration<Rep, Period> d)  // NOLINT: implicit by design
        : kind_(Kind::Relative), rel_(saturate(d)) {}
    // Absolute.
    constexpr Deadline(Clock::time_point t)  // NOLINT: implicit by design
        : kind_(Kind::Absolute), abs_(t) {}

    static constexpr Deadline never() { return Deadline(Clock::time_point::max()); }

    constexpr bool isDefault() const { return kind_ == Kind::Default; }

    // The absolute time point; `fallback` is used for a default Deadline.
    constexpr Clock::time_point resolve(Clock::time_point now, Clock::duration fallback) const {
        switch (kind_) {
            case Kind::Absolute:
                return abs_;
            case Kind::Relative:
                return addSaturated(now, rel_);
            case Kind::Default:
                break;
        }
        return addSaturated(now, fallback);
    }

  private:
    enum class Kind : unsigned char { Default, Relative, Absolute };
    template <class Rep, class Period>
    static constexpr Clock::duration saturate(std::chrono::duration<Rep, Period> d) {
        using Wide = std::chrono::duration<long double, Clock::period>;
        if (Wide(d) >= Wide(Clock::duration::max())) return Clock::duration::max();
        if (Wide(d) <= Wide(Clock::duration::min())) return Clock::duration::min();
        return std::chrono::duration_cast<Clock::duration>(d);
    }
    static constexpr Clock::time_point addSaturated(Clock::time_point t, Clock::duration d) {
        if (d <= Clock::duration::zero()) return t;
        if (t > Clock::time_point::max() - d) return Clock::time_point::max();
        return t + d;
    }

    Kind kind_ = Kind::Default;
    Clock::duration rel_{};
    Clock::time_point abs_{};
};

}  // namespace pnp::ua::client
