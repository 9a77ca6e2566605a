// summary.json: the run in one machine-readable file for R and Python pipelines
// (jsonlite::fromJSON, json.load). nlohmann::json is used in this file only.
#include <cmath>

#include <nlohmann/json.hpp>

#include "fit_csv.h"
#include "fit_report.h"
#include "pk/version.h"

namespace pk {
namespace cli {
namespace {

// A number, or null when it is not finite (JSON has no NaN).
nlohmann::json Number(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

nlohmann::json Subject(const SubjectFit& f, const Units& units) {
  const FitSummary& s = f.summary;
  nlohmann::json j = {{"id", f.id},          {"occurrence", f.occurrence}, {"status", FitStatus(f)},
                      {"trusted", Trusted(f)}, {"nobs", f.dv.size()},      {"ncens", f.censoring.cwiseAbs().sum()}};
  if (!f.ok) {
    j["error"] = f.error;
    return j;
  }
  j["ofv"] = Number(s.ofv);
  j["rss"] = Number(s.rss);
  j["minus2ll"] = Number(s.minus2ll);
  j["aic"] = Number(s.aic);
  j["bic"] = Number(s.bic);
  j["iterations"] = s.iterations;
  j["message"] = s.message;
  j["covariance_message"] = s.covariance_message;
  nlohmann::json estimates = nlohmann::json::array();
  for (const ParameterEstimate& e : s.estimates) {
    estimates.push_back({{"name", e.name},
                         {"estimate", Number(e.estimate)},
                         {"se", Number(e.se)},
                         {"rse_pct", Number(e.rse_pct)},
                         {"fixed", e.fixed},
                         {"at_bound", e.at_bound},
                         {"unit", ParameterUnit(e.name, units)}});
  }
  j["estimates"] = estimates;
  return j;
}

nlohmann::json Population(const TwoStageSummary& pop) {
  nlohmann::json parameters = nlohmann::json::array();
  for (size_t k = 0; k < pop.descriptive.size(); ++k) {
    const DescriptiveStatistics& d = pop.descriptive[k];
    nlohmann::json p = {{"name", d.name}, {"n", d.n}, {"mean", Number(d.mean)}, {"sd", Number(d.sd)},
                        {"geometric_mean", Number(d.geometric_mean)}, {"median", Number(d.median)}};
    if (pop.gts_ok) {
      const PopulationParameter& q = pop.population[k];
      p["typical"] = Number(q.typical);
      p["typical_rse_pct"] = Number(q.typical_rse_pct);
      p["omega2"] = Number(q.omega2);
      p["omega2_at_bound"] = q.omega2_at_bound;
      p["omega2_rse_pct"] = Number(q.omega2_rse_pct);
      p["bsv_cv_pct"] = Number(q.bsv_cv_pct);
    }
    parameters.push_back(p);
  }
  return {{"method", "two-stage"}, {"distribution", ToString(pop.distribution)}, {"gts_ok", pop.gts_ok},
          {"parameters", parameters}};
}

}  // namespace

std::string JsonSummary(const std::vector<SubjectFit>& fits, const ReportContext& context) {
  nlohmann::json run = {{"program", "pkfit"},
                        {"libpk_version", Version()},
                        {"model", context.model},
                        {"dataset", context.data ? context.data->source : ""},
                        {"method", context.method},
                        {"objective", ObjectiveName(fits)},
                        {"units", {{"time", context.units.time}, {"amount", context.units.amount},
                                   {"concentration", context.units.concentration}}},
                        {"command", context.command_line}};
  nlohmann::json subjects = nlohmann::json::array();
  int trusted = 0;
  for (const SubjectFit& f : fits) {
    subjects.push_back(Subject(f, context.units));
    trusted += Trusted(f) ? 1 : 0;
  }
  run["num_subjects"] = fits.size();
  run["num_trusted"] = trusted;
  run["subjects"] = subjects;
  if (context.population) run["population"] = Population(*context.population);
  // Text from the data (a units row, a path, a message quoting a field) may not be UTF-8: such bytes
  // become U+FFFD rather than an exception after the fits.
  return run.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
}

}  // namespace cli
}  // namespace pk
