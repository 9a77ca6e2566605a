// libpk: per-subject parameter values from a table, such as pkfit's estimates.csv.
//
//   const auto table = pk::ReadEstimates("fit/estimates.csv", *model);
//   for (const pk::SubjectEstimates& s : table) { ... s.id ... s.values.at("CL") ... }
//
// The table needs the columns ID, PARAMETER and ESTIMATE (names are
// case-insensitive, other columns such as SE and RSE_PCT are ignored). Fields
// may be double-quoted; blank lines and lines starting with '#' are skipped.
// pksim --estimates simulates each subject at its values; pkfit --init-from
// starts each subject's fit from them (FitSubjectsRequest::initial_by_subject).
#ifndef PK_ESTIMATES_H_
#define PK_ESTIMATES_H_

#include <string>
#include <utility>
#include <vector>

#include "pk/model.h"
#include "pk/parameters.h"

namespace pk {

/// (ID, values): one subject's rows of the table.
using SubjectEstimates = std::pair<double, ParameterValues>;

/// The subjects of the table at `path`, in the order their IDs first appear.
/// Every PARAMETER must be one of `model`'s parameters or dose modifiers
/// (pk/parameters.h), SIGMA_ADD or SIGMA_PROP, and may appear once per ID.
/// Throws pk::InputError naming the file, line and column (the field's number,
/// as for datasets) of the first problem.
std::vector<SubjectEstimates> ReadEstimates(const std::string& path, const Model& model);

/// The same from text in memory; `source` names it in errors.
std::vector<SubjectEstimates> ParseEstimates(const std::string& text, const std::string& source, const Model& model);

}  // namespace pk

#endif  // PK_ESTIMATES_H_
