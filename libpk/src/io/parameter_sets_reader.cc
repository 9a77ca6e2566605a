// Reading the estimates' uncertainty as pkpop writes it: covariance.csv and bootstrap.csv
// (pk/uncertainty.h).
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "../internal_text.h"
#include "csv_lines.h"
#include "pk/error.h"
#include "pk/output.h"
#include "pk/uncertainty.h"

namespace pk {
namespace {

using internal::IsSkippedLine;
using internal::SplitCsvLine;
using internal::ToUpper;

// The header's line (the first that is not skipped) and its fields; `first` is set past it.
std::vector<std::string> Header(const internal::NumberedLines& lines, const std::string& source, size_t* first,
                                int* line) {
  *first = 0;
  while (*first < lines.size() && IsSkippedLine(lines[*first].second)) ++*first;
  if (*first == lines.size()) throw InputError(source, 0, 0, "no header line");
  *line = lines[*first].first;
  return SplitCsvLine(lines[(*first)++].second);
}

// A data line's fields, as many as the header's.
std::vector<std::string> Fields(const std::string& text, size_t width, const std::string& source, int line) {
  std::vector<std::string> fields = SplitCsvLine(text);
  if (fields.size() != width) {
    throw InputError(source, line, 0, "expected " + std::to_string(width) + " fields as in the header, found " +
                                          std::to_string(fields.size()));
  }
  return fields;
}

double Number(const std::vector<std::string>& fields, size_t k, const std::string& source, int line) {
  double v = 0;
  if (!internal::ParseDouble(fields[k], &v) || !std::isfinite(v)) {
    throw InputError(source, line, static_cast<int>(k) + 1, "'" + fields[k] + "' is not a number");
  }
  return v;
}

// The bootstrap's columns are the estimates' parameters: each one the estimates hold (a covariance
// only where they have one), and every θ, Ω variance and σ of theirs among them.
void CheckSameParameters(const std::string& path, int line, const std::vector<std::string>& header,
                         const std::vector<std::string>& names, const PopulationEstimates& estimates, const Model& model) {
  const auto column = [&](const std::string& name) {
    for (size_t k = 0; k < header.size(); ++k) {
      if (header[k] == name) return static_cast<int>(k) + 1;
    }
    return 0;
  };
  std::vector<std::string> wanted;
  for (const auto& [theta, value] : estimates.theta) wanted.push_back(ToUpper(theta));
  for (const std::string& eta : estimates.etas) wanted.push_back("OMEGA(" + ToUpper(eta) + ")");
  for (const std::string& sigma : estimates.sigma_names) wanted.push_back(ToUpper(sigma));
  std::vector<std::string> upper;
  for (const std::string& n : names) upper.push_back(ToUpper(n));
  for (const std::string& w : wanted) {
    if (std::find(upper.begin(), upper.end(), w) == upper.end()) {
      throw InputError(path, line, 0, "no column " + w + ": a bootstrap of another run (" + estimates.source +
                                          " has it), or of another model");
    }
  }
  for (size_t k = 0; k < names.size(); ++k) {
    try {  // a name the estimates hold; a covariance where they have one (NaN marks where it goes)
      const PopulationEstimates probe =
          WithNaturalValues(estimates, {names[k]}, Eigen::VectorXd::Constant(1, std::nan("")), model);
      if (internal::OmegaArguments(upper[k]).size() == 2 &&
          (probe.omega.array().isNaN() && estimates.omega.array() == 0).any()) {
        throw InputError(names[k] + ": a covariance " + estimates.source + " does not have (a bootstrap of another run)");
      }
    } catch (const InputError& e) {
      throw InputError(path, line, column(names[k]), e.message());
    }
  }
}

}  // namespace

EstimatesCovariance ReadEstimatesCovariance(const std::string& path) {
  const internal::NumberedLines lines = internal::ReadLines(path);
  size_t at = 0;
  int header_line = 0;
  const std::vector<std::string> header = Header(lines, path, &at, &header_line);
  if (header.empty() || ToUpper(header[0]) != "PARAMETER") {
    throw InputError(path, header_line, 1, "expected pkpop's covariance.csv: PARAMETER, then a column per estimate");
  }
  EstimatesCovariance out;
  out.names.assign(header.begin() + 1, header.end());
  const auto m = static_cast<Eigen::Index>(out.names.size());
  out.covariance.resize(m, m);
  Eigen::Index row = 0;
  std::vector<int> row_line;  // each row's line in the file
  int last_line = header_line;
  for (; at < lines.size(); ++at) {
    if (IsSkippedLine(lines[at].second)) continue;
    const int line = lines[at].first;
    last_line = line;
    const std::vector<std::string> fields = Fields(lines[at].second, header.size(), path, line);
    if (row == m || fields[0] != out.names[static_cast<size_t>(row)]) {
      throw InputError(path, line, 1, "expected the row of " + (row < m ? out.names[static_cast<size_t>(row)] : "no estimate") +
                                          ", found " + fields[0]);
    }
    for (Eigen::Index k = 0; k < m; ++k) out.covariance(row, k) = Number(fields, static_cast<size_t>(k) + 1, path, line);
    row_line.push_back(line);
    ++row;
  }
  if (m == 0 || row == 0) {
    throw InputError(path, header_line, 0, "no estimate has a variance (the run had no covariance step, or it failed)");
  }
  if (row != m) {
    throw InputError(path, last_line, 0, "expected " + std::to_string(m) + " rows, one per estimate, found " +
                                             std::to_string(row));
  }
  const double scale = std::max(out.covariance.diagonal().cwiseAbs().maxCoeff(), 1e-300);
  for (Eigen::Index i = 0; i < m; ++i) {
    for (Eigen::Index j = 0; j < i; ++j) {
      if (std::abs(out.covariance(i, j) - out.covariance(j, i)) > 1e-10 * scale) {
        throw InputError(path, row_line[static_cast<size_t>(i)], static_cast<int>(j) + 2,
                         "the covariance is not symmetric: " + out.names[static_cast<size_t>(i)] + " with " +
                             out.names[static_cast<size_t>(j)] + " differs from the transposed entry");
      }
    }
  }
  return out;
}

std::vector<PopulationEstimates> ReadParameterSets(const std::string& path, const PopulationEstimates& estimates,
                                                   const Model& model) {
  const internal::NumberedLines lines = internal::ReadLines(path);
  size_t at = 0;
  int header_line = 0;
  const std::vector<std::string> header = Header(lines, path, &at, &header_line);
  int used = -1;
  std::vector<std::string> names;
  std::vector<size_t> columns;
  for (size_t k = 0; k < header.size(); ++k) {
    const std::string h = ToUpper(header[k]);
    if (h == "USED") used = static_cast<int>(k);
    if (h == "REPLICATE" || h == "CONVERGED" || h == "BOUNDARY" || h == "USED" || h == "OFV") continue;
    names.push_back(header[k]);
    columns.push_back(k);
  }
  CheckSameParameters(path, header_line, header, names, estimates, model);
  std::vector<PopulationEstimates> out;
  for (; at < lines.size(); ++at) {
    if (IsSkippedLine(lines[at].second)) continue;
    const int line = lines[at].first;
    const std::vector<std::string> fields = Fields(lines[at].second, header.size(), path, line);
    if (used >= 0 && Number(fields, static_cast<size_t>(used), path, line) != 1) continue;
    Eigen::VectorXd values(static_cast<Eigen::Index>(names.size()));
    for (size_t k = 0; k < columns.size(); ++k) values(static_cast<Eigen::Index>(k)) = Number(fields, columns[k], path, line);
    out.push_back(WithNaturalValues(estimates, names, values, model));
    out.back().source = path + ":" + std::to_string(line);
    std::string why;
    if (!InParameterSpace(out.back(), model, &why)) throw InputError(path, line, 0, "a used replicate outside the parameter space: " + why);
  }
  if (out.empty()) throw InputError(path, 0, 0, "no parameter set (no row marked USED)");
  return out;
}

}  // namespace pk
