// libFuzzer target: the dataset reader and NM-TRAN's IGNORE=/ACCEPT= filters on arbitrary bytes.
//
// Input: CSV text. When it starts with '@', its first line is a filter: "@IGNORE c1;c2" or
// "@ACCEPT c1;c2" with conditions as pkfit's --ignore/--accept take them (a one-character
// IGNORE is NM-TRAN's IGNORE=c). Any outcome but a dataset or a pk::InputError that names a
// place inside the input is a finding: a crash, a sanitizer report, another exception.
//
//   scripts/fuzz.sh 600    # ten minutes (tests/test.sh runs 30 s of it)
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "pk/dataset.h"
#include "pk/error.h"

namespace {

std::vector<std::string> Split(const std::string& list) {
  std::vector<std::string> out;
  size_t begin = 0;
  while (begin <= list.size()) {
    const size_t end = std::min(list.find(';', begin), list.size());
    if (end > begin) out.push_back(list.substr(begin, end - begin));
    begin = end + 1;
  }
  return out;
}

// The filter of an "@IGNORE ..." or "@ACCEPT ..." first line; strips that line from `text`.
pk::DatasetFilter TakeFilter(std::string* text) {
  pk::DatasetFilter filter;
  if (text->empty() || (*text)[0] != '@') return filter;
  const size_t eol = std::min(text->find('\n'), text->size());
  const std::string line = text->substr(1, eol - 1);
  *text = eol < text->size() ? text->substr(eol + 1) : std::string();
  const bool ignore = line.rfind("IGNORE ", 0) == 0, accept = line.rfind("ACCEPT ", 0) == 0;
  if (!ignore && !accept) return filter;
  std::vector<std::string> conditions = Split(line.substr(7));
  if (ignore && conditions.size() == 1 && conditions[0].size() == 1) {
    filter.ignore_character = conditions[0][0];
  } else {
    (ignore ? filter.ignore : filter.accept) = conditions;
  }
  return filter;
}

int Lines(const std::string& text) {
  int n = 1;
  for (char c : text) n += c == '\n' ? 1 : 0;
  return n;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::string text(reinterpret_cast<const char*>(data), size);
  const pk::DatasetFilter filter = TakeFilter(&text);
  try {
    const pk::Dataset d = pk::ParseDataset(text, "fuzz.csv", filter);
    for (const pk::Subject& s : d.subjects) {
      if (s.records.empty() || s.occurrence < 1) std::abort();
    }
  } catch (const pk::InputError& e) {
    // The place must be in the input: a line of it (0 for the whole file), never past its end.
    if (e.message().empty() || e.line() < 0 || e.line() > Lines(text) || e.column() < 0) std::abort();
  }
  return 0;
}
