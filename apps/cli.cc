#include "cli.h"

#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <sstream>

#include <boost/program_options.hpp>

#include "pk/error.h"
#include "pk/output.h"
#include "pk/version.h"

namespace pk {
namespace cli {
namespace {

double ToNumber(const std::string& text, const std::string& option, const std::string& item) {
  double v = 0;
  if (!ParseNumber(text, &v)) throw InputError(option + ": '" + item + "': '" + text + "' is not a number");
  return v;
}

// t to 15 significant digits: a grid's FROM + k·STEP without the rounding of the sum (0.1 + 0.2 is
// 0.30000000000000004; 0.3 is what FROM:STEP:TO means). Locale-independent, as the readers are.
double Snapped(double t) {
  char text[32];
  const auto written = std::to_chars(text, text + sizeof text, t, std::chars_format::general, 15);
  double snapped = t;
  if (written.ec == std::errc() && std::from_chars(text, written.ptr, snapped).ec == std::errc()) return snapped;
  return t;
}

}  // namespace

ParameterValues ParseAssignments(const std::vector<std::string>& items, const std::string& option) {
  ParameterValues values;
  for (const std::string& item : items) {
    const size_t eq = item.find('=');
    if (eq == std::string::npos || eq == 0) {
      throw InputError(option + ": expected NAME=VALUE, got '" + item + "'");
    }
    values[item.substr(0, eq)] = ToNumber(item.substr(eq + 1), option, item);
  }
  return values;
}

std::vector<double> ParseTimes(const std::vector<std::string>& specs) {
  std::vector<double> times;
  for (const std::string& spec : specs) {
    std::stringstream list(spec);
    std::string part;
    while (std::getline(list, part, ',')) {
      const size_t c1 = part.find(':');
      if (c1 == std::string::npos) {
        times.push_back(ToNumber(part, "--times", spec));
        continue;
      }
      const size_t c2 = part.find(':', c1 + 1);
      if (c2 == std::string::npos) throw InputError("--times: expected FROM:STEP:TO, got '" + part + "'");
      const double from = ToNumber(part.substr(0, c1), "--times", spec);
      const double step = ToNumber(part.substr(c1 + 1, c2 - c1 - 1), "--times", spec);
      const double to = ToNumber(part.substr(c2 + 1), "--times", spec);
      if (step <= 0 || to < from) throw InputError("--times: '" + part + "' needs STEP > 0 and TO >= FROM");
      // 0:24:0.5 (FROM:TO:STEP, mrgsolve's and R's seq order) would give the one time FROM.
      if (to > from && step > (to - from) * (1 + 1e-9)) {  // 0.1:0.2:0.3 (0.3 − 0.1 rounds below 0.2) is fine
        throw InputError("--times: '" + part + "' is FROM:STEP:TO, and STEP " + FormatNumber(step) +
                         " is longer than the range " + FormatNumber(from) + " to " + FormatNumber(to) +
                         " (did you mean " + part.substr(0, c1) + ":" + part.substr(c2 + 1) + ":" +
                         part.substr(c1 + 1, c2 - c1 - 1) + "?)");
      }
      const long count = std::lround(std::floor((to - from) / step + 1e-9));
      if (count > 10000000) throw InputError("--times: '" + part + "' asks for too many times");
      for (long k = 0; k <= count; ++k) times.push_back(Snapped(from + static_cast<double>(k) * step));
    }
  }
  return times;
}

namespace {

// An unknown option's message with the closest known option: "... (did you mean --data?)".
[[noreturn]] void RethrowUnknown(const boost::program_options::unknown_option& e,
                                 const boost::program_options::options_description& desc) {
  std::string given = e.get_option_name();
  given = given.substr(std::min(given.find_first_not_of('-'), given.size()));
  given = given.substr(0, given.find('='));
  std::vector<std::string> names;
  for (const auto& option : desc.options()) names.push_back(option->long_name());
  const std::string closest = ClosestName(given, names);
  throw InputError(std::string(e.what()) + (closest.empty() ? "" : " (did you mean --" + closest + "?)") +
                   " (see --help)");
}

}  // namespace

bool ParseCommandLine(int argc, char** argv, const boost::program_options::options_description& desc,
                      const char* usage, boost::program_options::variables_map* vm) {
  try {
    boost::program_options::store(boost::program_options::parse_command_line(argc, argv, desc), *vm);
  } catch (const boost::program_options::unknown_option& e) {
    RethrowUnknown(e, desc);
  }
  if (vm->count("version")) {
    const std::string program = std::filesystem::path(argv[0]).filename().string();
    std::cout << program << " (libpk) " << Version() << "\n";
    return false;
  }
  boost::program_options::notify(*vm);
  if (vm->count("help")) {
    std::cout << usage << "\n" << desc << "\n";
    return false;
  }
  return true;
}

int Run(const std::string& program, const std::function<int()>& body) {
  try {
    return body();
  } catch (const InputError& e) {
    std::cerr << program << ": error: " << e.what() << "\n";
    return 2;
  } catch (const boost::program_options::error& e) {
    std::cerr << program << ": error: " << e.what() << " (see --help)\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << program << ": error: " << e.what() << "\n";
    return 3;
  }
}

void AddFilterOptions(boost::program_options::options_description* desc, std::vector<std::string>* ignore,
                      std::vector<std::string>* accept) {
  namespace po = boost::program_options;
  desc->add_options()("ignore", po::value<std::vector<std::string>>(ignore)->composing(),
                      "NM-TRAN's IGNORE=: one character drops the data lines starting with it ('@': with a letter "
                      "or @), or conditions drop the records meeting any, e.g. 'DVID.EQ.2' or '(TIME.GT.24,BLQ.EQ.1)'; "
                      "repeatable")(
      "accept", po::value<std::vector<std::string>>(accept)->composing(),
      "NM-TRAN's ACCEPT=: keep only the records meeting one of these conditions, e.g. 'ID.LE.6'; repeatable");
}

DatasetFilter ParseFilter(const std::vector<std::string>& ignore, const std::vector<std::string>& accept) {
  DatasetFilter filter;
  for (const std::string& item : ignore) {
    if (item.size() != 1) {
      filter.ignore.push_back(item);
    } else if (filter.ignore_character != 0 && filter.ignore_character != item[0]) {
      throw InputError(std::string("--ignore: one ignore character, not both '") + filter.ignore_character +
                                     "' and '" + item + "' (NM-TRAN's IGNORE=c takes one)");
    } else {
      filter.ignore_character = item[0];
    }
  }
  filter.accept = accept;
  return filter;
}

Propagator ParsePropagator(const std::string& text) {
  return Parsed("--propagator", [&] { return pk::ParsePropagator(text); });
}

std::string Sig(double v, int digits) {
  if (!std::isfinite(v)) return "–";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*g", digits, v);
  return buf;
}

std::string EtaLabel(const std::string& eta_name) {
  return eta_name.rfind("ETA", 0) == 0 ? eta_name : "ETA_" + eta_name;
}

std::uint64_t ParseSeed(const std::string& seed) {
  if (seed.empty() || seed.size() > 20 || seed.find_first_not_of("0123456789") != std::string::npos) {
    throw InputError("--seed: expected a whole number from 0 to 18446744073709551615, not '" + seed + "'");
  }
  try {
    return std::stoull(seed);
  } catch (const std::exception&) {
    throw InputError("--seed: '" + seed + "' is above 18446744073709551615");
  }
}

std::string Quote(const std::string& s) {
  if (s.find_first_of(",\"\r\n") == std::string::npos) return s;
  std::string out = "\"";
  for (char c : s) out += c == '"' ? std::string("\"\"") : std::string(1, c);
  return out + "\"";
}

std::string Today() {
  const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm utc{};
  gmtime_r(&now, &utc);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%d %H:%M UTC", &utc);
  return buf;
}

}  // namespace cli
}  // namespace pk
