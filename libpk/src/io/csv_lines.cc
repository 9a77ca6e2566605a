#include "csv_lines.h"

// fccp copies file names with strncpy; GCC 12 flags that at inlining time (clang has no such warning).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wstringop-truncation"
#include <libfccp/csv.h>
#pragma GCC diagnostic pop
#else
#include <libfccp/csv.h>
#endif

#include <cctype>
#include <filesystem>
#include <fstream>
#include <utility>

#include "../internal_text.h"
#include "pk/error.h"

namespace pk {
namespace internal {
namespace {

// Bytes that a text line cannot hold: a NUL (which would end the line early, so a DV "2.\0 84"
// reads as 2) and a carriage return that does not end a line (a file with CR-only line ends
// reads as one long header). Scans `n` bytes; the place carries on from the last chunk: the line,
// and the column as the reader counts columns (fields, by the commas outside quotes before it).
// Throws pk::InputError naming the place.
class ByteCheck {
 public:
  explicit ByteCheck(std::string source) : source_(std::move(source)) {}
  void Scan(const char* p, size_t n) {
    for (size_t i = 0; i < n; ++i) {
      const char c = p[i];
      if (pending_cr_ && c != '\n') Bad(line_, column_, "a carriage return (CR) that does not end a line: save the "
                                                          "file with LF or CRLF line ends");
      pending_cr_ = false;
      if (c == '\0') Bad(line_, column_, "a NUL byte: this is not a text data file, or it is damaged");
      if (c == '\r') pending_cr_ = true;
      if (c == '"') quoted_ = !quoted_;
      if (c == ',' && !quoted_) ++column_;
      if (c == '\n') {
        ++line_;
        column_ = 1;
        quoted_ = false;
      }
    }
  }

 private:
  [[noreturn]] void Bad(int line, int column, const std::string& why) const {
    throw InputError(source_, line, column, why);
  }
  std::string source_;
  int line_ = 1, column_ = 1;
  bool pending_cr_ = false, quoted_ = false;
};

void CheckFile(const std::string& path) {
  std::error_code error;
  if (std::filesystem::is_directory(path, error)) throw InputError(path, 0, 0, "is a directory, not a data file");
  std::ifstream in(path, std::ios::binary);
  if (!in) return;  // the reader says it cannot open it
  ByteCheck check(path);
  char buf[1 << 16];
  while (in) {
    in.read(buf, sizeof buf);
    check.Scan(buf, static_cast<size_t>(in.gcount()));
  }
}

}  // namespace

// Text in memory is split here as fccp's LineReader splits a file (a UTF-8 BOM
// dropped, lines ending at '\n' with one '\r' before it removed, no empty line
// after a final '\n'), without the reader's 48 MB buffer, which every
// ParseDataset call would allocate and, under AddressSanitizer, clear.
NumberedLines TextLines(const std::string& text, const std::string& source) {
  ByteCheck(source).Scan(text.data(), text.size());
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
  CheckFile(path);
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

namespace {

void TrimInPlace(std::string* s) {
  size_t b = 0, e = s->size();
  while (b < e && internal::AsciiSpace((*s)[b])) ++b;
  while (e > b && internal::AsciiSpace((*s)[e - 1])) --e;
  s->erase(e);
  s->erase(0, b);
}

}  // namespace

void SplitCsvLine(const std::string& line, std::vector<std::string>* fields) {
  size_t n = 0;
  // The next field, reusing the string (and its capacity) of the line before.
  const auto next = [&]() -> std::string* {
    if (n == fields->size()) fields->emplace_back();
    std::string* f = &(*fields)[n++];
    f->clear();
    return f;
  };
  std::string* field = next();
  bool quoted = false;
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        *field += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        *field += c;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      TrimInPlace(field);
      field = next();
    } else {
      *field += c;
    }
  }
  TrimInPlace(field);
  fields->resize(n);
}

std::vector<std::string> SplitCsvLine(const std::string& line) {
  std::vector<std::string> fields;
  SplitCsvLine(line, &fields);
  return fields;
}

bool IsSkippedLine(const std::string& line) {
  const std::string t = Trim(line);
  return t.empty() || t[0] == '#';
}

}  // namespace internal
}  // namespace pk
