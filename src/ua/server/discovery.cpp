#include "ua/server/discovery.hpp"

#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <limits>

#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::server {

namespace {
std::string lower(std::string_view s) {
    std::string out(s);
    for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return out;
}

std::string recordKey(const std::string& name, const std::string& url) {
    std::string k;
    k.reserve(name.size() + 1 + url.size());
    k.append(name).push_back('\0');
    k.append(url);
    return k;
}

bool fileExists(const std::string& path) {
    struct stat st {};
    return ::stat(path.c_str(), &st) == 0;
}

// The server name for the requested locales (Part 4 §5.4.2: in the first requested locale
// available, else any): exact match first, then the same language ("en" for "en-US").
const LocalizedText& pickName(const std::vector<LocalizedText>& names,
                              const std::vector<String>& localeIds) {
    auto language = [](std::string_view l) { return lower(l.substr(0, l.find('-'))); };
    for (const auto& want : localeIds) {
        std::string w = lower(want);
        for (const auto& n : names)
            if (lower(n.locale) == w) return n;
        std::string lang = language(want);
        for (const auto& n : names)
            if (language(n.locale) == lang) return n;
    }
    return names.front();
}

const String& mdnsName(const Registration& r) {
    if (!r.mdns->mdnsServerName.empty()) return r.mdns->mdnsServerName;
    for (const auto& n : r.server.serverNames)
        if (!n.text.empty()) return n.text;
    return r.server.serverUri;
}
}  // namespace

LocalDiscovery::LocalDiscovery(DiscoveryConfig config)
    : config_(std::move(config)), lastCounterResetTime_(DateTime::now()) {}

LocalDiscovery::~LocalDiscovery() { stop(); }

void LocalDiscovery::start() {
    std::lock_guard lock(mutex_);
    if (thread_.joinable()) return;
    stopping_ = false;
    thread_ = std::thread([this] { run(); });
}

void LocalDiscovery::stop() {
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
        pending_.clear();
        overflowed_ = false;
    }
    wake_.notify_all();
    if (thread_.joinable() && thread_.get_id() != std::this_thread::get_id()) thread_.join();
}

// ---- the table of records (FindServersOnNetwork) ---------------------------------------------
std::uint32_t LocalDiscovery::nextRecordIdLocked() {
    if (nextRecordId_ == std::numeric_limits<std::uint32_t>::max()) {
        // The counter would wrap: renumber from 1 and tell clients through
        // lastCounterResetTime that earlier ids mean nothing now (Part 4 §5.4.3).
        std::map<std::uint32_t, Record> renumbered;
        std::uint32_t id = 1;
        for (auto& [old, r] : records_) {
            r.data.recordId = id;
            recordIds_[recordKey(r.data.serverName, r.data.discoveryUrl)] = id;
            renumbered.emplace(id++, std::move(r));
        }
        records_ = std::move(renumbered);
        nextRecordId_ = id;
        lastCounterResetTime_ = DateTime::now();
    }
    return nextRecordId_++;
}

std::uint32_t LocalDiscovery::upsertRecordLocked(const std::string& name, const std::string& url,
                                                 const std::vector<std::string>& caps,
                                                 Source source) {
    auto key = recordKey(name, url);
    auto it = recordIds_.find(key);
    Record* r;
    if (it != recordIds_.end()) {
        r = &records_.at(it->second);
    } else {
        std::uint32_t id = nextRecordIdLocked();
        r = &records_[id];
        r->data.recordId = id;
        r->data.serverName = name;
        r->data.discoveryUrl = url;
        recordIds_.emplace(std::move(key), id);
    }
    // The latest source wins the capabilities (the glue hears our own announcements too).
    r->data.serverCapabilities = caps;
    r->lowerCapabilities.clear();
    for (const auto& c : caps) r->lowerCapabilities.push_back(lower(c));
    switch (source) {
        case Source::Registration:
            ++r->registrations;
            break;
        case Source::Network:
            if (!r->network) ++networkRecordCount_;
            r->network = true;
            break;
        case Source::Self:
            r->self = true;
            break;
    }
    return r->data.recordId;
}

bool LocalDiscovery::releaseRecordLocked(const std::string& name, const std::string& url,
                                         Source source) {
    auto it = recordIds_.find(recordKey(name, url));
    if (it == recordIds_.end()) return false;
    auto rit = records_.find(it->second);
    Record& r = rit->second;
    switch (source) {
        case Source::Registration:
            if (r.registrations == 0) return false;
            --r.registrations;
            break;
        case Source::Network:
            if (!r.network) return false;
            r.network = false;
            --networkRecordCount_;
            break;
        case Source::Self:
            if (!r.self) return false;
            r.self = false;
            break;
    }
    if (r.registrations == 0 && !r.network && !r.self) {
        records_.erase(rit);
        recordIds_.erase(it);
    }
    return true;
}

void LocalDiscovery::addRecordsLocked(const Registration& reg) {
    if (!reg.mdns) return;
    for (const auto& url : reg.server.discoveryUrls)
        upsertRecordLocked(mdnsName(reg), url, reg.mdns->serverCapabilities, Source::Registration);
}

void LocalDiscovery::dropRecordsLocked(const Registration& reg) {
    if (!reg.mdns) return;
    for (const auto& url : reg.server.discoveryUrls)
        releaseRecordLocked(mdnsName(reg), url, Source::Registration);
}

bool LocalDiscovery::validRecord(const NetworkRecord& r) const {
    if (r.serverName.empty() || r.discoveryUrl.empty()) return false;
    if (r.serverName.size() > config_.maxStringLength ||
        r.discoveryUrl.size() > config_.maxStringLength ||
        r.serverCapabilities.size() > config_.maxListLength)
        return false;
    return std::none_of(r.serverCapabilities.begin(), r.serverCapabilities.end(),
                        [&](const auto& c) { return c.size() > config_.maxStringLength; });
}

void LocalDiscovery::setSelf(NetworkRecord self) {
    std::lock_guard lock(mutex_);
    if (self_) releaseRecordLocked(self_->serverName, self_->discoveryUrl, Source::Self);
    upsertRecordLocked(self.serverName, self.discoveryUrl, self.serverCapabilities, Source::Self);
    self_ = std::move(self);
}

std::uint32_t LocalDiscovery::addNetworkRecord(NetworkRecord record) {
    if (!validRecord(record)) return 0;
    std::lock_guard lock(mutex_);
    if (networkRecordCount_ >= config_.maxNetworkRecords &&
        !recordIds_.contains(recordKey(record.serverName, record.discoveryUrl)))
        return 0;
    return upsertRecordLocked(record.serverName, record.discoveryUrl, record.serverCapabilities,
                              Source::Network);
}

bool LocalDiscovery::removeNetworkRecord(const std::string& serverName,
                                         const std::string& discoveryUrl) {
    std::lock_guard lock(mutex_);
    return releaseRecordLocked(serverName, discoveryUrl, Source::Network);
}

void LocalDiscovery::setNextRecordIdForTesting(std::uint32_t id) {
    std::lock_guard lock(mutex_);
    nextRecordId_ = std::max<std::uint32_t>(id, 1);
}

std::vector<ServerOnNetwork> LocalDiscovery::records() const {
    std::lock_guard lock(mutex_);
    std::vector<ServerOnNetwork> out;
    out.reserve(records_.size());
    for (const auto& [id, r] : records_) out.push_back(r.data);
    return out;
}

// ---- registrations ----------------------------------------------------------------------
std::size_t LocalDiscovery::onRegistrationsChanged(Observer observer) {
    std::lock_guard lock(mutex_);
    observers_.emplace(nextObserverId_, std::move(observer));
    return nextObserverId_++;
}

void LocalDiscovery::removeObserver(std::size_t id) {
    std::lock_guard lock(mutex_);
    observers_.erase(id);
}

std::vector<Registration> LocalDiscovery::registeredServers() const {
    std::lock_guard lock(mutex_);
    std::vector<Registration> out;
    out.reserve(registrations_.size());
    for (const auto& [uri, e] : registrations_) out.push_back(e.registration);
    return out;
}

void LocalDiscovery::queueLocked(RegistrationEvent event) {
    // Without observers nobody waits for events: do not pile them up.
    if (observers_.empty()) return;
    if (pending_.size() >= config_.maxPendingEvents) {
        overflowed_ = true;
        return;
    }
    pending_.push_back(std::move(event));
    wake_.notify_all();
}

StatusCode LocalDiscovery::validate(const RegisteredServer& s) const {
    const std::size_t maxLen = config_.maxStringLength;
    auto tooLong = [&](const std::string& x) { return x.size() > maxLen; };
    if (s.serverUri.empty() || tooLong(s.serverUri)) return status::BadServerUriInvalid;
    if (s.serverNames.size() > config_.maxListLength ||
        s.discoveryUrls.size() > config_.maxListLength)
        return status::BadTooManyOperations;
    bool named = false;
    for (const auto& n : s.serverNames) {
        if (tooLong(n.text) || tooLong(n.locale)) return status::BadInvalidArgument;
        named |= !n.text.empty();
    }
    if (!named) return status::BadServerNameMissing;
    if (s.discoveryUrls.empty()) return status::BadDiscoveryUrlMissing;
    for (const auto& u : s.discoveryUrls) {
        if (u.empty()) return status::BadDiscoveryUrlMissing;
        if (tooLong(u)) return status::BadInvalidArgument;
    }
    if (tooLong(s.productUri) || tooLong(s.gatewayServerUri) || tooLong(s.semaphoreFilePath))
        return status::BadInvalidArgument;
    // Clients register servers; a Client is not one. Unknown enumeration values neither.
    if (s.serverType != ApplicationType::Server &&
        s.serverType != ApplicationType::ClientAndServer &&
        s.serverType != ApplicationType::DiscoveryServer)
        return status::BadInvalidArgument;
    if (!s.semaphoreFilePath.empty()) {
        // An embedded NUL would make stat() look at another path.
        if (s.semaphoreFilePath.find('\0') != std::string::npos) return status::BadInvalidArgument;
        if (!fileExists(s.semaphoreFilePath)) return status::BadSemaphoreFileMissing;
    }
    return status::Good;
}

void LocalDiscovery::removeLocked(const std::string& serverUri, RegistrationEvent::Reason reason) {
    auto it = registrations_.find(serverUri);
    if (it == registrations_.end()) return;
    expiry_.erase({it->second.expiresAt, serverUri});
    dropRecordsLocked(it->second.registration);
    RegistrationEvent ev;
    ev.kind = RegistrationEvent::Kind::Removed;
    ev.reason = reason;
    ev.registration = std::move(it->second.registration);
    registrations_.erase(it);
    queueLocked(std::move(ev));
}

StatusCode LocalDiscovery::apply(Registration reg) {
    std::lock_guard lock(mutex_);
    const std::string uri = reg.server.serverUri;
    if (!reg.server.isOnline) {
        // Unregistering an unknown server is not an error: it may have expired already.
        removeLocked(uri, RegistrationEvent::Reason::Unregistered);
        return status::Good;
    }
    const auto expiresAt = Clock::now() + config_.registrationExpiry;
    auto it = registrations_.find(uri);
    if (it == registrations_.end()) {
        if (registrations_.size() >= config_.maxRegisteredServers)
            return status::BadResourceUnavailable;
        addRecordsLocked(reg);
        registrations_.emplace(uri, Entry{reg, expiresAt});
        expiry_.emplace(expiresAt, uri);
        RegistrationEvent ev;
        ev.registration = std::move(reg);
        queueLocked(std::move(ev));
    } else {
        Entry& e = it->second;
        expiry_.erase({e.expiresAt, uri});
        e.expiresAt = expiresAt;
        expiry_.emplace(expiresAt, uri);
        // A plain renewal (the common case, every few hundred ms per device) changes nothing
        // else and reports nothing.
        if (!(e.registration.server == reg.server && e.registration.mdns == reg.mdns)) {
            dropRecordsLocked(e.registration);
            addRecordsLocked(reg);
            RegistrationEvent ev;
            ev.kind = RegistrationEvent::Kind::Updated;
            ev.reason = RegistrationEvent::Reason::Replaced;
            ev.previous = std::move(e.registration);
            e.registration = reg;
            ev.registration = std::move(reg);
            queueLocked(std::move(ev));
        }
    }
    wake_.notify_all();  // the earliest deadline may have changed
    return status::Good;
}

namespace {
// Whether a registration may go on: over a secured channel only for the server its
// certificate names; over None only where insecure registration is allowed.
StatusCode registrationAllowed(const RegisteredServer& server, const RegistrationChannel& channel,
                               bool allowInsecure) {
    if (!channel.secured) return allowInsecure ? status::Good : status::BadSecurityModeInsufficient;
    const auto& uris = channel.certificateUris;
    return std::find(uris.begin(), uris.end(), server.serverUri) != uris.end()
               ? status::Good
               : status::BadServerUriInvalid;
}
}  // namespace

void LocalDiscovery::registerServer(const RegisterServerRequest& req, RegisterServerResponse& resp,
                                    const RegistrationChannel& channel) {
    StatusCode st = registrationAllowed(req.server, channel, config_.allowInsecureRegistration);
    if (st.isGood()) st = validate(req.server);
    if (st.isGood()) st = apply(Registration{req.server, std::nullopt});
    resp.responseHeader.serviceResult = st;
}

void LocalDiscovery::registerServer2(const RegisterServer2Request& req,
                                     RegisterServer2Response& resp,
                                     const RegistrationChannel& channel) {
    StatusCode st = registrationAllowed(req.server, channel, config_.allowInsecureRegistration);
    if (st.isGood()) st = validate(req.server);
    if (st.isGood() && req.discoveryConfiguration.size() > config_.maxListLength)
        st = status::BadTooManyOperations;
    if (st.isBad()) {
        resp.responseHeader.serviceResult = st;
        return;
    }
    // One result per configuration (Part 4 §5.4.6); the first valid mDNS one is used.
    std::optional<MdnsDiscoveryConfiguration> mdns;
    DecodeLimits limits;
    limits.maxStringLength = config_.maxStringLength;
    limits.maxArrayLength = config_.maxListLength;
    for (const auto& x : req.discoveryConfiguration) {
        StatusCode result = status::Good;
        try {
            auto m = fromExtensionObject<MdnsDiscoveryConfiguration>(x, limits);
            if (!m)
                result = status::BadNotSupported;  // another kind of configuration
            else if (!mdns)
                mdns = std::move(*m);
        } catch (const DecodeError&) {
            result = status::BadInvalidArgument;  // malformed or beyond the bounds
        }
        resp.configurationResults.push_back(result);
    }
    if (req.requestHeader.returnDiagnostics != 0)
        resp.diagnosticInfos.resize(resp.configurationResults.size());
    resp.responseHeader.serviceResult = apply(Registration{req.server, std::move(mdns)});
    if (resp.responseHeader.serviceResult.isBad()) {
        resp.configurationResults.clear();
        resp.diagnosticInfos.clear();
    }
}

void LocalDiscovery::findServers(const FindServersRequest& req, FindServersResponse& resp) const {
    std::lock_guard lock(mutex_);
    const auto& filter = req.serverUris;
    resp.servers.reserve(resp.servers.size() +
                         (filter.empty() ? registrations_.size() : filter.size()));
    auto add = [&](const RegisteredServer& s) {
        ApplicationDescription d;
        d.applicationUri = s.serverUri;
        d.productUri = s.productUri;
        d.applicationName = pickName(s.serverNames, req.localeIds);
        d.applicationType = s.serverType;
        d.gatewayServerUri = s.gatewayServerUri;
        d.discoveryUrls = s.discoveryUrls;
        resp.servers.push_back(std::move(d));
    };
    if (filter.empty()) {
        for (const auto& [uri, e] : registrations_) add(e.registration.server);
        return;
    }
    // The filter is bounded by the decoder; a lookup per entry beats scanning the table.
    std::set<std::string_view> seen;
    for (const auto& uri : filter) {
        auto it = registrations_.find(uri);
        if (it != registrations_.end() && seen.insert(it->first).second)
            add(it->second.registration.server);
    }
}

void LocalDiscovery::findServersOnNetwork(const FindServersOnNetworkRequest& req,
                                          FindServersOnNetworkResponse& resp) const {
    if (req.serverCapabilityFilter.size() > config_.maxListLength) {
        resp.responseHeader.serviceResult = status::BadTooManyOperations;
        return;
    }
    std::vector<std::string> filter;
    for (const auto& c : req.serverCapabilityFilter) filter.push_back(lower(c));
    std::lock_guard lock(mutex_);
    resp.lastCounterResetTime = lastCounterResetTime_;
    for (auto it = records_.lower_bound(req.startingRecordId); it != records_.end(); ++it) {
        const auto& caps = it->second.lowerCapabilities;
        bool match = std::all_of(filter.begin(), filter.end(), [&](const std::string& f) {
            return std::find(caps.begin(), caps.end(), f) != caps.end();
        });
        if (!match) continue;
        resp.servers.push_back(it->second.data);
        if (req.maxRecordsToReturn != 0 && resp.servers.size() >= req.maxRecordsToReturn) break;
    }
}

// ---- the LDS's thread: expiry and observers -----------------------------------------------
void LocalDiscovery::run() {
    std::unique_lock lock(mutex_);
    while (!stopping_) {
        const auto now = Clock::now();
        while (!expiry_.empty() && expiry_.begin()->first <= now) {
            std::string uri = expiry_.begin()->second;
            removeLocked(uri, RegistrationEvent::Reason::Expired);
        }
        if (!pending_.empty() || overflowed_) {
            auto events = std::move(pending_);
            pending_.clear();
            if (overflowed_) {
                RegistrationEvent lost;
                lost.kind = RegistrationEvent::Kind::Overflow;
                events.push_back(std::move(lost));
                overflowed_ = false;
            }
            std::vector<Observer> observers;
            for (const auto& [id, o] : observers_) observers.push_back(o);
            lock.unlock();
            for (const auto& ev : events)
                for (const auto& o : observers) {
                    try {
                        o(ev);
                    } catch (...) {
                        // An observer's failure is its own; the others still hear the event.
                    }
                }
            lock.lock();
            continue;
        }
        if (expiry_.empty()) {
            wake_.wait(lock);
        } else {
            // A copy: wait_until reads its deadline again after waking, when a registration on
            // another thread may have erased the set's node (found by ASan).
            const Clock::time_point next = expiry_.begin()->first;
            wake_.wait_until(lock, next);
        }
    }
}

}  // namespace pnp::ua::server
