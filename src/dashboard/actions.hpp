// What a page asks for (docs/dashboard.md, "Actions"): login, run, halt / suspend / resume /
// reset, startProcess — each answered with one `reply` carrying the OPC UA status.
//
// Each page has its own OPC UA sessions, opened with the identity of its last login
// (anonymous before), so the servers' roles decide what it may do. Work runs on two bounded
// pools, never on the caller's (asio) thread: `workers` threads for the short calls and
// `maxRuns` threads for runs (a run holds its thread until the skill ends: lock, parameters,
// Start, the end, FinalResultData, unlock). Every OPC UA call has a deadline; a full queue is
// answered BadTooManyOperations at once. stop() halts the runs this dashboard started.
#pragma once

#include <chrono>
#include <cstddef>
#include <functional>
#include <memory>
#include <string>
#include <string_view>

#include "dashboard/cell_view.hpp"
#include "dashboard/web_server.hpp"

namespace pnp::dashboard {

struct ActionOptions {
    std::size_t workers = 4;
    std::size_t maxRuns = 8;     // skill runs at the same time
    std::size_t maxQueued = 64;  // per pool
    std::chrono::milliseconds requestTimeout{2000};
    std::chrono::milliseconds connectTimeout{5000};
    std::chrono::milliseconds runTimeout{600000};  // default deadline of a run (timeoutMs)
    std::size_t maxParameters = 64;
    std::size_t maxParameterBytes = 16 * 1024;  // one value's text
    std::size_t maxPages = 64;
};

class Actions {
  public:
    // reply(page, json text): called from the pools' threads (or the caller's for a
    // malformed request).
    using Reply = std::function<void(ClientId page, std::string message)>;

    Actions(const CellView& cell, ActionOptions options, Reply reply);
    ~Actions();  // stop()
    Actions(const Actions&) = delete;
    Actions& operator=(const Actions&) = delete;

    // One message from a page: validated here (bounded, quick), then queued.
    void handle(ClientId page, std::string_view text);
    // The page is gone: its sessions are closed (on a worker).
    void pageClosed(ClientId page);
    void stop();

    struct Impl;

  private:
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::dashboard
