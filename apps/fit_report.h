// pkfit's output files (I/O only).
#ifndef PK_APPS_FIT_REPORT_H_
#define PK_APPS_FIT_REPORT_H_

#include <string>
#include <vector>

#include "pk/fit_subjects.h"
#include "pk/two_stage.h"

namespace pk {
namespace cli {

struct ReportContext {
  std::string model;
  std::string data;
  std::string command_line;
  bool log_plots = false;
  /// Two-stage population estimates over the subjects, or null for none.
  const TwoStageSummary* population = nullptr;
};

/// Writes estimates.csv, summary.csv, predictions.csv, fit_details.csv, one
/// SVG per subject and report.html into `dir` (each file whole or not at all);
/// with a population summary also population.csv and population_omega.csv.
void WriteFitOutputs(const std::string& dir, const std::vector<SubjectFit>& fits, const ReportContext& context);

/// The starting values per subject as CSV: ID,PARAMETER,INITIAL,SOURCE.
std::string InitialTable(const std::vector<SubjectFit>& fits);

/// Linear models: the exponents and half-lives (tf models: also the compartmental readings), for the terminal.
std::string DerivedTable(const std::vector<SubjectFit>& fits);

/// The two-stage population estimates for the terminal.
std::string PopulationTable(const TwoStageSummary& population);

/// The estimates as a fixed-width table for the terminal.
std::string EstimatesTable(const std::vector<SubjectFit>& fits);

}  // namespace cli
}  // namespace pk

#endif  // PK_APPS_FIT_REPORT_H_
