// Mutated datasets: the reader and the event engine either accept the text or
// reject it with an InputError that names the file and a line and column that
// exist, and a simulation of what was accepted ends either with finite
// predictions or with a reason. Nothing else may escape, crash or hang (the
// sanitizer build runs a tenth of the variants). The mutations are seeded, so
// a failure reproduces; the failing text is printed.
#include <cmath>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/dataset.h"
#include "pk/error.h"
#include "pk/initial_estimates.h"
#include "pk/simulate.h"
#include "test_util.h"

namespace {

// A dataset that uses every NONMEM item the reader knows, with lags and bioavailability.
const char* const kEveryItem =
    "ID,TIME,AMT,RATE,II,ADDL,SS,EVID,CMT,MDV,DV,F1,ALAG1\n"
    "1,0,100,0,12,2,0,1,1,1,.,0.8,0.25\n"
    "1,1,0,0,0,0,0,0,2,0,2.5,0.8,0.25\n"
    "1,4,0,0,0,0,0,0,2,0,1.9,0.8,0.25\n"
    "1,48,200,50,0,0,0,1,2,1,.,0.8,0.25\n"
    "1,50,0,0,0,0,0,0,2,0,3.1,0.8,0.25\n"
    "1,60,0,0,0,0,0,3,2,1,.,0.8,0.25\n"
    "1,61,150,0,24,0,1,1,1,1,.,0.8,0.25\n"
    "1,70,0,0,0,0,0,2,2,1,.,0.8,0.25\n"
    "2,0,80,-2,0,0,0,1,2,1,.,1,0\n"
    "2,2,0,0,0,0,0,0,2,0,1.2,1,0\n"
    "2,5,100,0,8,0,2,1,1,1,.,1,0\n"
    "2,9,0,0,0,0,0,0,2,0,4.4,1,0\n";

// Repeated oral dosing as starting values handle it (no steady state, no reset).
const char* const kRepeatedDoses =
    "ID,TIME,AMT,II,ADDL,EVID,MDV,DV\n"
    "1,0,100,12,3,1,1,.\n"
    "1,1,0,0,0,0,0,2.9\n"
    "1,3,0,0,0,0,0,3.4\n"
    "1,8,0,0,0,0,0,2.0\n"
    "1,25,0,0,0,0,0,4.1\n"
    "1,47,0,0,0,0,0,2.6\n";

std::string ReadText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

std::string Mutate(std::string text, std::mt19937* rng) {
  static const char* const kTokens[] = {"0",  "1",   "9",     ".",   "-",     "e",    "+",   "nan", "inf", ",",
                                        "\n", "\r",  " ",     "\"",  "#",     "1e300", "-1", "1e9", "A",   "\t",
                                        "",   "2",   "-1e-300", "..", "1e-320", "3",   "4",   "99",  ",,",  "\x01"};
  // Whole-field values at the edges of what the items allow.
  // (ADDL near its bound of 100000 doses would make a variant cost 1e5 events; test_reader.cc covers the bound.)
  static const char* const kValues[] = {"0",  "-1",  "-2",   "1e9",    "1e-9", "1e300", "nan",       "",   "2",  "3",
                                        "4",  "0.5", "999",  "1e-300", "inf",  "-0",    "100000000", "24", "12", "x"};
  const int kinds = 6;
  const int count = 1 + static_cast<int>((*rng)() % 3);
  for (int c = 0; c < count && !text.empty(); ++c) {
    const size_t pos = (*rng)() % text.size();
    const std::string token = kTokens[(*rng)() % (sizeof kTokens / sizeof kTokens[0])];
    switch ((*rng)() % kinds) {
      case 0:  // replace one character
        text.replace(pos, 1, token);
        break;
      case 1:  // delete a few characters
        text.erase(pos, 1 + (*rng)() % 5);
        break;
      case 2:  // insert
        text.insert(pos, token);
        break;
      case 3: {  // duplicate the line at pos after the next line
        const size_t b = text.rfind('\n', pos) == std::string::npos ? 0 : text.rfind('\n', pos) + 1;
        const size_t e = text.find('\n', pos);
        if (e == std::string::npos) break;
        const std::string line = text.substr(b, e - b + 1);
        const size_t next = text.find('\n', e + 1);
        text.insert(next == std::string::npos ? text.size() : next + 1, line);
        break;
      }
      case 4: {  // replace the field at pos by an edge value
        size_t b = pos, e = pos;
        while (b > 0 && text[b - 1] != ',' && text[b - 1] != '\n') --b;
        while (e < text.size() && text[e] != ',' && text[e] != '\n' && text[e] != '\r') ++e;
        text.replace(b, e - b, kValues[(*rng)() % (sizeof kValues / sizeof kValues[0])]);
        break;
      }
      default:  // truncate
        text.resize(pos);
        break;
    }
  }
  return text;
}

// Number of lines and the largest number of comma-separated fields on one.
void Shape(const std::string& text, int* lines, int* fields) {
  *lines = 1;
  *fields = 1;
  int f = 1;
  for (char ch : text) {
    if (ch == '\n') {
      ++*lines;
      f = 1;
    } else if (ch == ',') {
      *fields = std::max(*fields, ++f);
    }
  }
}

// Why an InputError's location does not exist in `text`, or "" when it does.
std::string LocationProblem(const pk::InputError& e, const std::string& text) {
  int lines = 0, fields = 0;
  Shape(text, &lines, &fields);
  if (e.file() != "mutated.csv") return "the error names file '" + e.file() + "'";
  if (e.line() < 0 || e.line() > lines) return "line " + std::to_string(e.line()) + " does not exist";
  if (e.column() < 0 || e.column() > fields) return "column " + std::to_string(e.column()) + " does not exist";
  if (e.message().empty()) return "the message is empty";
  if (std::string(e.what()).rfind("mutated.csv", 0) != 0) return "the text does not start with the file name";
  return "";
}

// What is wrong with one subject's simulation and starting values, or "".
std::string SubjectProblem(const pk::Model& model, const pk::Model& sim_model, const pk::ParameterValues& values,
                           const pk::Dataset& data, int s, const std::string& text, bool* simulated) {
  try {
    const pk::SubjectSimulation sim = pk::SimulateSubject(sim_model, data, s, values);
    if (!sim.ok) return sim.message.empty() ? "a failed simulation without a reason" : "";
    *simulated = true;
    for (const pk::SimulatedRecord& row : sim.rows) {
      if (!std::isfinite(row.cp)) return "a prediction is not finite at TIME " + std::to_string(row.time);
    }
    // Starting values from the data read the same records (ADDL included).
    const pk::InitialEstimate est = pk::EstimateInitialValues(model, data, s);
    if (!est.ok) return est.message.empty() ? "no starting values and no reason" : "";
    for (const auto& kv : est.values) {
      if (!std::isfinite(kv.second)) return "starting value " + kv.first + " is not finite";
    }
  } catch (const pk::InputError& e) {
    const std::string why = LocationProblem(e, text);
    return why.empty() ? "" : why + " (" + e.what() + ")";
  } catch (const std::exception& e) {
    return std::string("escaped with ") + e.what();
  }
  return "";
}

// Returns how many variants parsed; counts how many simulations ran to the end.
// Problems are collected and checked once per variant, so that the check
// itself stays cheap (the sanitizer build runs this too).
int Exercise(const std::string& seed_text, int variants, unsigned seed, int* simulated) {
  std::mt19937 rng(seed);
  const auto model = pk::MakeModel("1cmt_oral");
  const pk::ParameterValues values = {{"KA", 1.2}, {"CL", 3}, {"V", 30}};
  // Every tenth accepted variant is simulated through the ODE propagator, with a nonlinear model.
  const auto ode_model = pk::MakeModel("1cmt_oral_mm");
  const pk::ParameterValues ode_values = {{"KA", 1.2}, {"VMAX", 30}, {"KM", 2}, {"V", 30}};
  int parsed = 0, failures = 0;
  for (int v = 0; v < variants; ++v) {
    const std::string text = Mutate(seed_text, &rng);
    pk::Dataset data;
    std::string problem;
    try {
      data = pk::ParseDataset(text, "mutated.csv");
    } catch (const pk::InputError& e) {
      problem = LocationProblem(e, text);
      if (!problem.empty()) problem += std::string(" (") + e.what() + ")";
    } catch (const std::exception& e) {
      problem = std::string("escaped the reader with ") + e.what();
    }
    if (problem.empty() && !data.subjects.empty()) {
      ++parsed;
      const bool ode = parsed % 10 == 0;
      for (size_t s = 0; s < data.subjects.size() && problem.empty(); ++s) {
        bool ran = false;
        problem = SubjectProblem(*model, ode ? *ode_model : *model, ode ? ode_values : values, data,
                                 static_cast<int>(s), text, &ran);
        if (!problem.empty()) problem = "subject " + std::to_string(s) + (ode ? " (ODE): " : ": ") + problem;
        if (ran) ++*simulated;
      }
    }
    if (!problem.empty() && ++failures <= 5) FAIL_CHECK("variant " << v << ": " << problem << "\n" << text);
  }
  CHECK(failures == 0);
  return parsed;
}

}  // namespace

// The sanitizer build runs the library about 40 times slower: it checks a
// tenth of the variants (the same first ones), the optimised build all of them.
// (It tested __SANITIZE_ADDRESS__, which clang does not define: since the
// sanitizer build moved to clang, it had run every variant.)
constexpr int kShare = pk_test::kSanitized ? 10 : 1;

TEST_CASE("mutated datasets are accepted or rejected with a location, never crash", "[reader][mutation]") {
  SECTION("every NONMEM item") {
    int simulated = 0;
    const int parsed = Exercise(kEveryItem, 12000 / kShare, 20261122u, &simulated);
    // The mutations must leave enough valid data to exercise the simulation too.
    CHECK(parsed > 1200 / kShare);
    CHECK(simulated > 1200 / kShare);
  }
  SECTION("repeated doses") {
    int simulated = 0;
    const int parsed = Exercise(kRepeatedDoses, 6000 / kShare, 11u, &simulated);
    CHECK(parsed > 600 / kShare);
    CHECK(simulated > 600 / kShare);
  }
  SECTION("theophylline") {
    int simulated = 0;
    const int parsed = Exercise(ReadText(std::string(PK_SOURCE_DIR) + "/datasets/theophylline.csv"), 2000 / kShare, 7u, &simulated);
    CHECK(parsed > 150 / kShare);
    CHECK(simulated > 150 / kShare);
  }
}
