// DDS: eProsima Fast DDS 2.9 (Debian). What it does exactly (QoS, transports, discovery,
// threads) is in README.md next to this file.
//
// Every message is one sample of a hand-written type, a CDR sequence<octet> (no key). The
// client writes requests to <prefix>_req and takes replies from <prefix>_rep; chain node i
// reads <prefix>_chain_<i> and writes <prefix>_chain_<i+1> or, as a stream's last node,
// <prefix>_chain_sink. Every node is a DomainParticipant of its own.
//
// Discovery is unicast only (loopback and the runner's netns have no multicast): a
// participant's initial peers are the well-known metatraffic ports of the participants it
// must find, which is why servers and chain nodes have fixed participant ids (server 0, chain
// client 0, node i: 1 + i).
#include <arpa/inet.h>
#include <fastcdr/Cdr.h>
#include <fastcdr/FastBuffer.h>
#include <fastcdr/exceptions/Exception.h>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastdds/rtps/transport/shared_mem/SharedMemTransportDescriptor.h>
#include <fastrtps/attributes/LibrarySettingsAttributes.h>
#include <fastrtps/utils/IPLocator.h>
#include <fastrtps/xmlparser/XMLProfileManager.h>
#include <ifaddrs.h>
#include <net/if.h>
#include <netinet/in.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <fastdds/dds/core/status/PublicationMatchedStatus.hpp>
#include <fastdds/dds/core/status/SubscriptionMatchedStatus.hpp>
#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/domain/qos/DomainParticipantQos.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/DataWriterListener.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/publisher/qos/DataWriterQos.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/subscriber/qos/DataReaderQos.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TopicDataType.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <iostream>
#include <list>
#include <map>
#include <mutex>
#include <thread>
#include <utility>

#include "bench/driver/driver.hpp"

namespace pnp::bench::dds {
namespace {

namespace fdds = eprosima::fastdds::dds;
namespace rtps = eprosima::fastrtps::rtps;
using driver::Bytes;
using driver::Clock;
using driver::Options;
using eprosima::fastrtps::Duration_t;
using eprosima::fastrtps::types::ReturnCode_t;

// Bounds: a sample's sequence length from the wire, and how many messages a writer that has
// not matched its reader yet keeps (a chain run has one message per node in flight).
constexpr std::uint32_t kMaxSample = 64u << 20;
constexpr std::size_t kMaxPending = 1024;
// KEEP_ALL history: samples stay until every reader acknowledged them; a writer blocks (up to
// the timeout) only when this many are unacknowledged.
constexpr std::int32_t kHistory = 5000;

// What a DataWriter writes (a view of the caller's bytes: no copy) and a DataReader takes
// (owned bytes).
struct Message {
    std::span<const std::byte> view;
    Bytes bytes;
};

// The topic type: sequence<octet>, CDR with encapsulation, no key (the IDL would be
// `struct PnpBytes { sequence<octet> data; };`).
class BytesType final : public fdds::TopicDataType {
  public:
    BytesType() {
        setName("pnp::bench::PnpBytes");
        m_typeSize = 4 + 4 + 1024;  // preallocated per history slot; larger samples realloc
        m_isGetKeyDefined = false;
    }

    bool serialize(void* data, rtps::SerializedPayload_t* payload) override {
        const auto& m = *static_cast<Message*>(data);
        eprosima::fastcdr::FastBuffer buffer(reinterpret_cast<char*>(payload->data),
                                             payload->max_size);
        eprosima::fastcdr::Cdr cdr(buffer, eprosima::fastcdr::Cdr::DEFAULT_ENDIAN,
                                   eprosima::fastcdr::Cdr::DDS_CDR);
        payload->encapsulation =
            cdr.endianness() == eprosima::fastcdr::Cdr::BIG_ENDIANNESS ? CDR_BE : CDR_LE;
        try {
            cdr.serialize_encapsulation();
            cdr.serialize(static_cast<std::uint32_t>(m.view.size()));
            cdr.serializeArray(reinterpret_cast<const std::uint8_t*>(m.view.data()), m.view.size());
        } catch (const eprosima::fastcdr::exception::Exception&) {
            return false;
        }
        payload->length = static_cast<std::uint32_t>(cdr.getSerializedDataLength());
        return true;
    }

    bool deserialize(rtps::SerializedPayload_t* payload, void* data) override {
        auto& m = *static_cast<Message*>(data);
        eprosima::fastcdr::FastBuffer buffer(reinterpret_cast<char*>(payload->data),
                                             payload->length);
        eprosima::fastcdr::Cdr cdr(buffer, eprosima::fastcdr::Cdr::DEFAULT_ENDIAN,
                                   eprosima::fastcdr::Cdr::DDS_CDR);
        try {
            cdr.read_encapsulation();
            std::uint32_t n = 0;
            cdr.deserialize(n);
            // Bounded by what actually arrived, not by what the length field claims.
            if (n > kMaxSample || n > payload->length) return false;
            m.bytes.resize(n);
            cdr.deserializeArray(reinterpret_cast<std::uint8_t*>(m.bytes.data()), n);
        } catch (const eprosima::fastcdr::exception::Exception&) {
            return false;
        }
        m.view = m.bytes;
        return true;
    }

    std::function<std::uint32_t()> getSerializedSizeProvider(void* data) override {
        const auto n = static_cast<std::uint32_t>(static_cast<Message*>(data)->view.size());
        return [n] { return 4 + 4 + n; };  // encapsulation, length, octets
    }

    void* createData() override { return new Message(); }
    void deleteData(void* data) override { delete static_cast<Message*>(data); }
    bool getKey(void*, rtps::InstanceHandle_t*, bool) override { return false; }
};

// ---- settings -----------------------------------------------------------------------------

struct Config {
    bool shm = false;  // variant "shm": shared memory for data, UDP for discovery
    std::uint32_t domain = 0;
    std::string prefix = "pnp";
    Duration_t blocking;  // a writer's max blocking time (KEEP_ALL history full)
};

int intSetting(const Options& o, const std::string& key, int fallback, int lo, int hi) {
    const std::string text = o.setting(key, std::to_string(fallback));
    std::size_t used = 0;
    int v = 0;
    try {
        v = std::stoi(text, &used);
    } catch (const std::exception&) {
        used = 0;
    }
    if (used != text.size() || v < lo || v > hi)
        throw std::invalid_argument("setting " + key + "=" + text + ": not an integer in " +
                                    std::to_string(lo) + ".." + std::to_string(hi));
    return v;
}

// Fast DDS 2.x hands samples between participants of one process directly unless told not
// to; a chain of nodes in one process would then not use the transport at all. Set once,
// before the first participant (the factory reads its XML profiles first, which could set
// it again).
void configureLibrary(const Options& o) {
    static std::once_flag once;
    std::call_once(once, [&] {
        const std::string mode = o.setting("intraprocess", "off");
        eprosima::fastrtps::LibrarySettingsAttributes library;
        if (mode == "off")
            library.intraprocess_delivery = eprosima::fastrtps::INTRAPROCESS_OFF;
        else if (mode == "user")
            library.intraprocess_delivery = eprosima::fastrtps::INTRAPROCESS_USER_DATA_ONLY;
        else if (mode == "full")
            library.intraprocess_delivery = eprosima::fastrtps::INTRAPROCESS_FULL;
        else
            throw std::invalid_argument("setting intraprocess=" + mode + ": off, user or full");
        fdds::DomainParticipantFactory::get_instance()->load_profiles();
        eprosima::fastrtps::xmlparser::XMLProfileManager::library_settings(library);
    });
}

Config config(const Options& o) {
    configureLibrary(o);
    Config c;
    const std::string variant = o.variant.empty() ? "udp" : o.variant;
    if (variant != "udp" && variant != "shm")
        throw std::invalid_argument("unknown variant " + variant + " (udp, shm)");
    c.shm = variant == "shm";
    // Fast DDS's port mapping (7400 + 250 * domain + ...) leaves room for domains 0..232.
    c.domain = static_cast<std::uint32_t>(intSetting(o, "domain", 0, 0, 232));
    c.prefix = o.setting("topic-prefix", "pnp");
    if (c.prefix.empty()) throw std::invalid_argument("setting topic-prefix is empty");
    c.blocking = Duration_t(static_cast<long double>(o.timeoutMs) / 1000.0L);
    return c;
}

// RTPS well-known metatraffic unicast port of participant `id` in `domain` (spec 9.6.1.1).
std::uint32_t metatrafficPort(std::uint32_t domain, int id) {
    const rtps::PortParameters p;
    return p.portBase + p.domainIDGain * domain + p.offsetd1 +
           p.participantIDGain * static_cast<std::uint32_t>(id);
}

rtps::Locator_t udpLocator(const std::string& address, std::uint32_t port) {
    rtps::Locator_t l;
    l.kind = LOCATOR_KIND_UDPv4;
    if (!rtps::IPLocator::setIPv4(l, address) || !rtps::IPLocator::isIPv4(address))
        throw std::invalid_argument("not an IPv4 address: " + address);
    l.port = port;
    return l;
}

// The MTU of the interface that has IPv4 `address` (0 when unknown).
unsigned interfaceMtu(const std::string& address) {
    in_addr want{};
    if (::inet_pton(AF_INET, address.c_str(), &want) != 1) return 0;
    ifaddrs* all = nullptr;
    if (::getifaddrs(&all) != 0) return 0;
    std::string name;
    for (const ifaddrs* i = all; i != nullptr; i = i->ifa_next)
        if (i->ifa_addr != nullptr && i->ifa_addr->sa_family == AF_INET &&
            reinterpret_cast<const sockaddr_in*>(i->ifa_addr)->sin_addr.s_addr == want.s_addr) {
            name = i->ifa_name;
            break;
        }
    ::freeifaddrs(all);
    if (name.empty() || name.size() >= IFNAMSIZ) return 0;
    const int fd = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    if (fd < 0) return 0;
    ifreq r{};
    std::memcpy(r.ifr_name, name.c_str(), name.size() + 1);
    const int got = ::ioctl(fd, SIOCGIFMTU, &r);
    ::close(fd);
    return got == 0 && r.ifr_mtu > 0 ? static_cast<unsigned>(r.ifr_mtu) : 0;
}

// RTPS messages no larger than the interface's MTU allows without IP fragmentation (a lost
// IP fragment loses the whole datagram, and its retransmission again: under network load a
// 32 KiB sample over a 1500-byte link never got through); larger samples are split by RTPS
// (DATA_FRAG), whose fragments are acknowledged and resent one by one. Loopback (MTU 64 KiB):
// Fast DDS's default.
std::uint32_t maxRtpsMessage(const std::string& address) {
    constexpr std::uint32_t kFastDdsDefault = 65500;
    constexpr unsigned kIpUdpHeaders = 20 + 8;
    const unsigned mtu = interfaceMtu(address);
    if (mtu <= kIpUdpHeaders + 1024) return kFastDdsDefault;
    return std::min<std::uint32_t>(kFastDdsDefault, mtu - kIpUdpHeaders);
}

struct Peer {
    std::string address;
    int participantId;
};

// One DomainParticipant with its publisher, subscriber and topics; deletes them all.
class Participant {
  public:
    // self: this participant's own address (its UDP interface and metatraffic locator);
    // id: its participant id (-1: the first free one); peers: whom it announces itself to.
    Participant(const Config& c, const std::string& name, const std::string& self, int id,
                const std::vector<Peer>& peers)
        : config_(c) {
        fdds::DomainParticipantQos qos = fdds::PARTICIPANT_QOS_DEFAULT;
        qos.name(name);
        qos.wire_protocol().participant_id = id;
        auto& builtin = qos.wire_protocol().builtin;
        builtin.discovery_config.discoveryProtocol = rtps::DiscoveryProtocol_t::SIMPLE;
        // Port 0: Fast DDS fills in this participant's well-known metatraffic port.
        builtin.metatrafficUnicastLocatorList.push_back(udpLocator(self, 0));
        for (const Peer& p : peers)
            builtin.initialPeersList.push_back(
                udpLocator(p.address, metatrafficPort(c.domain, p.participantId)));
        auto& transport = qos.transport();
        transport.use_builtin_transports = false;
        auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
        udp->interfaceWhiteList.push_back(self);
        udp->maxMessageSize = maxRtpsMessage(self);
        if (c.shm)  // first: preferred for data between participants of one host
            transport.user_transports.push_back(
                std::make_shared<eprosima::fastdds::rtps::SharedMemTransportDescriptor>());
        transport.user_transports.push_back(udp);

        participant_ =
            fdds::DomainParticipantFactory::get_instance()->create_participant(c.domain, qos);
        if (!participant_)
            throw std::runtime_error(
                "cannot create a DDS participant in domain " + std::to_string(c.domain) + " on " +
                self + (id >= 0 ? " with participant id " + std::to_string(id) : std::string()));
        type_ = fdds::TypeSupport(new BytesType());
        publisher_ = participant_->create_publisher(fdds::PUBLISHER_QOS_DEFAULT);
        subscriber_ = participant_->create_subscriber(fdds::SUBSCRIBER_QOS_DEFAULT);
        if (type_.register_type(participant_) != ReturnCode_t::RETCODE_OK || !publisher_ ||
            !subscriber_) {
            destroy();
            throw std::runtime_error("cannot set up the DDS participant " + name);
        }
    }
    Participant(const Participant&) = delete;
    Participant& operator=(const Participant&) = delete;
    ~Participant() { destroy(); }

    fdds::DataWriter* writer(const std::string& topic, fdds::DataWriterListener* listener) {
        fdds::DataWriterQos q = fdds::DATAWRITER_QOS_DEFAULT;
        q.reliability().kind = fdds::RELIABLE_RELIABILITY_QOS;
        q.reliability().max_blocking_time = config_.blocking;
        q.durability().kind = fdds::VOLATILE_DURABILITY_QOS;
        q.history().kind = fdds::KEEP_ALL_HISTORY_QOS;
        limits(q.resource_limits());
        q.endpoint().history_memory_policy = rtps::PREALLOCATED_WITH_REALLOC_MEMORY_MODE;
        q.publish_mode().kind = fdds::SYNCHRONOUS_PUBLISH_MODE;
        q.data_sharing().off();  // "shm" means the SHM transport, not zero-copy data sharing
        // Unacknowledged samples are announced every 50 ms (default 3 s): a sample that
        // reached a reader before it had matched this writer is repaired quickly.
        q.reliable_writer_qos().times.heartbeatPeriod = Duration_t(0, 50'000'000);
        auto* w = publisher_->create_datawriter(topicNamed(topic), q, listener,
                                                fdds::StatusMask::publication_matched());
        if (!w) throw std::runtime_error("cannot create a DDS writer on " + topic);
        return w;
    }

    fdds::DataReader* reader(const std::string& topic, fdds::DataReaderListener* listener) {
        fdds::DataReaderQos q = fdds::DATAREADER_QOS_DEFAULT;
        q.reliability().kind = fdds::RELIABLE_RELIABILITY_QOS;
        q.durability().kind = fdds::VOLATILE_DURABILITY_QOS;
        q.history().kind = fdds::KEEP_ALL_HISTORY_QOS;
        limits(q.resource_limits());
        q.endpoint().history_memory_policy = rtps::PREALLOCATED_WITH_REALLOC_MEMORY_MODE;
        q.data_sharing().off();
        auto* r = subscriber_->create_datareader(
            topicNamed(topic), q, listener,
            listener ? fdds::StatusMask::data_available() : fdds::StatusMask::none());
        if (!r) throw std::runtime_error("cannot create a DDS reader on " + topic);
        return r;
    }

    const Config& config() const { return config_; }

  private:
    static void limits(fdds::ResourceLimitsQosPolicy& l) {
        l.max_samples = kHistory;
        l.max_instances = 1;
        l.max_samples_per_instance = kHistory;
        l.allocated_samples = 4;
    }

    fdds::Topic* topicNamed(const std::string& name) {
        auto it = topics_.find(name);
        if (it != topics_.end()) return it->second;
        fdds::Topic* t =
            participant_->create_topic(name, type_.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
        if (!t) throw std::runtime_error("cannot create the DDS topic " + name);
        return topics_.emplace(name, t).first->second;
    }

    void destroy() {
        if (!participant_) return;
        participant_->delete_contained_entities();
        fdds::DomainParticipantFactory::get_instance()->delete_participant(participant_);
        participant_ = nullptr;
    }

    Config config_;
    fdds::DomainParticipant* participant_ = nullptr;
    fdds::TypeSupport type_;
    fdds::Publisher* publisher_ = nullptr;
    fdds::Subscriber* subscriber_ = nullptr;
    std::map<std::string, fdds::Topic*> topics_;
};

// ---- servers and chain nodes --------------------------------------------------------------

// A writer whose messages wait until it has matched a reader: a VOLATILE writer does not
// deliver what it wrote before the match to that reader, and the client (or a chain's next
// node) may still be discovering us. Pending messages are written by flush(), called from
// the serving thread, not from Fast DDS's listener threads.
class Outbox final : public fdds::DataWriterListener {
  public:
    void attach(fdds::DataWriter* w) { writer_ = w; }

    // Called from a reader's listener: writes at once (the common case) or queues.
    void send(std::span<const std::byte> bytes) {
        std::lock_guard lock(mutex_);
        if (matched_ && pending_.empty()) {
            write(bytes);
            return;
        }
        if (pending_.size() >= kMaxPending) {
            pending_.pop_front();
            report("no reader matched: dropped the oldest queued message");
        }
        pending_.emplace_back(bytes.begin(), bytes.end());
        hasPending_ = true;
    }

    void flush() {
        if (!hasPending_ || !matched_) return;
        std::lock_guard lock(mutex_);
        while (matched_ && !pending_.empty()) {
            write(pending_.front());
            pending_.pop_front();
        }
        hasPending_ = !pending_.empty();
    }

    void on_publication_matched(fdds::DataWriter*,
                                const fdds::PublicationMatchedStatus& status) override {
        matched_ = status.current_count > 0;
    }

  private:
    void write(std::span<const std::byte> bytes) {
        Message m{bytes, {}};
        if (!writer_->write(&m)) report("write failed (history full or no memory)");
    }
    void report(const char* what) {
        if (!reported_.exchange(true))
            std::cerr << "dds: " << writer_->get_topic()->get_name() << ": " << what
                      << " (reported once)" << std::endl;
    }

    fdds::DataWriter* writer_ = nullptr;
    std::mutex mutex_;
    std::deque<Bytes> pending_;
    std::atomic<bool> matched_{false};
    std::atomic<bool> hasPending_{false};
    std::atomic<bool> reported_{false};
};

// Takes every sample and hands it to the outbox (echo / forward) or answers one byte (ack).
// Runs on the reader's receive thread: it only copies and writes, which does not block
// (KEEP_ALL history of kHistory samples, one request in flight).
class Relay final : public fdds::DataReaderListener {
  public:
    Relay(Outbox& out, bool ack) : out_(out), ack_(ack) {}

    void on_data_available(fdds::DataReader* reader) override {
        std::lock_guard lock(mutex_);  // a reader may be served by several receive threads
        fdds::SampleInfo info;
        while (reader->take_next_sample(&in_, &info) == ReturnCode_t::RETCODE_OK) {
            if (!info.valid_data) continue;
            static constexpr std::byte kAck[1] = {std::byte{1}};
            if (ack_)
                out_.send(kAck);
            else
                out_.send(in_.bytes);
        }
    }

  private:
    Outbox& out_;
    bool ack_;
    std::mutex mutex_;
    Message in_;
};

// Flushes outboxes every 10 ms until stop (only startup ever queues).
void serveUntilStopped(const std::stop_token& stop, std::list<Outbox>& outboxes) {
    while (!stop.stop_requested()) {
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
        for (Outbox& o : outboxes) o.flush();
    }
}

void runServer(driver::ServerContext& ctx) {
    const Options& o = ctx.options;
    const Config c = config(o);
    const int id = intSetting(o, "participant-id", 0, 0, 119);
    std::list<Outbox> outboxes(1);
    Relay relay(outboxes.front(), o.mode == driver::Mode::Ack);
    Participant p(c, "pnp-mw-dds server", o.host, id, {});
    outboxes.front().attach(p.writer(c.prefix + "_rep", &outboxes.front()));
    p.reader(c.prefix + "_req", &relay);
    ctx.ready();
    serveUntilStopped(ctx.stop, outboxes);
}

std::string chainTopic(const Config& c, int node) {
    return c.prefix + "_chain_" + std::to_string(node);
}
int nodeParticipantId(int node) { return 1 + node; }

// Node i has participant id 1 + i: its ports (metatraffic and user unicast, 2 per id) must
// stay below 65536. Ids above 119 reach into the next domains' port ranges, which is harmless
// while no other run uses those domains at the same time.
void checkChainPorts(const Config& c, const Options& o) {
    if (metatrafficPort(c.domain, nodeParticipantId(o.nodes())) + 1 > 65535)
        throw std::invalid_argument("a chain of " + std::to_string(o.nodes()) +
                                    " nodes does not fit the ports of domain " +
                                    std::to_string(c.domain) + " (use a smaller domain id)");
}

void runChainNodes(driver::ServerContext& ctx) {
    const Options& o = ctx.options;
    const Config c = config(o);
    checkChainPorts(c, o);
    if (o.hops < 1 || o.first < 0 || o.count < 1 || o.first + o.count > o.nodes())
        throw std::invalid_argument("nodes " + std::to_string(o.first) + ".." +
                                    std::to_string(o.first + o.count - 1) + " not in 0.." +
                                    std::to_string(o.nodes() - 1));
    // Declared in this order so that participants (and their listener threads) go first.
    std::list<Outbox> outboxes;
    std::list<Relay> relays;
    std::list<Participant> nodes;
    for (int i = o.first; i < o.first + o.count; ++i) {
        const bool last = (i + 1) % o.hops == 0;
        std::vector<Peer> peers;  // neighbours in the stream; the chain client finds the ends
        if (i % o.hops != 0) peers.push_back({o.host, nodeParticipantId(i - 1)});
        if (!last) peers.push_back({o.host, nodeParticipantId(i + 1)});
        Participant& p = nodes.emplace_back(c, "pnp-mw-dds node " + std::to_string(i), o.host,
                                            nodeParticipantId(i), peers);
        Outbox& out = outboxes.emplace_back();
        Relay& relay = relays.emplace_back(out, false);
        out.attach(p.writer(last ? c.prefix + "_chain_sink" : chainTopic(c, i + 1), &out));
        p.reader(chainTopic(c, i), &relay);
    }
    ctx.ready();
    serveUntilStopped(ctx.stop, outboxes);
}

// ---- clients ------------------------------------------------------------------------------

std::int32_t publicationMatches(fdds::DataWriter* w) {
    fdds::PublicationMatchedStatus s;
    w->get_publication_matched_status(s);
    return s.current_count;
}
std::int32_t subscriptionMatches(fdds::DataReader* r) {
    fdds::SubscriptionMatchedStatus s;
    r->get_subscription_matched_status(s);
    return s.current_count;
}

// Waits (bounded) until `matched` holds.
void waitForMatch(const Options& o, const std::function<bool()>& matched,
                  const std::function<std::string()>& state) {
    const auto deadline = Clock::now() + std::chrono::milliseconds(o.timeoutMs);
    while (!matched()) {
        if (Clock::now() >= deadline)
            throw std::runtime_error("no DDS peer matched within " + std::to_string(o.timeoutMs) +
                                     " ms (" + state() + ")");
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
}

// Waits for the next valid sample until the deadline; false on timeout.
bool takeNext(fdds::DataReader* reader, Message& into, Clock::time_point deadline) {
    fdds::SampleInfo info;
    for (;;) {
        while (reader->take_next_sample(&into, &info) == ReturnCode_t::RETCODE_OK)
            if (info.valid_data) return true;
        const auto left = deadline - Clock::now();
        if (left <= Clock::duration::zero()) return false;
        const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(left).count();
        reader->wait_for_unread_message(Duration_t(static_cast<std::int32_t>(ns / 1'000'000'000),
                                                   static_cast<std::uint32_t>(ns % 1'000'000'000)));
    }
}

class DdsClient final : public driver::Client {
  public:
    explicit DdsClient(const Options& o)
        : config_(config(o)),
          timeout_(o.timeoutMs),
          participant_(config_, "pnp-mw-dds client", o.local, -1,
                       {{o.host, intSetting(o, "participant-id", 0, 0, 119)}}),
          writer_(participant_.writer(config_.prefix + "_req", nullptr)),
          reader_(participant_.reader(config_.prefix + "_rep", nullptr)) {
        waitForMatch(
            o,
            [this] { return publicationMatches(writer_) > 0 && subscriptionMatches(reader_) > 0; },
            [this] {
                return "request writer matched " + std::to_string(publicationMatches(writer_)) +
                       ", reply reader matched " + std::to_string(subscriptionMatches(reader_)) +
                       " in domain " + std::to_string(config_.domain);
            });
    }

    void request(std::span<const std::byte> payload, Bytes& reply) override {
        Message out{payload, {}};
        if (!writer_->write(&out)) throw std::runtime_error("DDS write failed");
        if (!takeNext(reader_, in_, Clock::now() + std::chrono::milliseconds(timeout_)))
            throw std::runtime_error("no answer from the server within " +
                                     std::to_string(timeout_) + " ms");
        reply.swap(in_.bytes);
    }

  private:
    Config config_;
    int timeout_;
    Participant participant_;
    fdds::DataWriter* writer_;
    fdds::DataReader* reader_;
    Message in_;
};

class DdsChainClient final : public driver::ChainClient {
  public:
    explicit DdsChainClient(const Options& o)
        : config_(chainConfig(o)),
          participant_(config_, "pnp-mw-dds chain client", o.local, 0, ends(o)),
          sink_(participant_.reader(config_.prefix + "_chain_sink", nullptr)) {
        for (int s = 0; s < o.streams; ++s)
            firsts_[s * o.hops] = participant_.writer(chainTopic(config_, s * o.hops), nullptr);
        // Every stream's first node reads what we write, every stream's last node writes to
        // our sink.
        waitForMatch(
            o,
            [this, &o] {
                if (subscriptionMatches(sink_) < o.streams) return false;
                return std::all_of(firsts_.begin(), firsts_.end(),
                                   [](const auto& f) { return publicationMatches(f.second) > 0; });
            },
            [this, &o] {
                const auto firsts =
                    std::count_if(firsts_.begin(), firsts_.end(),
                                  [](const auto& f) { return publicationMatches(f.second) > 0; });
                return std::to_string(firsts) + " of " + std::to_string(o.streams) +
                       " first nodes and " + std::to_string(subscriptionMatches(sink_)) + " of " +
                       std::to_string(o.streams) + " last nodes matched in domain " +
                       std::to_string(config_.domain);
            });
    }

    void send(int node, std::span<const std::byte> message) override {
        auto it = firsts_.find(node);
        if (it == firsts_.end())
            throw std::invalid_argument("chain node " + std::to_string(node) +
                                        " is not a first node");
        Message out{message, {}};
        if (!it->second->write(&out)) throw std::runtime_error("DDS write failed");
    }

    bool receive(Bytes& message, Clock::time_point deadline) override {
        if (!takeNext(sink_, in_, deadline)) return false;
        message.swap(in_.bytes);
        return true;
    }

  private:
    static Config chainConfig(const Options& o) {
        Config c = config(o);
        checkChainPorts(c, o);
        return c;
    }
    static std::vector<Peer> ends(const Options& o) {
        std::vector<Peer> peers;
        for (int s = 0; s < o.streams; ++s) {
            peers.push_back({o.host, nodeParticipantId(s * o.hops)});
            if (o.hops > 1) peers.push_back({o.host, nodeParticipantId(s * o.hops + o.hops - 1)});
        }
        return peers;
    }

    Config config_;
    Participant participant_;
    fdds::DataReader* sink_;
    std::map<int, fdds::DataWriter*> firsts_;
    Message in_;
};

}  // namespace
}  // namespace pnp::bench::dds

#ifdef PNP_SANITIZED_BUILD
// Debian's libfastrtps 2.9 deletes a statistics reader through a base of another size
// (RTPSReader::~RTPSReader, all inside the library): ASan's new-delete-type-mismatch check
// stops every participant's tear-down there. Off for this executable only; every other
// check stays.
extern "C" const char* __asan_default_options() { return "new_delete_type_mismatch=0"; }
#endif

int main(int argc, char** argv) {
    namespace driver = pnp::bench::driver;
    namespace dds = pnp::bench::dds;
    driver::Adapter a;
    a.name = "dds";
    a.variants = {"udp", "shm"};
    a.description =
        "eProsima Fast DDS 2.9, RELIABLE KEEP_ALL request/reply topics, unicast discovery; udp: "
        "UDPv4 on the given interface only, shm: shared-memory transport for data";
    a.makeClient = [](const driver::Options& o) { return std::make_unique<dds::DdsClient>(o); };
    a.runServer = dds::runServer;
    a.runChainNodes = dds::runChainNodes;
    a.makeChainClient = [](const driver::Options& o) {
        return std::make_unique<dds::DdsChainClient>(o);
    };
    return driver::adapterMain(argc, argv, a);
}
