#include "kb/endpoint.hpp"

#include <curl/curl.h>
#include <dlfcn.h>

#include <charconv>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <type_traits>

#include "kb/sparql.hpp"
#include "kb/store.hpp"
#include "kb/turtle.hpp"

namespace pnp::kb {
namespace {

constexpr std::size_t kMaxErrorText = 500;
constexpr std::string_view kXsdString = "http://www.w3.org/2001/XMLSchema#string";
constexpr std::string_view kXsdBoolean = "http://www.w3.org/2001/XMLSchema#boolean";

std::string truncated(std::string s) {
    if (s.size() > kMaxErrorText) s = s.substr(0, kMaxErrorText) + "...";
    while (!s.empty() && (s.back() == '\n' || s.back() == '\r' || s.back() == ' ')) s.pop_back();
    return s;
}

// libcurl, loaded when the first endpoint is opened: linked into every pnp process it would
// map ~30 libraries (TLS, Kerberos, LDAP, ...) at each start — tens of ms of every device's
// plug-in time — for the few processes that use `--kb http://`. (Debian's cpp-httplib is no
// better: it initialises OpenSSL, config file included, in every process that links it.)
struct Curl {
    CURLcode (*global_init)(long) = nullptr;
    CURL* (*easy_init)() = nullptr;
    void (*easy_cleanup)(CURL*) = nullptr;
    CURLcode (*easy_setopt)(CURL*, CURLoption, ...) = nullptr;
    CURLcode (*easy_perform)(CURL*) = nullptr;
    CURLcode (*easy_getinfo)(CURL*, CURLINFO, ...) = nullptr;
    const char* (*easy_strerror)(CURLcode) = nullptr;
    char* (*easy_escape)(CURL*, const char*, int) = nullptr;
    void (*free)(void*) = nullptr;
    curl_slist* (*slist_append)(curl_slist*, const char*) = nullptr;
    void (*slist_free_all)(curl_slist*) = nullptr;

    // Throws KbError when libcurl is not installed (Debian: libcurl4).
    static const Curl& get() {
        static const Curl curl = load();
        if (!curl.easy_init)
            throw KbError("the SPARQL endpoint client needs libcurl.so.4 (Debian: libcurl4)");
        return curl;
    }

  private:
    static Curl load() {
        Curl c;
        void* lib = ::dlopen("libcurl.so.4", RTLD_NOW | RTLD_LOCAL);
        if (lib == nullptr) return c;
        auto sym = [&](auto& f, const char* name) {
            f = reinterpret_cast<std::remove_reference_t<decltype(f)>>(::dlsym(lib, name));
            return f != nullptr;
        };
        const bool all =
            sym(c.global_init, "curl_global_init") && sym(c.easy_init, "curl_easy_init") &&
            sym(c.easy_cleanup, "curl_easy_cleanup") && sym(c.easy_setopt, "curl_easy_setopt") &&
            sym(c.easy_perform, "curl_easy_perform") && sym(c.easy_getinfo, "curl_easy_getinfo") &&
            sym(c.easy_strerror, "curl_easy_strerror") && sym(c.easy_escape, "curl_easy_escape") &&
            sym(c.free, "curl_free") && sym(c.slist_append, "curl_slist_append") &&
            sym(c.slist_free_all, "curl_slist_free_all");
        if (!all || c.global_init(CURL_GLOBAL_DEFAULT) != CURLE_OK) return Curl{};
        return c;  // the library stays loaded for the life of the process
    }
};

class EndpointKnowledgeBase final : public KnowledgeBase {
  public:
    // The URL was checked (host, port) by openEndpoint(); libcurl takes it whole.
    explicit EndpointKnowledgeBase(std::string url) : url_(std::move(url)) {}

    Results select(std::string_view query, Deadline deadline) override {
        auto json = queryJson(query, deadline);
        Results results;
        try {
            for (const auto& v : json.at("head").at("vars"))
                results.variables.push_back(v.get<std::string>());
            const auto& bindings = json.at("results").at("bindings");
            if (bindings.size() > kMaxResultRows) {
                throw KbError(url_ + ": more than " + std::to_string(kMaxResultRows) + " results");
            }
            results.rows.reserve(bindings.size());
            for (const auto& b : bindings) {
                std::vector<std::optional<Term>> row(results.variables.size());
                for (std::size_t j = 0; j < results.variables.size(); ++j) {
                    auto it = b.find(results.variables[j]);
                    if (it != b.end()) row[j] = termOf(*it);
                }
                results.rows.push_back(std::move(row));
            }
        } catch (const nlohmann::json::exception& e) {
            throw KbError(url_ + ": malformed SPARQL JSON results: " + e.what());
        }
        return results;
    }

    bool ask(std::string_view query, Deadline deadline) override {
        auto json = queryJson(query, deadline);
        auto it = json.find("boolean");
        if (it != json.end() && it->is_boolean()) return it->get<bool>();
        // Virtuoso 7 answers a POSTed ASK as a SELECT of one variable __ASK_RETVAL: one row
        // (value 1) when true, no row when false.
        try {
            const auto& vars = json.at("head").at("vars");
            if (vars.size() == 1 && vars[0] == "__ASK_RETVAL") {
                const auto& bindings = json.at("results").at("bindings");
                if (bindings.empty()) return false;
                auto v = bindings[0].at("__ASK_RETVAL").at("value").get<std::string>();
                return v != "0" && v != "false";
            }
        } catch (const nlohmann::json::exception&) {
        }
        throw KbError(url_ + ": the answer to an ASK query has no boolean");
    }

    void update(std::string_view update, Deadline deadline) override {
        checkSize(update);
        post("update", update, "*/*", deadline);
    }

    std::size_t loadTurtle(const std::filesystem::path& file, const std::string& graph,
                           Deadline deadline) override {
        iri(graph);
        auto triples = parseTurtleFile(file, "b");
        // Blank node labels hold only within one request: every triple with a blank node goes
        // into the same (last) request, so the file's structure survives.
        std::vector<const TermTriple*> plain, blank;
        for (const auto& t : triples) {
            bool hasBlank = t[0].kind == Term::Kind::Blank || t[2].kind == Term::Kind::Blank;
            (hasBlank ? blank : plain).push_back(&t);
        }
        auto send = [&](const std::vector<const TermTriple*>& batch, bool withBlanks) {
            // Virtuoso refuses blank nodes in INSERT DATA ("not allowed in a constant clause");
            // an INSERT template with an empty WHERE makes them fresh nodes, as the spec says.
            std::string text =
                std::string(withBlanks ? "INSERT" : "INSERT DATA") + " { GRAPH <" + graph + "> {\n";
            for (const auto* t : batch) {
                text += toNTriples((*t)[0]) + " " + toNTriples((*t)[1]) + " " +
                        toNTriples((*t)[2]) + " .\n";
            }
            text += withBlanks ? "} } WHERE { }" : "} }";
            try {
                post("update", text, "*/*", deadline);
            } catch (const KbError& e) {
                throw KbError(file.string() + ": loading into " + e.what());
            }
        };
        for (std::size_t i = 0; i < plain.size(); i += kTriplesPerInsert) {
            std::vector<const TermTriple*> batch(
                plain.begin() + static_cast<std::ptrdiff_t>(i),
                plain.begin() +
                    static_cast<std::ptrdiff_t>(std::min(plain.size(), i + kTriplesPerInsert)));
            send(batch, false);
        }
        if (!blank.empty()) send(blank, true);
        return triples.size();
    }

    std::string describe() const override { return url_; }

  private:
    void checkSize(std::string_view text) const {
        if (text.size() > kMaxQueryBytes) {
            throw KbError("SPARQL text of " + std::to_string(text.size()) + " bytes, more than " +
                          std::to_string(kMaxQueryBytes));
        }
    }

    nlohmann::json queryJson(std::string_view query, Deadline deadline) {
        checkSize(query);
        std::string body = post("query", query, "application/sparql-results+json", deadline);
        try {
            return nlohmann::json::parse(body);
        } catch (const nlohmann::json::exception& e) {
            throw KbError(url_ + ": the answer is not SPARQL JSON results (" + e.what() +
                          "): " + truncated(body));
        }
    }

    Term termOf(const nlohmann::json& b) const {
        std::string type = b.at("type").get<std::string>();
        Term t;
        t.value = b.at("value").get<std::string>();
        if (type == "uri") {
            t.kind = Term::Kind::Iri;
        } else if (type == "bnode") {
            t.kind = Term::Kind::Blank;
        } else if (type == "literal" || type == "typed-literal") {
            t.kind = Term::Kind::Literal;
            if (auto it = b.find("datatype"); it != b.end()) t.datatype = it->get<std::string>();
            if (auto it = b.find("xml:lang"); it != b.end()) t.lang = it->get<std::string>();
            if (t.datatype == kXsdString || !t.lang.empty()) t.datatype.clear();
            // Virtuoso writes booleans as 1 / 0.
            if (t.datatype == kXsdBoolean && (t.value == "1" || t.value == "0")) {
                t.value = t.value == "1" ? "true" : "false";
            }
        } else {
            throw KbError(url_ + ": unknown term type '" + type + "' in the results");
        }
        return t;
    }

    // POSTs `field`=`text` (SPARQL 1.1 Protocol, form-encoded); returns the response body.
    std::string post(const char* field, std::string_view text, const char* accept,
                     Deadline deadline) {
        const auto remaining = std::chrono::duration_cast<std::chrono::milliseconds>(
            deadline - std::chrono::steady_clock::now());
        if (remaining.count() <= 0) throw KbError(url_ + ": deadline exceeded");
        const Curl& curl = Curl::get();
        std::unique_ptr<CURL, void (*)(CURL*)> h(curl.easy_init(), curl.easy_cleanup);
        if (!h) throw KbError(url_ + ": cannot create an HTTP request");
        std::unique_ptr<char, void (*)(void*)> escaped(
            curl.easy_escape(h.get(), text.data(), static_cast<int>(text.size())), curl.free);
        if (!escaped) throw KbError(url_ + ": cannot encode the request");
        const std::string form = std::string(field) + "=" + escaped.get();
        std::unique_ptr<curl_slist, void (*)(curl_slist*)> headers(nullptr, curl.slist_free_all);
        for (const std::string& line :
             {std::string("Accept: ") + accept,
              std::string("Content-Type: application/x-www-form-urlencoded")})
            headers.reset(curl.slist_append(headers.release(), line.c_str()));
        struct Sink {
            std::string body;
            bool tooLarge = false;
        } sink;
        auto write = +[](char* data, std::size_t size, std::size_t n, void* user) -> std::size_t {
            auto* s = static_cast<Sink*>(user);
            if (s->body.size() + size * n > kMaxEndpointResponseBytes) {
                s->tooLarge = true;
                return 0;  // aborts the transfer
            }
            s->body.append(data, size * n);
            return size * n;
        };
        CURL* c = h.get();
        curl.easy_setopt(c, CURLOPT_URL, url_.c_str());
        curl.easy_setopt(c, CURLOPT_PROTOCOLS_STR, "http");
        curl.easy_setopt(c, CURLOPT_NOSIGNAL, 1L);
        curl.easy_setopt(c, CURLOPT_HTTPHEADER, headers.get());
        curl.easy_setopt(c, CURLOPT_POSTFIELDS, form.c_str());
        curl.easy_setopt(c, CURLOPT_POSTFIELDSIZE_LARGE, static_cast<curl_off_t>(form.size()));
        curl.easy_setopt(c, CURLOPT_TIMEOUT_MS, static_cast<long>(remaining.count()));
        curl.easy_setopt(c, CURLOPT_CONNECTTIMEOUT_MS, static_cast<long>(remaining.count()));
        curl.easy_setopt(c, CURLOPT_WRITEFUNCTION, write);
        curl.easy_setopt(c, CURLOPT_WRITEDATA, &sink);
        const CURLcode rc = curl.easy_perform(c);
        if (sink.tooLarge) {
            throw KbError(url_ + ": answer larger than " +
                          std::to_string(kMaxEndpointResponseBytes) + " bytes");
        }
        if (rc == CURLE_OPERATION_TIMEDOUT) throw KbError(url_ + ": deadline exceeded");
        if (rc != CURLE_OK) throw KbError(url_ + ": " + curl.easy_strerror(rc));
        long status = 0;
        curl.easy_getinfo(c, CURLINFO_RESPONSE_CODE, &status);
        if (status < 200 || status >= 300) {
            throw KbError(url_ + ": HTTP " + std::to_string(status) + ": " + truncated(sink.body));
        }
        return std::move(sink.body);
    }

    std::string url_;
};

}  // namespace

std::unique_ptr<KnowledgeBase> openEndpoint(const std::string& url) {
    constexpr std::string_view scheme = "http://";
    if (!url.starts_with(scheme)) throw KbError("'" + url + "': expected http://host:port/path");
    std::string rest = url.substr(scheme.size());
    auto slash = rest.find('/');
    std::string authority = rest.substr(0, slash);
    int port = 80;
    std::string host = authority;
    if (auto colon = authority.rfind(':'); colon != std::string::npos) {
        host = authority.substr(0, colon);
        std::string digits = authority.substr(colon + 1);
        auto r = std::from_chars(digits.data(), digits.data() + digits.size(), port);
        if (digits.empty() || r.ec != std::errc() || r.ptr != digits.data() + digits.size() ||
            port <= 0 || port > 65535) {
            throw KbError("'" + url + "': bad port '" + digits + "'");
        }
    }
    if (host.empty() || host.find_first_of("@[] ") != std::string::npos) {
        throw KbError("'" + url + "': bad host '" + host + "'");
    }
    return std::make_unique<EndpointKnowledgeBase>(url);
}

}  // namespace pnp::kb
