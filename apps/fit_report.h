// pkfit's output files and terminal tables (I/O and presentation only).
#ifndef PK_APPS_FIT_REPORT_H_
#define PK_APPS_FIT_REPORT_H_

#include <string>
#include <vector>

#include "cli.h"
#include "pk/dataset.h"
#include "pk/fit_subjects.h"
#include "pk/two_stage.h"
#include "pk/units.h"

namespace pk {
namespace cli {

/// The concentration axis of the per-subject plots.
enum class Axis { kAuto, kLinear, kLog, kBoth };

struct ReportContext {
  std::string model;
  std::string model_description;
  /// How the fits were made, for the report's header ("maximum likelihood, additive error; ...").
  std::string method;
  std::string command_line;
  const Dataset* data = nullptr;
  Units units;
  /// kAuto: semi-log for models whose response is a sum of several exponentials (linear models
  /// with more than one compartment), linear otherwise.
  Axis axis = Axis::kAuto;
  bool multi_exponential = false;
  /// Two-stage population estimates over the subjects, or null for none.
  const TwoStageSummary* population = nullptr;
};

/// Writes estimates.csv, summary.csv, predictions.csv, fit_details.csv, summary.json, one SVG
/// per subject and report.html into `dir` (each file whole or not at all, the set completed by
/// its MANIFEST); with a population summary also population.csv and population_omega.csv.
void WriteFitOutputs(const std::string& dir, const std::vector<SubjectFit>& fits, const ReportContext& context);

/// The starting values per subject as CSV: ID,PARAMETER,INITIAL,SOURCE.
std::string InitialTable(const std::vector<SubjectFit>& fits);

/// Linear models: the exponents and half-lives (tf models: also the compartmental readings), for the terminal.
std::string DerivedTable(const std::vector<SubjectFit>& fits);

/// The two-stage population estimates for the terminal.
std::string PopulationTable(const TwoStageSummary& population);

/// The estimates as a fixed-width table for the terminal: per subject the objective a NONMEM
/// user compares (OFV for maximum likelihood, RSS for least squares), AIC, BIC and the
/// estimates with their units and RSE%.
std::string EstimatesTable(const std::vector<SubjectFit>& fits, const Units& units);

// Shared by the report's writers.

/// A subject in file names and anchors ("1", "1_occ2") and in text ("1", "1 (occurrence 2)").
std::string SubjectKey(const SubjectFit& f);
std::string SubjectLabel(const SubjectFit& f);
/// An estimate as every table shows it: 4 significant digits, "0 (bound)" for a σ gone to 0.
std::string EstimateText(const ParameterEstimate& e);
/// RSE% to 3 significant digits ("–" for none, "fixed" for a fixed parameter).
std::string RseText(const ParameterEstimate& e);
/// "OFV" (maximum likelihood) or "RSS" (least squares), and the subject's value of it.
std::string ObjectiveName(const std::vector<SubjectFit>& fits);
double ReportedObjective(const FitSummary& s);
/// What the objective is, in a sentence for under a table.
std::string ObjectiveNote(const std::vector<SubjectFit>& fits);
/// Whether a subject's fit can be trusted: it ran, converged and is identifiable (IV data fitted
/// with an oral model's depot, say, leave CL and V unidentifiable, and so untrusted).
bool Trusted(const SubjectFit& f);

/// report.html (fit_html.cc) and summary.json (fit_json.cc); `files` receives the SVG files.
std::string HtmlReport(const std::vector<SubjectFit>& fits, const ReportContext& context,
                       std::vector<std::pair<std::string, std::string>>* files);
std::string JsonSummary(const std::vector<SubjectFit>& fits, const ReportContext& context);

}  // namespace cli
}  // namespace pk

#endif  // PK_APPS_FIT_REPORT_H_
