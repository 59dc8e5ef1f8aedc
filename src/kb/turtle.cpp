#include "kb/turtle.hpp"

#include <serd/serd.h>

#include <cctype>
#include <cstdarg>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <memory>
#include <optional>
#include <system_error>

namespace pnp::kb {
namespace {

constexpr std::string_view kXsdString = "http://www.w3.org/2001/XMLSchema#string";

struct ReadState {
    SerdEnv* env = nullptr;
    std::string file;
    std::string text;  // the file's content
    std::vector<TermTriple> triples;
    std::optional<std::string> error;
};

std::string text(const SerdNode* node) {
    return std::string(reinterpret_cast<const char*>(node->buf), node->n_bytes);
}

// "file:line:col" of the first use of the prefixed name `name` (serd reports an unknown prefix
// through the statement, which carries no position).
std::string whereIs(const ReadState& st, const std::string& name) {
    std::size_t at = 0;
    while ((at = st.text.find(name, at)) != std::string::npos) {
        char before = at == 0 ? ' ' : st.text[at - 1];
        if (!std::isalnum(static_cast<unsigned char>(before)) && before != '_' && before != '-' &&
            before != ':' && before != '.') {
            break;
        }
        ++at;
    }
    if (at == std::string::npos) return st.file;
    std::size_t line = 1, lineStart = 0;
    for (std::size_t i = 0; i < at; ++i) {
        if (st.text[i] == '\n') ++line, lineStart = i + 1;
    }
    return st.file + ":" + std::to_string(line) + ":" + std::to_string(at - lineStart + 1);
}

// An IRI from a URI or CURIE node, resolved against the base and prefixes seen so far.
std::optional<std::string> expand(const ReadState& st, const SerdNode* node) {
    SerdNode full = serd_env_expand_node(st.env, node);
    if (full.buf == nullptr) return std::nullopt;
    std::string out = text(&full);
    serd_node_free(&full);
    return out;
}

SerdStatus onError(void* handle, const SerdError* error) {
    auto* st = static_cast<ReadState*>(handle);
    if (st->error) return SERD_SUCCESS;
    char message[512];
    va_list args;
    va_copy(args, *error->args);
    std::vsnprintf(message, sizeof message, error->fmt, args);
    va_end(args);
    std::string what = message;
    while (!what.empty() && (what.back() == '\n' || what.back() == ' ')) what.pop_back();
    st->error = st->file + ":" + std::to_string(error->line) + ":" +
                std::to_string(error->col + 1) + ": " + what;
    return SERD_SUCCESS;
}

SerdStatus onBase(void* handle, const SerdNode* uri) {
    auto* st = static_cast<ReadState*>(handle);
    return serd_env_set_base_uri(st->env, uri);
}

SerdStatus onPrefix(void* handle, const SerdNode* name, const SerdNode* uri) {
    auto* st = static_cast<ReadState*>(handle);
    return serd_env_set_prefix(st->env, name, uri);
}

SerdStatus onStatement(void* handle, SerdStatementFlags, const SerdNode*, const SerdNode* subject,
                       const SerdNode* predicate, const SerdNode* object, const SerdNode* datatype,
                       const SerdNode* lang) {
    auto* st = static_cast<ReadState*>(handle);
    auto convert = [&](const SerdNode* node, Term& out) -> bool {
        switch (node->type) {
            case SERD_URI:
            case SERD_CURIE: {
                auto full = expand(*st, node);
                if (!full) {
                    if (!st->error) {
                        st->error =
                            whereIs(*st, text(node)) + ": undefined prefix in '" + text(node) + "'";
                    }
                    return false;
                }
                out = Term{Term::Kind::Iri, *full, "", ""};
                return true;
            }
            case SERD_BLANK:
                out = Term{Term::Kind::Blank, text(node), "", ""};
                return true;
            case SERD_LITERAL: {
                out = Term{Term::Kind::Literal, text(node), "", ""};
                if (lang != nullptr) out.lang = text(lang);
                if (datatype != nullptr) {
                    auto full = expand(*st, datatype);
                    if (!full) {
                        if (!st->error) {
                            st->error = whereIs(*st, text(datatype)) + ": undefined prefix in '" +
                                        text(datatype) + "'";
                        }
                        return false;
                    }
                    if (*full != kXsdString) out.datatype = *full;
                }
                return true;
            }
            default:
                if (!st->error) st->error = st->file + ": unexpected node '" + text(node) + "'";
                return false;
        }
    };
    TermTriple triple;
    if (!convert(subject, triple[0]) || !convert(predicate, triple[1]) ||
        !convert(object, triple[2])) {
        return SERD_ERR_BAD_SYNTAX;
    }
    st->triples.push_back(std::move(triple));
    return SERD_SUCCESS;
}

}  // namespace

std::vector<TermTriple> parseTurtleFile(const std::filesystem::path& file,
                                        const std::string& blankPrefix) {
    std::error_code ec;
    auto size = std::filesystem::file_size(file, ec);
    if (ec) throw KbError(file.string() + ": cannot read: " + ec.message());
    if (size > kMaxTurtleFileBytes) {
        throw KbError(file.string() + ": " + std::to_string(size) + " bytes, more than the " +
                      std::to_string(kMaxTurtleFileBytes) + " a Turtle file may have");
    }
    ReadState st;
    st.file = file.string();
    // The base IRI of relative references: the file's own URI, as serdi does.
    auto absolute = std::filesystem::absolute(file, ec).string();
    SerdNode base = serd_node_new_file_uri(reinterpret_cast<const uint8_t*>(absolute.c_str()),
                                           nullptr, nullptr, true);
    st.env = serd_env_new(&base);
    std::unique_ptr<SerdEnv, void (*)(SerdEnv*)> env(st.env, serd_env_free);
    std::unique_ptr<SerdReader, void (*)(SerdReader*)> reader(
        serd_reader_new(SERD_TURTLE, &st, nullptr, onBase, onPrefix, onStatement, nullptr),
        serd_reader_free);
    serd_node_free(&base);
    serd_reader_set_strict(reader.get(), true);
    serd_reader_set_error_sink(reader.get(), onError, &st);
    serd_reader_add_blank_prefix(reader.get(),
                                 reinterpret_cast<const uint8_t*>(blankPrefix.c_str()));
    {
        std::ifstream in(file, std::ios::binary);
        if (!in) throw KbError(st.file + ": cannot open");
        st.text.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    }
    if (st.text.find('\0') != std::string::npos)
        throw KbError(st.file + ": a NUL byte in a Turtle file");
    SerdStatus status =
        serd_reader_read_string(reader.get(), reinterpret_cast<const uint8_t*>(st.text.c_str()));
    if (st.error) throw KbError(*st.error);
    if (status != SERD_SUCCESS) {
        throw KbError(st.file + ": " + reinterpret_cast<const char*>(serd_strerror(status)));
    }
    return std::move(st.triples);
}

}  // namespace pnp::kb
