// Helpers shared by the tests.
#ifndef PK_TESTS_TEST_UTIL_H_
#define PK_TESTS_TEST_UTIL_H_

#include <algorithm>
#include <cmath>
#include <memory>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "pk/catalogue.h"
#include "pk/dataset.h"
#include "pk/simulate.h"

namespace pk_test {

/// Simulates CSV text with a catalogue model; requires success.
inline pk::SubjectSimulation SimulateText(const std::string& model, const std::string& csv,
                                          const pk::ParameterValues& values, int subject = 0) {
  const pk::Dataset data = pk::ParseDataset(csv, "test.csv");
  return pk::SimulateSubject(*pk::MakeModel(model), data, subject, values);
}

/// Relative difference with a floor on the scale.
inline double RelDiff(double a, double b, double floor = 1e-12) {
  return std::fabs(a - b) / std::max({std::fabs(a), std::fabs(b), floor});
}

/// An event scenario for the gradient tests: dose rows, and the dose modifiers
/// to estimate with their values.
struct Scenario {
  const char* name;
  const char* doses;  // CSV rows (ID,TIME,AMT,RATE,II,ADDL,SS,EVID,DV), one per line
  std::vector<std::string> extra_free;
  std::vector<double> extra_values;
};

/// The scenario's dose rows merged by time with nine samples (doses first at equal times).
inline std::shared_ptr<pk::Dataset> ScenarioData(const Scenario& sc) {
  std::vector<std::pair<double, std::string>> rows;
  std::istringstream doses(sc.doses);
  for (std::string line; std::getline(doses, line);) {
    rows.push_back({std::stod(line.substr(line.find(',') + 1)), line});
  }
  const double times[] = {0.25, 0.9, 1.7, 3.1, 5.3, 7.9, 11.2, 15.5, 23.6};
  for (int k = 0; k < 9; ++k) {
    std::ostringstream row;
    row << "1," << times[k] << ",0,0,0,0,0,0," << 0.5 + 0.4 * k * (k % 3);
    rows.push_back({times[k], row.str()});
  }
  std::stable_sort(rows.begin(), rows.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  std::ostringstream csv;
  csv << "ID,TIME,AMT,RATE,II,ADDL,SS,EVID,DV\n";
  for (const auto& r : rows) csv << r.second << "\n";
  return std::make_shared<pk::Dataset>(pk::ParseDataset(csv.str(), sc.name));
}

}  // namespace pk_test

#endif  // PK_TESTS_TEST_UTIL_H_
