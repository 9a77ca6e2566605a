// pkfit's CSV outputs, one writer per file (parsing and I/O only: the numbers come from the library).
#ifndef PK_APPS_FIT_CSV_H_
#define PK_APPS_FIT_CSV_H_

#include <string>
#include <vector>

#include "pk/fit_subjects.h"
#include "pk/two_stage.h"
#include "pk/units.h"

namespace pk {
namespace cli {

/// A number as CSV writes it: all its digits, empty when not finite.
std::string Csv(double v);
/// "converged", "not converged", "failed" or "unbounded".
std::string FitStatus(const SubjectFit& f);

std::string EstimatesCsv(const std::vector<SubjectFit>& fits, const Units& units);     ///< estimates.csv
std::string SummaryCsv(const std::vector<SubjectFit>& fits);       ///< summary.csv
std::string PredictionsCsv(const std::vector<SubjectFit>& fits, const Dataset& data);   ///< predictions.csv
std::string FitDetailsCsv(const std::vector<SubjectFit>& fits);    ///< fit_details.csv
/// derived.csv, or "" when no fit has derived parameters.
std::string DerivedCsv(const std::vector<SubjectFit>& fits, const Units& units);
std::string PopulationCsv(const TwoStageSummary& pop, const Units& units);             ///< population.csv
std::string PopulationOmegaCsv(const TwoStageSummary& pop);        ///< population_omega.csv

}  // namespace cli
}  // namespace pk

#endif  // PK_APPS_FIT_CSV_H_
