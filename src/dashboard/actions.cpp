#include "dashboard/actions.hpp"

#include <condition_variable>
#include <deque>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <stop_token>
#include <thread>
#include <vector>

#include "dashboard/client_config.hpp"
#include "skill/client/generic_client.hpp"
#include "ua/client/client.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::dashboard {

namespace {

using json = nlohmann::json;
using skill::client::GenericSkillClient;
using ua::client::Error;

constexpr std::size_t kMaxIdBytes = 128;
constexpr std::size_t kMaxCredentialBytes = 256;

// A fixed number of threads over a bounded queue.
class Pool {
  public:
    Pool(std::size_t threads, std::size_t maxQueued) : maxQueued_(maxQueued) {
        for (std::size_t i = 0; i < threads; ++i)
            threads_.emplace_back([this](std::stop_token) { run(); });
    }
    ~Pool() { stop(); }
    bool post(std::function<void()> job) {
        {
            std::lock_guard lock(mutex_);
            if (stopped_ || jobs_.size() >= maxQueued_) return false;
            jobs_.push_back(std::move(job));
        }
        wake_.notify_one();
        return true;
    }
    void stop() {
        {
            std::lock_guard lock(mutex_);
            stopped_ = true;
            jobs_.clear();
        }
        wake_.notify_all();
        threads_.clear();  // joins
    }

  private:
    void run() {
        for (;;) {
            std::function<void()> job;
            {
                std::unique_lock lock(mutex_);
                wake_.wait(lock, [&] { return stopped_ || !jobs_.empty(); });
                if (stopped_) return;
                job = std::move(jobs_.front());
                jobs_.pop_front();
            }
            try {
                job();
            } catch (...) {
                // a job answers its own errors
            }
        }
    }
    std::size_t maxQueued_;
    std::mutex mutex_;
    std::condition_variable wake_;
    std::deque<std::function<void()>> jobs_;
    bool stopped_ = false;
    std::vector<std::jthread> threads_;
};

std::string statusName(ua::StatusCode s) { return std::string(s.name()); }

}  // namespace

struct Actions::Impl {
    const CellView& cell;
    ActionOptions options;
    Reply reply;

    // A page's identity and its sessions (one per server), its skill handles.
    struct Page {
        std::mutex mutex;
        ua::client::Identity identity = ua::client::Anonymous{};
        std::string user;
        std::map<std::string, std::shared_ptr<ua::client::Client>> sessions;
        std::map<std::string, std::shared_ptr<GenericSkillClient>> skills;
    };
    std::mutex mutex;
    std::map<ClientId, std::shared_ptr<Page>> pages;
    std::stop_source stopRuns;
    Pool quick;
    Pool runs;

    Impl(const CellView& c, ActionOptions o, Reply r)
        : cell(c),
          options(std::move(o)),
          reply(std::move(r)),
          quick(options.workers, options.maxQueued),
          runs(options.maxRuns, options.maxQueued) {}

    void answer(ClientId page, const json& id, bool ok, const std::string& status,
                const std::string& message, json result = nullptr) {
        json m = {
            {"type", "reply"}, {"id", id}, {"ok", ok}, {"status", status}, {"message", message}};
        if (!result.is_null()) m["result"] = std::move(result);
        reply(page, m.dump());
    }

    std::shared_ptr<Page> page(ClientId id) {
        std::lock_guard lock(mutex);
        auto it = pages.find(id);
        if (it != pages.end()) return it->second;
        if (pages.size() >= options.maxPages) return nullptr;
        return pages.emplace(id, std::make_shared<Page>()).first->second;
    }

    ua::client::ClientConfig clientConfig() const {
        return dashboard::clientConfig(options.requestTimeout, options.connectTimeout);
    }

    // The page's session with the skill's server and its handle on the skill (cached).
    std::shared_ptr<GenericSkillClient> skillFor(Page& p, const SkillTarget& t) {
        std::lock_guard lock(p.mutex);
        if (auto it = p.skills.find(t.id); it != p.skills.end()) return it->second;
        auto& session = p.sessions[t.endpointUrl];
        if (!session) {
            auto client = std::make_shared<ua::client::Client>(clientConfig());
            client->connect(t.endpointUrl, p.identity, options.connectTimeout);
            client->startBackgroundThread();
            session = std::move(client);
        }
        auto sc = std::make_shared<GenericSkillClient>(
            session, t.node, ua::client::Deadline(options.requestTimeout));
        p.skills[t.id] = sc;
        return sc;
    }

    void dropSessions(Page& p) {
        std::map<std::string, std::shared_ptr<ua::client::Client>> sessions;
        {
            std::lock_guard lock(p.mutex);
            p.skills.clear();
            sessions.swap(p.sessions);
        }
        for (auto& [url, s] : sessions) s->disconnect();
    }

    // Runs `work` and answers with its outcome: an Error's status, another exception's text.
    template <class F>
    void guarded(ClientId page, const json& id, F&& work) {
        try {
            work();
        } catch (const Error& e) {
            answer(page, id, false, statusName(e.status()), e.what());
        } catch (const std::exception& e) {
            answer(page, id, false, "BadInternalError", e.what());
        }
    }

    void login(ClientId pageId, const json& id, std::string user, std::string password) {
        auto p = page(pageId);
        if (!p) return answer(pageId, id, false, "BadTooManySessions", "too many pages");
        guarded(pageId, id, [&] {
            ua::client::Identity identity = ua::client::Anonymous{};
            if (!user.empty()) identity = ua::client::UserName{user, password};
            const std::string url = cell.anySkillServer();
            if (url.empty())
                throw Error(ua::status::BadNotConnected,
                            "no server with skills to check the login on");
            // The server decides: a session with that identity is opened and closed.
            ua::client::Client probe(clientConfig());
            probe.connect(url, identity, options.connectTimeout);
            probe.disconnect();
            dropSessions(*p);
            {
                std::lock_guard lock(p->mutex);
                p->identity = identity;
                p->user = user;
            }
            answer(
                pageId, id, true, "Good",
                user.empty() ? "anonymous" : "logged in as " + user + " (checked on " + url + ")",
                json{{"user", user.empty() ? json(nullptr) : json(user)}});
        });
    }

    void program(ClientId pageId, const json& id, const std::string& action, const SkillTarget& t) {
        auto p = page(pageId);
        if (!p) return answer(pageId, id, false, "BadTooManySessions", "too many pages");
        guarded(pageId, id, [&] {
            auto sc = skillFor(*p, t);
            const ua::client::Deadline d(options.requestTimeout);
            if (action == "halt")
                sc->halt(d);
            else if (action == "suspend")
                sc->suspend(d);
            else if (action == "resume")
                sc->resume(d);
            else
                sc->reset(d);
            answer(pageId, id, true, "Good", action + " " + t.name);
        });
    }

    static json runResultJson(const skill::client::RunResult& r) {
        json values = json::object();
        for (const auto& [name, value] : r.finalResult.values) {
            std::string text = skill::client::formatValue(value);
            if (text.size() > 4096) text = text.substr(0, 4096) + "...";
            values[name] = text;
        }
        return {{"result", std::string(skill::toString(r.result))},
                {"message", r.message.empty() ? r.finalResult.message : r.message},
                {"timedOut", r.timedOut},
                {"values", values}};
    }

    void run(ClientId pageId, const json& id, const SkillTarget& t,
             std::vector<std::string> assignments, std::chrono::milliseconds timeout) {
        auto p = page(pageId);
        if (!p) return answer(pageId, id, false, "BadTooManySessions", "too many pages");
        guarded(pageId, id, [&] {
            auto sc = skillFor(*p, t);
            // Converted by the server's DataTypes; a bad value throws here, before any call.
            const auto params = sc->parse(assignments);
            const auto r = sc->run(params, ua::client::Deadline(timeout), stopRuns.get_token());
            const bool ok = r.result == skill::SkillResult::Completed;
            answer(pageId, id, ok, ok ? "Good" : "BadInvalidState",
                   t.name + ": " + std::string(skill::toString(r.result)) +
                       (r.message.empty() ? "" : " (" + r.message + ")"),
                   runResultJson(r));
        });
    }

    void handle(ClientId pageId, std::string_view text) {
        const json m = json::parse(text, nullptr, false);
        json id = nullptr;
        if (!m.is_object())
            return answer(pageId, id, false, "BadDecodingError", "not a JSON object");
        if (m.contains("id")) {
            id = m["id"];
            const bool okId =
                (id.is_string() && id.get<std::string>().size() <= kMaxIdBytes) || id.is_number();
            if (!okId) return answer(pageId, nullptr, false, "BadInvalidArgument", "bad id");
        }
        const std::string action = m.value("action", "");
        auto text_of = [&](const char* key, std::size_t max) -> std::optional<std::string> {
            if (!m.contains(key)) return std::string();
            if (!m[key].is_string() || m[key].get<std::string>().size() > max) return std::nullopt;
            return m[key].get<std::string>();
        };
        auto post = [&](Pool& pool, std::function<void()> job) {
            if (!pool.post(std::move(job)))
                answer(pageId, id, false, "BadTooManyOperations", "busy: try again");
        };
        if (action == "login" || action == "logout") {
            auto user = text_of("user", kMaxCredentialBytes);
            auto password = text_of("password", kMaxCredentialBytes);
            if (!user || !password)
                return answer(pageId, id, false, "BadInvalidArgument", "user / password");
            if (action == "logout") user->clear();
            return post(
                quick, [this, pageId, id, u = *user, pw = *password] { login(pageId, id, u, pw); });
        }
        if (action == "halt" || action == "suspend" || action == "resume" || action == "reset" ||
            action == "run") {
            const auto skillId = text_of("skill", 4096);
            if (!skillId || skillId->empty())
                return answer(pageId, id, false, "BadInvalidArgument", "skill: the skill's id");
            const auto target = cell.skill(*skillId);
            if (!target) return answer(pageId, id, false, "BadNodeIdUnknown", "no such skill");
            if (action != "run")
                return post(quick, [this, pageId, id, action, t = *target] {
                    program(pageId, id, action, t);
                });
            std::vector<std::string> assignments;
            if (m.contains("parameters")) {
                const auto& ps = m["parameters"];
                if (!ps.is_object() || ps.size() > options.maxParameters)
                    return answer(pageId, id, false, "BadInvalidArgument",
                                  "parameters: an object of at most " +
                                      std::to_string(options.maxParameters) + " names");
                for (const auto& [name, value] : ps.items()) {
                    std::string v = value.is_string() ? value.get<std::string>() : value.dump();
                    if (name.size() > 256 || v.size() > options.maxParameterBytes)
                        return answer(pageId, id, false, "BadInvalidArgument",
                                      "parameter " + name.substr(0, 64) + ": too long");
                    assignments.push_back(name + "=" + v);
                }
            }
            auto timeout = options.runTimeout;
            if (m.contains("timeoutMs") && m["timeoutMs"].is_number_integer()) {
                const auto ms = m["timeoutMs"].get<long long>();
                if (ms < 1 || ms > 86'400'000)
                    return answer(pageId, id, false, "BadInvalidArgument", "timeoutMs");
                timeout = std::chrono::milliseconds(ms);
            }
            return post(runs, [this, pageId, id, t = *target, a = std::move(assignments), timeout] {
                run(pageId, id, t, a, timeout);
            });
        }
        if (action == "startProcess") {
            const auto iri = text_of("processIri", 4096);
            if (!iri || iri->empty())
                return answer(pageId, id, false, "BadInvalidArgument", "processIri");
            const auto target = cell.processSkill();
            if (!target)
                return answer(pageId, id, false, "BadNotFound", "no MES (ExecuteProcess) detected");
            auto timeout = options.runTimeout;
            return post(runs, [this, pageId, id, t = *target, iri = *iri, timeout] {
                run(pageId, id, t, {"ProcessIri=" + iri}, timeout);
            });
        }
        answer(pageId, id, false, "BadNotSupported",
               "unknown action (login, logout, run, halt, suspend, resume, reset, startProcess)");
    }
};

Actions::Actions(const CellView& cell, ActionOptions options, Reply reply)
    : impl_(std::make_unique<Impl>(cell, std::move(options), std::move(reply))) {}

Actions::~Actions() { stop(); }

void Actions::handle(ClientId page, std::string_view text) { impl_->handle(page, text); }

void Actions::pageClosed(ClientId pageId) {
    std::shared_ptr<Impl::Page> p;
    {
        std::lock_guard lock(impl_->mutex);
        const auto it = impl_->pages.find(pageId);
        if (it == impl_->pages.end()) return;
        p = it->second;
        impl_->pages.erase(it);
    }
    Impl* d = impl_.get();
    // Not on the caller's thread: CloseSession waits for its answer (bounded).
    if (!d->quick.post([d, p] { d->dropSessions(*p); })) {
        // queue full: the sessions close when the last run holding them ends
    }
}

void Actions::stop() {
    impl_->stopRuns.request_stop();  // runs halt their skill and unlock it
    impl_->runs.stop();
    impl_->quick.stop();
    std::lock_guard lock(impl_->mutex);
    impl_->pages.clear();
}

}  // namespace pnp::dashboard
