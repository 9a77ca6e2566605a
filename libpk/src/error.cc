#include "pk/error.h"

#include "internal_text.h"

#include <algorithm>
#include <cctype>
#include <utility>

namespace pk {
namespace {

std::string Locate(const std::string& file, int line, int column, const std::string& message) {
  std::string where = file;
  if (line > 0) where += (where.empty() ? "line " : ":") + std::to_string(line);
  if (column > 0) where += (line > 0 ? ":" : (where.empty() ? "column " : ":")) + std::to_string(column);
  return where.empty() ? message : where + ": " + message;
}

// Levenshtein distance of the upper-cased strings (one row at a time).
size_t EditDistance(const std::string& a, const std::string& b) {
  std::vector<size_t> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    size_t diagonal = row[0];
    row[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      const bool same = internal::AsciiUpper(a[i - 1]) == internal::AsciiUpper(b[j - 1]);
      const size_t next = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (same ? 0 : 1)});
      diagonal = row[j];
      row[j] = next;
    }
  }
  return row[b.size()];
}

}  // namespace

std::string ClosestName(const std::string& name, const std::vector<std::string>& candidates) {
  const size_t limit = std::max<size_t>(2, name.size() / 3);
  std::string best;
  size_t best_distance = limit + 1;
  for (const std::string& c : candidates) {
    const size_t d = EditDistance(name, c);
    if (d < best_distance) {
      best = c;
      best_distance = d;
    }
  }
  return best;
}

InputError::InputError(std::string file, int line, int column, std::string message)
    : std::runtime_error(Locate(file, line, column, message)),
      file_(std::move(file)),
      line_(line),
      column_(column),
      message_(std::move(message)) {}

InputError::InputError(std::string message) : InputError("", 0, 0, std::move(message)) {}

}  // namespace pk
