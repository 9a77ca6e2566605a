// Parsing helpers shared by the command-line apps (parsing and I/O only).
#ifndef PK_APPS_CLI_H_
#define PK_APPS_CLI_H_

#include <functional>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <boost/program_options.hpp>

#include "pk/dataset.h"
#include "pk/error.h"
#include "pk/parameters.h"
#include "pk/propagator.h"

namespace pk {
namespace cli {

/// "NAME=VALUE" pairs as given to --param/--init/--fix; throws pk::InputError naming `option`.
ParameterValues ParseAssignments(const std::vector<std::string>& items, const std::string& option);

/// Output times: "FROM:STEP:TO" (inclusive) or a comma-separated list, or several of them.
std::vector<double> ParseTimes(const std::vector<std::string>& specs);

/// Adds --ignore and --accept (NM-TRAN's IGNORE= and ACCEPT=) to `desc`, collected into `ignore` and `accept`.
void AddFilterOptions(boost::program_options::options_description* desc, std::vector<std::string>* ignore,
                      std::vector<std::string>* accept);
/// The dataset filter they give: a one-character --ignore is IGNORE=c, longer ones are conditions.
DatasetFilter ParseFilter(const std::vector<std::string>& ignore, const std::vector<std::string>& accept);

/// "auto", "exact", "ode" or "rk"; throws pk::InputError otherwise.
Propagator ParsePropagator(const std::string& text);

/// Parses the command line into `vm`; prints `usage` and the options and returns false when
/// --help was given, prints the version and returns false for --version (`desc` holds both). An
/// unknown option is a pk::InputError that names the closest known one.
bool ParseCommandLine(int argc, char** argv, const boost::program_options::options_description& desc,
                      const char* usage, boost::program_options::variables_map* vm);

/// Runs `parse` and prefixes the message of a pk::InputError it throws with `option`
/// ("--gradient: expected ...").
template <typename Parse>
auto Parsed(const std::string& option, const Parse& parse) -> decltype(parse()) {
  try {
    return parse();
  } catch (const InputError& e) {
    throw InputError(option + ": " + e.message());
  }
}

/// Runs `body` and maps errors to exit codes: pk::InputError and bad options -> 2
/// with one line "<program>: error: ..." on stderr; other exceptions -> 3.
int Run(const std::string& program, const std::function<int()>& body);

/// `v` to `digits` significant digits, "–" when not finite.
std::string Sig(double v, int digits);
/// The date and time now, for a report's header ("2026-11-25 14:03 UTC").
std::string Today();
/// An η's column label: ETA_CL for the log-normal η on CL; a model file's η keeps its own name
/// when that already starts with ETA (ETA_CL, not ETA_ETA_CL).
std::string EtaLabel(const std::string& eta_name);

/// --seed's value: a whole number from 0 to 2^64 − 1; throws pk::InputError otherwise.
std::uint64_t ParseSeed(const std::string& text);
/// A CSV text field, quoted (RFC 4180) when it holds a comma, a quote or a line end: a covariance's
/// name OMEGA(V,CL) is one field.
std::string Quote(const std::string& s);

}  // namespace cli
}  // namespace pk

#endif  // PK_APPS_CLI_H_
