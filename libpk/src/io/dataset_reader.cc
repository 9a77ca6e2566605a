// Reading NONMEM-style CSV datasets (see pk/dataset.h for the rules).
#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <map>
#include <unordered_map>
#include <memory>
#include <string>
#include <vector>

#include "../internal_text.h"
#include "csv_lines.h"
#include "record_filter.h"
#include "pk/dataset.h"
#include "pk/error.h"
#include "pk/output.h"

namespace pk {
namespace {

using internal::IsSkippedLine;
using internal::ParseDouble;
using internal::SplitCsvLine;
using internal::ToUpper;
using internal::Trim;

constexpr double kMissing = std::numeric_limits<double>::quiet_NaN();
// A TIME beyond this is a mistake (1e10 h is a million years; 1e10 min, nineteen thousand): with it,
// every exponential of a rate times a time under- or overflows.
constexpr double kMaxTime = 1e10;

// The PREDPP data items, in the order of Item.
const char* const kItemNames[] = {"ID", "TIME", "AMT", "RATE", "II", "ADDL",
                                  "SS", "EVID", "CMT", "MDV", "DV"};
enum Item { kId, kTime, kAmt, kRate, kIi, kAddl, kSs, kEvid, kCmt, kMdv, kDv, kNumItems };

// NM-TRAN's date labels and the order of a date's components under each
// (y = year, m = month, d = day).
const char* const kDateLabels[] = {"DATE", "DAT1", "DAT2", "DAT3"};
const char* const kDateOrders[] = {"mdy", "dmy", "ymd", "ydm"};
const char* const kDateForms[] = {"month/day/year", "day/month/year", "year/month/day", "year/day/month"};

// Days from 1970-01-01 to a proleptic Gregorian date (the civil-from-days
// inverse of the usual era arithmetic).
long DaysFromCivil(long y, int m, int d) {
  y -= m <= 2;
  const long era = (y >= 0 ? y : y - 399) / 400;
  const long yoe = y - era * 400;
  const long doy = (153 * (m + (m > 2 ? -3 : 9)) + 2) / 5 + d - 1;
  const long doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
  return era * 146097 + doe - 719468;
}

bool IsLeapYear(long y) { return (y % 4 == 0 && y % 100 != 0) || y % 400 == 0; }

int DaysInMonth(long y, int m) {
  static const int kDays[] = {31, 28, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31};
  return m == 2 && IsLeapYear(y) ? 29 : kDays[m - 1];
}

// A date field as a day number, by NM-TRAN's rules: one component is a day
// (it may be 0 or negative); two are the day and month, in the label's order
// without the year (then no year is known, so February 29 is refused); three
// are a calendar date whose one- or two-digit year is 2000–2050 up to 50 and
// 1951–1999 above (NM-TRAN's default LAST20 = 50). Components are separated by
// any non-digit character. Returns false with `why` when the field is none of these.
bool ParseDate(const std::string& text, int format, long* day, std::string* why) {
  double single = 0;
  if (ParseDouble(text, &single)) {
    if (single != std::floor(single) || std::fabs(single) > 1e7) {
      *why = "a single date component is a whole day number";
      return false;
    }
    *day = static_cast<long>(single);
    return true;
  }
  std::vector<std::string> parts;
  std::string digits;
  for (char c : text) {
    if (std::isdigit(static_cast<unsigned char>(c))) {
      digits += c;
    } else if (!digits.empty()) {
      parts.push_back(digits);
      digits.clear();
    }
  }
  if (!digits.empty()) parts.push_back(digits);
  const std::string form = kDateForms[format];
  if (parts.size() < 2 || parts.size() > 3) {
    *why = "not a date (" + form + ")";
    return false;
  }
  long y = 2001;  // no year given: a year without February 29
  int m = 0, d = 0;
  std::string order = kDateOrders[format];
  if (parts.size() == 2) order.erase(order.find('y'), 1);
  for (size_t k = 0; k < parts.size(); ++k) {
    if (parts[k].size() > 4) {
      *why = "not a date (" + form + ")";
      return false;
    }
    const long v = std::stol(parts[k]);
    if (order[k] == 'y') {
      y = parts[k].size() <= 2 ? (v <= 50 ? 2000 + v : 1900 + v) : v;
    } else if (order[k] == 'm') {
      m = static_cast<int>(v);
    } else {
      d = static_cast<int>(v);
    }
  }
  if (m < 1 || m > 12) {
    *why = "month " + std::to_string(m) + " is not 1 to 12 (" + form + ")";
    return false;
  }
  if (d < 1 || d > DaysInMonth(y, m)) {
    *why = parts.size() == 2 && m == 2 && d == 29 ? "February 29 needs a year"
                                                   : "day " + std::to_string(d) + " is not in month " +
                                                         std::to_string(m) + " (" + form + ")";
    return false;
  }
  *day = DaysFromCivil(y, m, d);
  return true;
}

// A clock time "hh:mm" or "hh:mm:ss" (hours may be negative or past 24), or
// decimal hours, in hours.
bool ParseClock(const std::string& text, double* hours) {
  if (text.find(':') == std::string::npos) return ParseDouble(text, hours);
  const bool negative = !text.empty() && text[0] == '-';
  std::vector<std::string> parts;
  std::string part;
  for (size_t i = negative ? 1 : 0; i <= text.size(); ++i) {
    if (i == text.size() || text[i] == ':') {
      parts.push_back(part);
      part.clear();
    } else if (std::isdigit(static_cast<unsigned char>(text[i]))) {
      part += text[i];
    } else {
      return false;
    }
  }
  if (parts.size() < 2 || parts.size() > 3) return false;
  double value[3] = {0, 0, 0};
  for (size_t k = 0; k < parts.size(); ++k) {
    if (parts[k].empty() || parts[k].size() > 6) return false;
    value[k] = std::stod(parts[k]);
    if (k > 0 && (value[k] >= 60 || parts[k].size() > 2)) return false;
  }
  const double h = value[0] + value[1] / 60 + value[2] / 3600;
  *hours = negative ? -h : h;
  return true;
}

class Parser {
 public:
  Parser(std::string source, const DatasetFilter& filter) : source_(std::move(source)), filter_(filter) {}

  Dataset Parse(std::vector<std::pair<int, std::string>> lines) {
    Dataset data;
    data.source = source_;
    size_t first = 0;
    while (first < lines.size() && IsSkippedLine(lines[first].second)) ++first;
    if (first == lines.size()) Fail(0, 0, "the file has no header line");
    // NONMEM separates data items by commas or blanks: a header without a comma whose names are
    // separated by spaces or tabs makes the whole file blank-separated.
    blank_separated_ = lines[first].second.find(',') == std::string::npos &&
                       lines[first].second.find('"') == std::string::npos &&
                       SplitBlanks(lines[first].second).size() > 1;
    ReadHeader(lines[first].first, lines[first].second, &data);
    if (first + 1 < lines.size()) ReadUnitsRow(lines[first + 1].second, &data);
    const internal::RecordFilter filter(filter_, data.columns, source_);
    // Records are read one line at a time into reused fields: memory holds the lines and the dataset.
    std::vector<std::string> fields;
    const auto kept = [&](size_t i) {
      if (IsSkippedLine(lines[i].second) || filter.DropsLine(lines[i].second)) return false;
      Split(lines[i].second, &fields);
      return !filter.DropsRecord(fields);
    };
    // NM-TRAN's day-time translation: with a date column, or when any TIME is
    // a clock time, every TIME becomes hours since its subject's first record.
    const size_t tc = static_cast<size_t>(item_column_[kTime]);
    clock_ = false;
    for (size_t i = first + 1; i < lines.size() && !clock_; ++i) {
      if (lines[i].second.find(':') == std::string::npos || !kept(i)) continue;
      clock_ = fields.size() > tc && fields[tc].find(':') != std::string::npos;
    }
    data.relative_times = clock_ || date_column_ >= 0;
    for (size_t i = first + 1; i < lines.size(); ++i) {
      if (kept(i)) ReadRecord(lines[i].first, fields, &data);
    }
    if (data.subjects.empty()) Fail(lines[first].first, 0, "the file has no data records");
    return data;
  }

 private:
  static std::vector<std::string> SplitBlanks(const std::string& line) {
    std::vector<std::string> fields;
    size_t i = 0;
    while (true) {
      i = line.find_first_not_of(" \t", i);
      if (i == std::string::npos) break;
      const size_t end = line.find_first_of(" \t", i);
      fields.push_back(line.substr(i, end == std::string::npos ? std::string::npos : end - i));
      i = end;
    }
    return fields;
  }
  void Split(const std::string& line, std::vector<std::string>* fields) const {
    if (blank_separated_) {
      *fields = SplitBlanks(line);
    } else {
      SplitCsvLine(line, fields);
    }
  }

  [[noreturn]] void Fail(int line, int column, const std::string& message) const {
    throw InputError(source_, line, column, message);
  }
  int Col(Item item) const { return item_column_[item] + 1; }
  std::string Label(Item item) const { return kItemNames[item]; }

  // A units row: the comment right after the header, '#' then one field per column ("#,h,mg,mg/L"
  // under "ID,TIME,AMT,DV"; "# . h mg mg/L" in a blank-separated file, '.' for no unit). A comment
  // of another shape is an ordinary comment.
  void ReadUnitsRow(const std::string& line, Dataset* data) const {
    const size_t hash = line.find_first_not_of(" \t");
    if (hash == std::string::npos || line[hash] != '#') return;
    std::vector<std::string> units;
    Split(line.substr(hash + 1), &units);
    if (units.size() != data->columns.size()) return;
    for (size_t c = 0; c < units.size(); ++c) {
      const std::string unit = internal::Trim(units[c]);
      double number = 0;
      if (internal::ParseDouble(unit, &number)) return;  // a commented-out record, not units
      if (!unit.empty() && unit != ".") data->column_units[data->columns[c]] = unit;  // '.': no unit
    }
  }

  // The names are kept once, upper case, in data->columns (columns_ points there for the records'
  // messages): a header of 10⁶ columns held three times, and a hash map of them, was most of the
  // memory reading such a file took.
  void ReadHeader(int line_number, const std::string& line, Dataset* data) {
    data->header_line = line_number;
    Split(line, &data->columns);
    columns_ = &data->columns;
    for (std::string& name : data->columns) name = ToUpper(name);
    for (int k = 0; k < kNumItems; ++k) item_column_[k] = -1;
    date_column_ = -1;
    int also = -1;
    const int duplicate = FirstDuplicate(data->columns, &also);
    data->extra_columns.reserve(data->columns.size());
    extra_positions_.reserve(data->columns.size());
    for (size_t c = 0; c < data->columns.size(); ++c) {
      const std::string& name = data->columns[c];
      const int column = static_cast<int>(c) + 1;
      if (name.empty()) Fail(line_number, column, "empty column name in the header");
      if (static_cast<int>(c) == duplicate) {
        Fail(line_number, column, "duplicate column " + name + " (also column " + std::to_string(also + 1) + ")");
      }
      for (int f = 0; f < 4; ++f) {
        if (name != kDateLabels[f]) continue;
        if (date_column_ >= 0) {
          Fail(line_number, column, "a second date column " + name + " (also " + data->columns[date_column_] +
                                        ", column " + std::to_string(date_column_ + 1) + ")");
        }
        date_column_ = static_cast<int>(c);
        date_format_ = f;
      }
      if (static_cast<int>(c) == date_column_) continue;  // read with TIME, not kept as a number
      bool is_item = false;
      for (int k = 0; k < kNumItems; ++k) {
        if (name == kItemNames[k]) {
          item_column_[k] = static_cast<int>(c);
          is_item = true;
        }
      }
      if (!is_item) {
        extra_positions_.push_back(static_cast<int>(c));
        data->extra_columns.push_back(name);
      }
    }
    if (item_column_[kTime] < 0) {
      std::string hint;
      if (data->columns.size() == 1) {
        for (const char* sep : {";", "\t", "|"}) {
          if (data->columns[0].find(sep) != std::string::npos) {
            hint = std::string("; columns are separated by commas, and this header seems to use '") +
                   (sep[0] == '\t' ? "\\t" : sep) + "'";
            break;
          }
        }
      }
      Fail(line_number, 0, "missing required column TIME (the header has: " +
                               internal::Join(data->columns, ",") + ")" + hint);
    }
  }

  // The first column (0-based) whose name an earlier column has, and that earlier column in *also;
  // −1 when the names are distinct. By sorting column indices: 4 bytes a column.
  static int FirstDuplicate(const std::vector<std::string>& names, int* also) {
    std::vector<int> order(names.size());
    for (size_t c = 0; c < order.size(); ++c) order[c] = static_cast<int>(c);
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return names[a] < names[b]; });
    int first = -1;
    for (size_t k = 1; k < order.size(); ++k) {
      // A group of equal names, in column order: its second column is where the first one repeats.
      if (names[order[k]] != names[order[k - 1]] || (k >= 2 && names[order[k - 1]] == names[order[k - 2]])) continue;
      if (first < 0 || order[k] < first) {
        first = order[k];
        *also = order[k - 1];
      }
    }
    return first;
  }

  // Parses a numeric field; returns NaN for a missing field ("." or empty).
  double Number(int line, const std::vector<std::string>& fields, int c) const {
    const std::string& text = fields[c];
    if (text.empty() || text == ".") return kMissing;
    double v = 0;
    if (!ParseDouble(text, &v)) {
      const bool hexadecimal = text.find_first_of("xX") != std::string::npos;
      Fail(line, c + 1, "column " + (*columns_)[c] + ": '" + internal::Printable(text) + "' is not a number" +
                            (hexadecimal ? " (write numbers in decimal)" : ""));
    }
    return v;
  }


  double Value(int line, const std::vector<std::string>& fields, enum Item item, double absent) const {
    if (item_column_[item] < 0) return absent;
    const double v = Number(line, fields, item_column_[item]);
    return std::isnan(v) ? absent : v;
  }

  int Integer(int line, const std::vector<std::string>& fields, enum Item item, int absent) const {
    const double v = Value(line, fields, item, absent);
    if (v != std::floor(v) || std::fabs(v) > 1e9) {
      Fail(line, Col(item), Label(item) + " must be a whole number, not " + fields[item_column_[item]]);
    }
    return static_cast<int>(v);
  }

  void ReadRecord(int line, const std::vector<std::string>& fields, Dataset* data) {
    if (fields.size() != columns_->size()) {
      Fail(line, static_cast<int>(std::min(fields.size(), columns_->size())) + 1,
           "expected " + std::to_string(columns_->size()) + " fields as in the header, found " +
               std::to_string(fields.size()));
    }
    Record r;
    r.line = line;
    r.id = Value(line, fields, kId, 1.0);
    if (r.id != std::floor(r.id) || std::fabs(r.id) >= 1e15) {
      Fail(line, Col(kId), "ID must be a whole number (of at most 15 digits), not " + fields[item_column_[kId]]);
    }
    const bool translated = data->relative_times;
    long day = 0;
    const double time = translated ? DayAndHours(line, fields, &day) : Value(line, fields, kTime, kMissing);
    if (std::isnan(time)) Fail(line, Col(kTime), "TIME is missing");
    if (std::fabs(time) > kMaxTime) {
      Fail(line, Col(kTime), "TIME " + FormatNumber(time) + " is beyond ±" + FormatNumber(kMaxTime) +
                                 " (no dosing history spans that long in any unit)");
    }
    r.time = time;
    r.amt = Value(line, fields, kAmt, 0.0);
    r.rate = Value(line, fields, kRate, 0.0);
    r.ii = Value(line, fields, kIi, 0.0);
    r.addl = Integer(line, fields, kAddl, 0);
    r.ss = Integer(line, fields, kSs, 0);
    r.cmt = Integer(line, fields, kCmt, 0);
    if (item_column_[kDv] >= 0) {
      const double dv = Number(line, fields, item_column_[kDv]);
      r.dv_missing = std::isnan(dv);
      r.dv = r.dv_missing ? 0.0 : dv;
    }
    const bool has_mdv = item_column_[kMdv] >= 0 && fields[item_column_[kMdv]] != "." &&
                         !fields[item_column_[kMdv]].empty();
    const int mdv = Integer(line, fields, kMdv, 0);
    if (has_mdv && mdv != 0 && mdv != 1) Fail(line, Col(kMdv), "MDV must be 0 or 1, not " + std::to_string(mdv));
    const bool has_evid = item_column_[kEvid] >= 0 && fields[item_column_[kEvid]] != "." &&
                          !fields[item_column_[kEvid]].empty();
    int evid = 0;
    if (has_evid) {
      evid = Integer(line, fields, kEvid, 0);
      if (evid < 0 || evid > 4) Fail(line, Col(kEvid), "EVID must be 0, 1, 2, 3 or 4, not " + std::to_string(evid));
    } else {
      evid = r.amt > 0 || (r.ss > 0 && r.rate != 0) ? 1 : (has_mdv && mdv == 1 ? 2 : 0);
    }
    r.evid = static_cast<Evid>(evid);
    r.mdv = has_mdv ? mdv : (evid == 0 && !r.dv_missing ? 0 : 1);
    if (evid == 0 && r.dv_missing) r.mdv = 1;

    Validate(line, r);

    r.extra.reserve(extra_positions_.size());
    for (int c : extra_positions_) r.extra.push_back(Number(line, fields, c));

    const bool new_subject = data->subjects.empty() || data->subjects.back().id != r.id;
    if (translated) {
      if (new_subject) origin_ = {day, r.time};
      // Days and hours apart: hours since 1970 would cost digits.
      r.time = 24.0 * static_cast<double>(day - origin_.first) + (r.time - origin_.second);
    }
    if (new_subject) {
      const int occurrence = ++occurrences_[r.id];  // a map: a scan of the subjects so far is quadratic
      data->subjects.push_back(Subject());
      data->subjects.back().id = r.id;
      data->subjects.back().occurrence = occurrence;
      if (occurrence > 1) data->repeated_ids.push_back({r.id, line});
    } else {
      const Record& prev = data->subjects.back().records.back();
      const bool reset = r.evid == Evid::kReset || r.evid == Evid::kResetDose;
      if (r.time < prev.time && !reset) {
        Fail(line, Col(kTime), "TIME decreases within ID " + internal::Trim(fields[std::max(item_column_[kId], 0)]) +
                                   " (" + FormatNumber(r.time) + " after " + FormatNumber(prev.time) +
                                   ") on a record that is not a reset (EVID 3 or 4)" +
                                   (clock_ && date_column_ < 0
                                        ? std::string("; clock times cannot pass midnight without a date column "
                                                      "(DATE, DAT1, DAT2 or DAT3)")
                                        : std::string()));
      }
    }
    data->subjects.back().records.push_back(std::move(r));
  }

  // A record's date as a day number (0 without a date column) in *day, and
  // its clock time or decimal hours as the result; NaN when TIME is missing.
  double DayAndHours(int line, const std::vector<std::string>& fields, long* day) const {
    const int tc = item_column_[kTime];
    const std::string& text = fields[tc];
    if (text.empty() || text == ".") return kMissing;
    double hours = 0;
    if (!ParseClock(text, &hours)) {
      Fail(line, tc + 1, "column TIME: '" + text + "' is not a clock time (hh:mm) or a number of hours");
    }
    if (date_column_ < 0) return hours;
    const std::string& date = fields[date_column_];
    if (date.empty() || date == ".") Fail(line, date_column_ + 1, (*columns_)[date_column_] + " is missing");
    std::string why;
    if (!ParseDate(date, date_format_, day, &why)) {
      Fail(line, date_column_ + 1, "column " + (*columns_)[date_column_] + ": '" + date + "': " + why);
    }
    return hours;
  }

  void Validate(int line, const Record& r) const {
    const RecordProblem problem = CheckRecord(r);
    if (problem.message.empty()) return;
    for (int k = 0; k < kNumItems; ++k) {
      if (problem.column == kItemNames[k]) Fail(line, Col(static_cast<Item>(k)), problem.message);
    }
    Fail(line, 0, problem.message);
  }

  std::string source_;
  DatasetFilter filter_;
  const std::vector<std::string>* columns_ = nullptr;  // the header's names, upper case (ReadHeader)
  int item_column_[kNumItems];
  std::vector<int> extra_positions_;
  int date_column_ = -1;   // DATE, DAT1, DAT2 or DAT3, when present
  int date_format_ = 0;    // index into kDateLabels
  bool clock_ = false;     // some TIME is a clock time
  bool blank_separated_ = false;  // items separated by spaces or tabs (NONMEM accepts them), not commas
  std::pair<long, double> origin_;  // day and hours of the current subject's first record
  std::unordered_map<double, int> occurrences_;  // subjects so far of each ID
};

}  // namespace

RecordProblem CheckRecord(const Record& r) {
  const auto bad = [](const char* column, std::string message) { return RecordProblem{column, std::move(message)}; };
  if (r.amt < 0) return bad("AMT", "AMT must not be negative");
  if (r.rate < 0 && r.rate != -1 && r.rate != -2) {
    return bad("RATE", "RATE must be positive, 0, -1 (modelled rate) or -2 (modelled duration)");
  }
  if (r.ii < 0) return bad("II", "II must not be negative");
  if (r.addl < 0) return bad("ADDL", "ADDL must not be negative");
  if (r.ss < 0 || r.ss > 2) return bad("SS", "SS must be 0, 1 or 2, not " + std::to_string(r.ss));
  if (r.cmt < 0) return bad("CMT", "a negative CMT (turning a compartment off) is not supported");
  if (!r.IsDose()) {
    if (r.amt != 0) return bad("AMT", "AMT must be 0 on a record that is not a dose (EVID 0, 2 or 3)");
    if (r.rate != 0) return bad("RATE", "RATE must be 0 on a record that is not a dose");
    if (r.ss != 0) return bad("SS", "SS must be 0 on a record that is not a dose");
    if (r.addl != 0) return bad("ADDL", "ADDL must be 0 on a record that is not a dose");
    return {};
  }
  const bool constant_infusion = r.ss > 0 && r.amt == 0 && r.rate != 0 && r.ii == 0;
  if (constant_infusion) {
    if (r.rate == -2) {
      return bad("RATE", "a steady-state constant infusion (AMT=0, II=0) cannot have a modelled duration (RATE=-2)");
    }
    if (r.addl != 0) return bad("ADDL", "ADDL must be 0 on a steady-state constant infusion (AMT=0, II=0)");
    return {};
  }
  if (r.amt == 0) return bad("AMT", "AMT must be positive on a dose record");
  if (r.addl > 0 && r.ii <= 0) return bad("II", "ADDL>0 needs II>0");
  if (r.ss > 0 && r.ii <= 0) {
    return bad("II", "a steady-state dose needs II>0 (or AMT=0, RATE>0, II=0 for a constant infusion)");
  }
  return {};
}

namespace {

// Whether `name` in upper case is `upper` (ASCII), without a copy: simulations look columns up per subject.
bool SameUpper(const std::string& upper, const std::string& name) {
  if (upper.size() != name.size()) return false;
  for (size_t k = 0; k < name.size(); ++k) {
    if (upper[k] != internal::AsciiUpper(name[k])) return false;
  }
  return true;
}

}  // namespace

int Dataset::ExtraColumn(const std::string& name) const {
  for (size_t i = 0; i < extra_columns.size(); ++i) {
    if (SameUpper(extra_columns[i], name)) return static_cast<int>(i);
  }
  return -1;
}

int Dataset::ColumnNumber(const std::string& name) const {
  const std::string upper = ToUpper(name);
  for (size_t i = 0; i < columns.size(); ++i) {
    if (columns[i] == upper) return static_cast<int>(i) + 1;
  }
  return 0;
}

int Dataset::NumRecords() const {
  int n = 0;
  for (const Subject& s : subjects) n += static_cast<int>(s.records.size());
  return n;
}

Dataset ParseDataset(const std::string& text, const std::string& source, const DatasetFilter& filter) {
  return Parser(source, filter).Parse(internal::TextLines(text, source));
}

Dataset ReadDataset(const std::string& path, const DatasetFilter& filter) {
  return Parser(path, filter).Parse(internal::ReadLines(path));
}

}  // namespace pk
