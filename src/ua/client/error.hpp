// Client errors and results.
//
// Service-level failures (a ServiceFault, a Bad serviceResult in the ResponseHeader, a
// response that cannot be decoded) and transport failures (connection refused or lost,
// timeouts) are all reported as one exception type, ua::client::Error, which carries the
// StatusCode. Per-operation statuses (one DataValue of a Read, one StatusCode of a Write,
// one CallMethodResult) are returned in the results and never thrown.
#pragma once

#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <variant>

#include "ua/types/status_code.hpp"

namespace pnp::ua::client {

class Error : public std::runtime_error {
  public:
    // what() reads "<message>: BadTimeout (0x800A0000)".
    Error(StatusCode status, std::string_view message);
    StatusCode status() const noexcept { return status_; }

  private:
    StatusCode status_;
};

// The outcome of an asynchronous request: a value or the Error that a blocking call would
// have thrown.
template <class T>
class Result {
  public:
    Result(T value) : v_(std::in_place_index<0>, std::move(value)) {}      // NOLINT
    Result(Error error) : v_(std::in_place_index<1>, std::move(error)) {}  // NOLINT

    bool ok() const noexcept { return v_.index() == 0; }
    explicit operator bool() const noexcept { return ok(); }
    // Good, or the status of the error.
    StatusCode status() const noexcept { return ok() ? StatusCode{} : std::get<1>(v_).status(); }
    // nullptr when ok().
    const Error* error() const noexcept { return std::get_if<1>(&v_); }

    // The value; throws the Error when !ok().
    T& value() & { return check(), std::get<0>(v_); }
    const T& value() const& { return check(), std::get<0>(v_); }
    T&& value() && { return check(), std::move(std::get<0>(v_)); }
    T* operator->() { return &value(); }
    const T* operator->() const { return &value(); }
    T& operator*() & { return value(); }
    const T& operator*() const& { return value(); }

  private:
    void check() const {
        if (!ok()) throw std::get<1>(v_);
    }
    std::variant<T, Error> v_;
};

}  // namespace pnp::ua::client
