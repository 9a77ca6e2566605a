// Reading pkpop's population_estimates.csv (see pk/population_estimates.h).
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "../internal_text.h"
#include "csv_lines.h"
#include "pk/error.h"
#include "pk/output.h"
#include "pk/population_estimates.h"
#include "pk/residual_error.h"

namespace pk {
namespace {

using internal::IsSkippedLine;
using internal::OmegaArguments;
using internal::SplitCsvLine;
using internal::ToUpper;

struct Row {
  int line, column;  // the PARAMETER field's
  std::string name;  // as written
  double value;
};

class Reader {
 public:
  Reader(const std::string& source, const Model& model) : source_(source), model_(model) { out_.source = source; }

  void Fail(const Row& r, const std::string& message) const { throw InputError(source_, r.line, r.column, message); }

  // The η of OMEGA(NAME): a model file's η parameter, or an estimable parameter (log-normal).
  void AddEta(const Row& r, const std::string& name) {
    const int i = model_.ParameterIndex(name);
    if (i < 0) Fail(r, r.name + ": '" + name + "' is not a parameter of model " + model_.name());
    if (model_.is_covariate(i)) Fail(r, r.name + ": " + name + " is a covariate, which has no η");
    if (!(r.value >= 0)) Fail(r, r.name + ": a variance is not negative, not " + FormatNumber(r.value));
    const std::string& canonical = model_.parameter_names()[static_cast<size_t>(i)];
    for (const std::string& e : out_.etas) {
      if (e == canonical) Fail(r, r.name + " is given twice");
    }
    out_.etas.push_back(canonical);
    out_.eta_log_normal.push_back(!model_.is_eta(i));
    variances_.push_back(r.value);
  }

  int EtaIndex(const Row& r, const std::string& name) const {
    const int i = model_.ParameterIndex(name);
    for (size_t k = 0; i >= 0 && k < out_.etas.size(); ++k) {
      if (out_.etas[k] == model_.parameter_names()[static_cast<size_t>(i)]) return static_cast<int>(k);
    }
    Fail(r, r.name + ": " + name + " has no variance OMEGA(" + name + ")");
    return -1;
  }

  void Add(const Row& r) {
    const std::string upper = ToUpper(r.name);
    if (upper == "OFV") return;
    const std::vector<std::string> omega = OmegaArguments(upper);
    if (omega.size() == 1) return AddEta(r, omega[0]);
    // pkpop tables Ω's lower triangle by rows (OMEGA(CL), OMEGA(V,CL), OMEGA(V)): a covariance is
    // placed once every variance is known.
    if (omega.size() == 2) return covariances_.push_back({r, {omega[0], omega[1]}});
    if (IsResidualErrorName(upper)) {
      if (!(r.value >= 0)) Fail(r, r.name + ": σ is a standard deviation, not " + FormatNumber(r.value));
      out_.sigma_names.push_back(upper);
      sigmas_.push_back(r.value);
      return;
    }
    const int i = model_.ParameterIndex(r.name);
    if (i < 0) Fail(r, "'" + r.name + "' is not a parameter of model " + model_.name());
    const std::string& canonical = model_.parameter_names()[static_cast<size_t>(i)];
    if (!out_.theta.emplace(canonical, r.value).second) Fail(r, r.name + " is given twice");
  }

  PopulationEstimates Finish() {
    const auto q = static_cast<Eigen::Index>(out_.etas.size());
    out_.omega = Eigen::MatrixXd::Zero(q, q);
    for (Eigen::Index k = 0; k < q; ++k) out_.omega(k, k) = variances_[static_cast<size_t>(k)];
    for (const auto& [row, names] : covariances_) {
      const int a = EtaIndex(row, names.first), b = EtaIndex(row, names.second);
      if (out_.omega(a, b) != 0) Fail(row, row.name + " is given twice");
      out_.omega(a, b) = out_.omega(b, a) = row.value;
    }
    out_.sigma = Eigen::Map<const Eigen::VectorXd>(sigmas_.data(), static_cast<Eigen::Index>(sigmas_.size()));
    return out_;
  }

 private:
  const std::string& source_;
  const Model& model_;
  PopulationEstimates out_;
  std::vector<double> variances_, sigmas_;
  std::vector<std::pair<Row, std::pair<std::string, std::string>>> covariances_;
};

PopulationEstimates Parse(const internal::NumberedLines& lines, const std::string& source, const Model& model) {
  size_t first = 0;
  while (first < lines.size() && IsSkippedLine(lines[first].second)) ++first;
  if (first == lines.size()) throw InputError(source, 0, 0, "the population estimates have no header line");
  const int header_line = lines[first].first;
  const std::vector<std::string> header = SplitCsvLine(lines[first].second);
  int name = -1, value = -1;
  for (int k = 0; k < static_cast<int>(header.size()); ++k) {
    const std::string h = ToUpper(header[k]);
    if (h == "PARAMETER") name = k;
    if (h == "ESTIMATE") value = k;
  }
  if (name < 0 || value < 0) {
    throw InputError(source, header_line, 0, "population estimates need the columns PARAMETER and ESTIMATE (pkpop's "
                                             "population_estimates.csv)");
  }
  Reader reader(source, model);
  for (size_t i = first + 1; i < lines.size(); ++i) {
    if (IsSkippedLine(lines[i].second)) continue;
    const int line = lines[i].first;
    const std::vector<std::string> fields = SplitCsvLine(lines[i].second);
    if (fields.size() != header.size()) {
      throw InputError(source, line, 0, "expected " + std::to_string(header.size()) + " fields as in the header, found " +
                                            std::to_string(fields.size()));
    }
    Row r{line, name + 1, fields[static_cast<size_t>(name)], 0};
    if (ToUpper(r.name) == "OFV") continue;
    if (!internal::ParseDouble(fields[static_cast<size_t>(value)], &r.value) || !std::isfinite(r.value)) {
      throw InputError(source, line, value + 1, "ESTIMATE: '" + fields[static_cast<size_t>(value)] + "' is not a number");
    }
    reader.Add(r);
  }
  PopulationEstimates out = reader.Finish();
  if (out.etas.empty()) throw InputError(source, header_line, 0, "the population estimates have no OMEGA: no η to draw");
  return out;
}

}  // namespace

PopulationEstimates ReadPopulationEstimates(const std::string& path, const Model& model) {
  return Parse(internal::ReadLines(path), path, model);
}

PopulationEstimates ParsePopulationEstimates(const std::string& text, const std::string& source, const Model& model) {
  return Parse(internal::TextLines(text, source), source, model);
}

}  // namespace pk
