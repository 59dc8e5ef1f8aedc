// Output helpers of the pnp command line tool: exit codes, errors, aligned tables.
#pragma once

#include <ostream>
#include <stdexcept>
#include <string>
#include <vector>

namespace pnp::cli {

// Exit codes of every pnp command.
enum ExitCode : int {
    kExitOk = 0,
    kExitUaError = 1,  // an OPC UA error (connection, service or operation status): name printed
    kExitUsage = 2,    // bad command line (unknown option, malformed node id / value, ...)
};

// A command line the tool cannot act on (exit code 2).
class UsageError : public std::invalid_argument {
  public:
    using std::invalid_argument::invalid_argument;
};

// Columns aligned by the display width of their cells (UTF-8 aware); the last column is
// not padded. Cells must not contain line breaks (they are replaced by spaces).
class Table {
  public:
    explicit Table(std::vector<std::string> headers) : headers_(std::move(headers)) {}
    void add(std::vector<std::string> row) { rows_.push_back(std::move(row)); }
    bool empty() const { return rows_.empty(); }
    void print(std::ostream& out) const;

  private:
    std::vector<std::string> headers_;
    std::vector<std::vector<std::string>> rows_;
};

// Number of terminal columns the UTF-8 text takes (one per code point).
std::size_t displayWidth(const std::string& s);

}  // namespace pnp::cli
