#include "csv_lines.h"

// fccp copies file names with strncpy; GCC 12 flags that at inlining time.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wstringop-truncation"
#include <libfccp/csv.h>
#pragma GCC diagnostic pop

#include "../internal_text.h"
#include "pk/error.h"

namespace pk {
namespace internal {

// Text in memory is split here as fccp's LineReader splits a file (a UTF-8 BOM
// dropped, lines ending at '\n' with one '\r' before it removed, no empty line
// after a final '\n'), without the reader's 48 MB buffer, which every
// ParseDataset call would allocate and, under AddressSanitizer, clear.
NumberedLines TextLines(const std::string& text) {
  NumberedLines lines;
  size_t begin = text.compare(0, 3, "\xEF\xBB\xBF") == 0 ? 3 : 0;
  int number = 0;
  while (begin < text.size()) {
    size_t end = text.find('\n', begin);
    const size_t next = end == std::string::npos ? text.size() : end + 1;
    if (end == std::string::npos) end = text.size();
    if (end > begin && text[end - 1] == '\r') --end;
    lines.emplace_back(++number, text.substr(begin, end - begin));
    begin = next;
  }
  return lines;
}

NumberedLines ReadLines(const std::string& path) {
  NumberedLines lines;
  try {
    io::LineReader reader(path);
    int number = 0;
    while (char* line = reader.next_line()) lines.emplace_back(++number, line);
  } catch (const io::error::can_not_open_file&) {
    throw InputError(path, 0, 0, "cannot open the file");
  } catch (const io::error::base& e) {
    throw InputError(path, 0, 0, e.what());
  }
  return lines;
}

std::vector<std::string> SplitCsvLine(const std::string& line) {
  std::vector<std::string> fields;
  std::string field;
  bool quoted = false;
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        field += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        field += c;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      fields.push_back(Trim(field));
      field.clear();
    } else {
      field += c;
    }
  }
  fields.push_back(Trim(field));
  return fields;
}

bool IsSkippedLine(const std::string& line) {
  const std::string t = Trim(line);
  return t.empty() || t[0] == '#';
}

}  // namespace internal
}  // namespace pk
