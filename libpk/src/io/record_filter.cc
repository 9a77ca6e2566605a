#include "record_filter.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>

#include "../internal_text.h"
#include "pk/error.h"

namespace pk {
namespace internal {
namespace {

// The operators, longest spellings first so that ">=" is not read as ">".
struct Spelling {
  const char* text;
  int op;  // RecordFilter::Op, as an int (it is private)
};
const Spelling kSpellings[] = {{".EQN.", 0}, {".NEN.", 1}, {".EQ.", 0}, {".NE.", 1}, {".GT.", 2}, {".GE.", 3},
                               {".LT.", 4},  {".LE.", 5},  {"==", 0},   {"/=", 1},   {"!=", 1},   {">=", 3},
                               {"<=", 5},    {">", 2},     {"<", 4},    {"=", 0}};

// "(A, B)" or "A, B" into A and B (a quoted value may hold a comma).
std::vector<std::string> SplitList(std::string spec) {
  spec = Trim(spec);
  const bool open = !spec.empty() && spec.front() == '(', close = !spec.empty() && spec.back() == ')';
  if (open != close || (open && spec.size() < 2)) {
    throw InputError("'" + spec + "': unbalanced parentheses (write (A, B) or A, B)");
  }
  if (open) spec = spec.substr(1, spec.size() - 2);
  std::vector<std::string> out(1);
  char quote = 0;
  for (char c : spec) {
    if (quote) {
      if (c == quote) quote = 0;
    } else if (c == '\'' || c == '"') {
      quote = c;
    } else if (c == ',') {
      out.emplace_back();
      continue;
    }
    out.back() += c;
  }
  return out;
}

}  // namespace

RecordFilter::RecordFilter(const DatasetFilter& filter, const std::vector<std::string>& columns,
                           const std::string& source)
    : ignore_character_(filter.ignore_character), accept_(!filter.accept.empty()) {
  if (!filter.ignore.empty() && !filter.accept.empty()) {
    throw InputError(source, 0, 0, "IGNORE=(list) and ACCEPT=(list) cannot be combined (as in NM-TRAN): give one");
  }
  const char* option = accept_ ? "ACCEPT" : "IGNORE";
  for (const std::string& spec : accept_ ? filter.accept : filter.ignore) {
    for (const std::string& item : SplitList(spec)) {
      const std::string cond = Trim(item);
      const std::string upper = ToUpper(cond);
      auto fail = [&](const std::string& why) {
        throw InputError(source, 0, 0, std::string(option) + "=(" + cond + "): " + why);
      };
      if (cond.empty()) fail("an empty condition");
      // The first operator after the label (labels hold no dots or operator characters).
      size_t at = std::string::npos, length = 0;
      int op = -1;
      for (const Spelling& s : kSpellings) {
        const size_t p = upper.find(s.text);
        if (p != std::string::npos && p > 0 && (p < at || (p == at && std::string(s.text).size() > length))) {
          at = p;
          length = std::string(s.text).size();
          op = s.op;
        }
      }
      if (op < 0) fail("expected LABEL OP VALUE with OP one of .EQ. .NE. .GT. .GE. .LT. .LE. == /= > >= < <=");
      const std::string label = Trim(upper.substr(0, at));
      std::string value = Trim(cond.substr(at + length));
      if (value.size() >= 2 && (value.front() == '\'' || value.front() == '"') && value.back() == value.front()) {
        value = value.substr(1, value.size() - 2);
      }
      if (value.empty()) fail("no value to compare with");
      const auto it = std::find(columns.begin(), columns.end(), label);
      if (it == columns.end()) fail("no column " + label + " in the header (it has: " + Join(columns, ",") + ")");
      double number = std::numeric_limits<double>::quiet_NaN();
      if (!ParseDouble(value, &number)) number = std::numeric_limits<double>::quiet_NaN();
      const Op o = static_cast<Op>(op);
      if (std::isnan(number) && o != Op::kEq && o != Op::kNe) fail("'" + value + "' is not a number to order by");
      conditions_.push_back({static_cast<size_t>(it - columns.begin()), o, value, number});
    }
  }
}

bool RecordFilter::DropsLine(const std::string& line) const {
  if (ignore_character_ == 0) return false;
  const auto first = std::find_if(line.begin(), line.end(), [](char c) { return c != ' ' && c != '\t'; });
  if (first == line.end()) return false;
  if (ignore_character_ == '@') return *first == '@' || internal::AsciiAlpha(*first);
  return *first == ignore_character_;
}

bool RecordFilter::Holds(const Condition& c, const std::vector<std::string>& fields) {
  const std::string field = c.column < fields.size() ? fields[c.column] : std::string();
  double x = 0;  // NM-TRAN reads a missing numeric field as 0
  const bool numeric = !std::isnan(c.number) && (field.empty() || field == "." || ParseDouble(field, &x));
  if (!numeric) {
    if (c.op == Op::kEq) return field == c.text;
    if (c.op == Op::kNe) return field != c.text;
    return false;
  }
  switch (c.op) {
    case Op::kEq: return x == c.number;
    case Op::kNe: return x != c.number;
    case Op::kGt: return x > c.number;
    case Op::kGe: return x >= c.number;
    case Op::kLt: return x < c.number;
    case Op::kLe: return x <= c.number;
  }
  return false;
}

bool RecordFilter::DropsRecord(const std::vector<std::string>& fields) const {
  if (conditions_.empty()) return false;
  const bool any = std::any_of(conditions_.begin(), conditions_.end(),
                               [&](const Condition& c) { return Holds(c, fields); });
  return accept_ ? !any : any;
}

}  // namespace internal
}  // namespace pk
