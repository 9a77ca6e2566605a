// Reading per-subject parameter tables (see pk/estimates.h).
#include <algorithm>
#include <map>
#include <unordered_map>
#include <string>
#include <vector>

#include "../internal_text.h"
#include "csv_lines.h"
#include "pk/error.h"
#include "pk/estimates.h"
#include "pk/objective.h"
#include "pk/output.h"

namespace pk {
namespace {

using internal::IsSkippedLine;
using internal::SplitCsvLine;
using internal::ToUpper;

std::vector<SubjectEstimates> Parse(const internal::NumberedLines& lines, const std::string& source,
                                    const Model& model) {
  auto fail = [&](int line, int column, const std::string& message) {
    throw InputError(source, line, column, message);
  };
  const ParameterLayout layout(model);
  size_t first = 0;
  while (first < lines.size() && IsSkippedLine(lines[first].second)) ++first;
  if (first == lines.size()) fail(0, 0, "the estimates table has no header line");
  const int header_line = lines[first].first;
  const std::vector<std::string> header = SplitCsvLine(lines[first].second);
  int id = -1, name = -1, value = -1;
  for (int k = 0; k < static_cast<int>(header.size()); ++k) {
    const std::string h = ToUpper(header[k]);
    int* slot = h == "ID" ? &id : h == "PARAMETER" ? &name : h == "ESTIMATE" ? &value : nullptr;
    if (slot == nullptr) continue;
    if (*slot >= 0) fail(header_line, k + 1, "duplicate column " + h + " (also column " + std::to_string(*slot + 1) + ")");
    *slot = k;
  }
  if (id < 0 || name < 0 || value < 0) {
    fail(header_line, 0, "the estimates table needs the columns ID, PARAMETER and ESTIMATE");
  }
  std::vector<SubjectEstimates> out;
  std::map<std::pair<double, std::string>, int> seen;  // (ID, canonical parameter name) -> line
  std::unordered_map<double, size_t> entry_of;  // ID -> its entry in out
  for (size_t i = first + 1; i < lines.size(); ++i) {
    const int line = lines[i].first;
    if (IsSkippedLine(lines[i].second)) continue;
    const std::vector<std::string> fields = SplitCsvLine(lines[i].second);
    if (fields.size() != header.size()) {
      fail(line, 0, "expected " + std::to_string(header.size()) + " fields as in the header, found " +
                        std::to_string(fields.size()));
    }
    auto number = [&](int k, const char* what) {
      double v = 0;
      if (!internal::ParseDouble(fields[k], &v)) fail(line, k + 1, std::string(what) + ": '" + fields[k] + "' is not a number");
      return v;
    };
    const double subject = number(id, "ID");
    const std::string& parameter = fields[name];
    const std::string upper = ToUpper(parameter);
    // A layout name (its canonical spelling) or an error model's σ.
    const int index = layout.Index(parameter);
    const std::string key = index >= 0 ? layout.name(index) : upper;
    if (index < 0 && !IsResidualErrorName(upper)) {
      fail(line, name + 1, model.IsFormerName(parameter) ? model.UnknownParameter(parameter, layout.names())
                                                         : "'" + parameter + "' is not a parameter of model " + model.name());
    }
    const double estimate = number(value, "ESTIMATE");
    const auto again = seen.emplace(std::make_pair(subject, key), line);
    if (!again.second) {
      fail(line, name + 1, parameter + " is given twice for ID " + FormatNumber(subject) + " (also line " +
                               std::to_string(again.first->second) + ")");
    }
    const auto slot = entry_of.emplace(subject, out.size());  // the table's order of IDs, found in O(1)
    if (slot.second) out.emplace_back(subject, ParameterValues());
    out[slot.first->second].second[key] = estimate;
  }
  if (out.empty()) fail(header_line, 0, "the estimates table has no rows");
  return out;
}

}  // namespace

std::vector<SubjectEstimates> ReadEstimates(const std::string& path, const Model& model) {
  return Parse(internal::ReadLines(path), path, model);
}

std::vector<SubjectEstimates> ParseEstimates(const std::string& text, const std::string& source, const Model& model) {
  return Parse(internal::TextLines(text, source), source, model);
}

}  // namespace pk
