// pkpop's report.html and its plots (the only user of kainjow::mustache in pkpop).
#ifndef PK_APPS_POP_HTML_H_
#define PK_APPS_POP_HTML_H_

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "pk/bootstrap.h"
#include "pk/npde.h"
#include "pk/population.h"
#include "pk/vpc.h"

namespace pk {
namespace cli {

struct PopulationReportContext {
  std::string model, error, dataset_path, command_line;
  std::optional<VpcSummary> vpc;  ///< a VPC section when present
  std::optional<NpdeSummary> npde;  ///< an NPDE section when present
  std::optional<BootstrapSummary> bootstrap;  ///< a bootstrap section when present
};

/// report.html and the plots it shows (gof_*.svg, eta_*.svg), as (file name, contents) pairs.
std::vector<std::pair<std::string, std::string>> PopulationReport(const PopulationProblem& problem,
                                                                  const PopulationSummary& fit,
                                                                  const PopulationReportContext& context);

}  // namespace cli
}  // namespace pk

#endif  // PK_APPS_POP_HTML_H_
