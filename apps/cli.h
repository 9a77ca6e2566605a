// Parsing helpers shared by the command-line apps (parsing and I/O only).
#ifndef PK_APPS_CLI_H_
#define PK_APPS_CLI_H_

#include <functional>
#include <string>
#include <vector>

#include "pk/parameters.h"

namespace pk {
namespace cli {

/// "NAME=VALUE" pairs as given to --param/--init/--fix; throws pk::InputError naming `option`.
ParameterValues ParseAssignments(const std::vector<std::string>& items, const std::string& option);

/// Output times: "FROM:STEP:TO" (inclusive) or a comma-separated list, or several of them.
std::vector<double> ParseTimes(const std::vector<std::string>& specs);

/// Runs `body` and maps errors to exit codes: pk::InputError and bad options -> 2
/// with one line "<program>: error: ..." on stderr; other exceptions -> 3.
int Run(const std::string& program, const std::function<int()>& body);

}  // namespace cli
}  // namespace pk

#endif  // PK_APPS_CLI_H_
