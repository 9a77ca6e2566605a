#include "cli.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <sstream>

#include <boost/program_options.hpp>

#include "pk/error.h"

namespace pk {
namespace cli {
namespace {

double ToNumber(const std::string& text, const std::string& option, const std::string& item) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0' || !std::isfinite(v)) {
    throw InputError("", 0, 0, option + ": '" + item + "': '" + text + "' is not a number");
  }
  return v;
}

}  // namespace

ParameterValues ParseAssignments(const std::vector<std::string>& items, const std::string& option) {
  ParameterValues values;
  for (const std::string& item : items) {
    const size_t eq = item.find('=');
    if (eq == std::string::npos || eq == 0) {
      throw InputError("", 0, 0, option + ": expected NAME=VALUE, got '" + item + "'");
    }
    values[item.substr(0, eq)] = ToNumber(item.substr(eq + 1), option, item);
  }
  return values;
}

std::vector<std::pair<double, ParameterValues>> ReadEstimates(const std::string& path, const Model& model) {
  std::ifstream in(path);
  if (!in) throw InputError(path, 0, 0, "cannot open the estimates file");
  const ParameterLayout layout(model);
  auto split = [](std::string line) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::vector<std::string> fields;
    std::stringstream ss(line);
    std::string f;
    while (std::getline(ss, f, ',')) fields.push_back(f);
    if (!line.empty() && line.back() == ',') fields.emplace_back();
    return fields;
  };
  auto column_of = [](const std::vector<std::string>& fields, int k) {  // 1-based column of field k
    int col = 1;
    for (int i = 0; i < k; ++i) col += static_cast<int>(fields[i].size()) + 1;
    return col;
  };
  std::string line;
  int line_number = 0;
  std::vector<std::string> header;
  while (header.empty() && std::getline(in, line)) {
    ++line_number;
    if (line.find_first_not_of(" \t\r") != std::string::npos) header = split(line);
  }
  int id = -1, name = -1, value = -1;
  for (int k = 0; k < static_cast<int>(header.size()); ++k) {
    std::string h;
    for (char c : header[k]) {
      if (c != '"' && c != ' ') h += static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
    }
    if (h == "ID") id = k;
    if (h == "PARAMETER") name = k;
    if (h == "ESTIMATE") value = k;
  }
  if (id < 0 || name < 0 || value < 0) {
    throw InputError(path, std::max(line_number, 1), 0, "the estimates file needs the columns ID, PARAMETER and ESTIMATE");
  }
  std::vector<std::pair<double, ParameterValues>> out;
  while (std::getline(in, line)) {
    ++line_number;
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    const std::vector<std::string> fields = split(line);
    if (fields.size() != header.size()) {
      throw InputError(path, line_number, 0, "expected " + std::to_string(header.size()) + " fields as in the header, found " +
                                                 std::to_string(fields.size()));
    }
    auto number = [&](int k, const char* what) {
      char* end = nullptr;
      const double v = std::strtod(fields[k].c_str(), &end);
      if (fields[k].empty() || *end != '\0' || !std::isfinite(v)) {
        throw InputError(path, line_number, column_of(fields, k),
                         std::string(what) + ": '" + fields[k] + "' is not a number");
      }
      return v;
    };
    const double subject = number(id, "ID");
    const std::string& parameter = fields[name];
    std::string upper;
    for (char c : parameter) upper += static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
    if (layout.Index(parameter) < 0 && upper != "SIGMA_ADD" && upper != "SIGMA_PROP") {
      throw InputError(path, line_number, column_of(fields, name),
                       "'" + parameter + "' is not a parameter of model " + model.name());
    }
    const double estimate = number(value, "ESTIMATE");
    auto it = std::find_if(out.begin(), out.end(), [&](const auto& e) { return e.first == subject; });
    if (it == out.end()) {
      out.emplace_back(subject, ParameterValues());
      it = out.end() - 1;
    }
    it->second[parameter] = estimate;
  }
  if (out.empty()) throw InputError(path, line_number, 0, "the estimates file has no rows");
  return out;
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
      if (c2 == std::string::npos) throw InputError("", 0, 0, "--times: expected FROM:STEP:TO, got '" + part + "'");
      const double from = ToNumber(part.substr(0, c1), "--times", spec);
      const double step = ToNumber(part.substr(c1 + 1, c2 - c1 - 1), "--times", spec);
      const double to = ToNumber(part.substr(c2 + 1), "--times", spec);
      if (step <= 0 || to < from) throw InputError("", 0, 0, "--times: '" + part + "' needs STEP > 0 and TO >= FROM");
      const long count = std::lround(std::floor((to - from) / step + 1e-9));
      if (count > 10000000) throw InputError("", 0, 0, "--times: '" + part + "' asks for too many times");
      for (long k = 0; k <= count; ++k) times.push_back(from + static_cast<double>(k) * step);
    }
  }
  return times;
}

bool ParseCommandLine(int argc, char** argv, const boost::program_options::options_description& desc,
                      const char* usage, boost::program_options::variables_map* vm) {
  boost::program_options::store(boost::program_options::parse_command_line(argc, argv, desc), *vm);
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

Propagator ParsePropagator(const std::string& text) {
  for (Propagator p : {Propagator::kAuto, Propagator::kExact, Propagator::kOde}) {
    if (text == ToString(p)) return p;
  }
  throw InputError("", 0, 0, "--propagator must be auto, exact or ode, not '" + text + "'");
}

}  // namespace cli
}  // namespace pk
