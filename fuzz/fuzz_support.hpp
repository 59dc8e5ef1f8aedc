// Shared helpers of the libFuzzer targets in fuzz/.
//
// Seed corpora are not committed: every target can write its seeds itself, built from real
// encoded messages by the codecs of this tree. LLVMFuzzerInitialize of a target calls
// handleSeedFlag(); started as
//     fuzz_<name> -pnp_write_seeds=<dir>
// the target writes its seeds into <dir> and exits before libFuzzer parses its flags.
// fuzz/CMakeLists.txt does that at build time into build-fuzz/corpus/<name>/, the corpus
// directory scripts/test.sh hands to the fuzzer.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <vector>

#include "ua/types/binary.hpp"

namespace pnp::fuzz {

// A failed check of a fuzz target: prints and aborts (libFuzzer saves the input).
[[noreturn]] inline void fail(const char* what, const std::string& detail = {}) {
    std::fprintf(stderr, "fuzz check failed: %s%s%s\n", what, detail.empty() ? "" : ": ",
                 detail.c_str());
    std::abort();
}
inline void check(bool ok, const char* what, const std::string& detail = {}) {
    if (!ok) fail(what, detail);
}

// Collects named seed files.
class SeedWriter {
  public:
    void add(std::string name, std::vector<ua::Byte> bytes) {
        seeds_.push_back({std::move(name), std::move(bytes)});
    }
    void add(std::string name, ua::Byte prefix, const ua::Buffer& rest) {
        std::vector<ua::Byte> b;
        b.reserve(rest.size() + 1);
        b.push_back(prefix);
        b.insert(b.end(), rest.begin(), rest.end());
        add(std::move(name), std::move(b));
    }
    void add(std::string name, ua::Byte prefix1, ua::Byte prefix2, const ua::Buffer& rest) {
        std::vector<ua::Byte> b;
        b.reserve(rest.size() + 2);
        b.push_back(prefix1);
        b.push_back(prefix2);
        b.insert(b.end(), rest.begin(), rest.end());
        add(std::move(name), std::move(b));
    }
    // Writes every seed as <dir>/seed-<name>; false on an I/O error.
    bool write(const std::filesystem::path& dir) const {
        std::error_code ec;
        std::filesystem::create_directories(dir, ec);
        if (ec) return false;
        for (const auto& [name, bytes] : seeds_) {
            std::ofstream f(dir / ("seed-" + name), std::ios::binary | std::ios::trunc);
            f.write(reinterpret_cast<const char*>(bytes.data()),
                    static_cast<std::streamsize>(bytes.size()));
            if (!f) return false;
        }
        return true;
    }
    std::size_t size() const { return seeds_.size(); }

  private:
    struct Seed {
        std::string name;
        std::vector<ua::Byte> bytes;
    };
    std::vector<Seed> seeds_;
};

// When argv holds -pnp_write_seeds=<dir>: calls make(writer), writes the seeds and exits.
template <class F>
void handleSeedFlag(int* argc, char*** argv, F&& make) {
    constexpr std::string_view flag = "-pnp_write_seeds=";
    for (int i = 1; i < *argc; ++i) {
        std::string_view a = (*argv)[i];
        if (!a.starts_with(flag)) continue;
        std::filesystem::path dir(a.substr(flag.size()));
        SeedWriter w;
        make(w);
        if (!w.write(dir)) {
            std::fprintf(stderr, "cannot write seeds into %s\n", dir.c_str());
            std::exit(1);
        }
        std::printf("wrote %zu seeds into %s\n", w.size(), dir.c_str());
        std::exit(0);
    }
}

template <class T>
ua::Buffer encoded(const T& v) {
    return ua::encodeToBuffer(v);
}

inline void append(ua::Buffer& out, const ua::Buffer& more) {
    out.insert(out.end(), more.begin(), more.end());
}

}  // namespace pnp::fuzz
