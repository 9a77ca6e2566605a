// Helpers shared by the tests.
#ifndef PK_TESTS_TEST_UTIL_H_
#define PK_TESTS_TEST_UTIL_H_

#include <cmath>
#include <string>
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

}  // namespace pk_test

#endif  // PK_TESTS_TEST_UTIL_H_
