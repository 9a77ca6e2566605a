// Helpers shared by the tests.
#ifndef PK_TESTS_TEST_UTIL_H_
#define PK_TESTS_TEST_UTIL_H_

#include <algorithm>
#include <clocale>
#include <cmath>
#include <memory>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/dataset.h"
#include "pk/objective.h"
#include "pk/simulate.h"

namespace pk_test {

/// Sets the C locale (LC_ALL) to `name` when it is not null, and back to "C" at scope's end, also when
/// a check fails and the test case ends early.
class LocaleGuard {
 public:
  explicit LocaleGuard(const char* name) : set_(name != nullptr && std::setlocale(LC_ALL, name) != nullptr) {}
  ~LocaleGuard() {
    if (set_) std::setlocale(LC_ALL, "C");
  }
  LocaleGuard(const LocaleGuard&) = delete;
  LocaleGuard& operator=(const LocaleGuard&) = delete;
  bool set() const { return set_; }

 private:
  bool set_;
};

/// Simulates CSV text with a catalogue model; requires success.
inline pk::SubjectSimulation SimulateText(const std::string& model, const std::string& csv,
                                          const pk::ParameterValues& values, int subject = 0) {
  const pk::Dataset data = pk::ParseDataset(csv, "test.csv");
  return pk::SimulateSubject(*pk::MakeModel(model), data, subject, values);
}

#ifdef PK_SANITIZED
constexpr bool kSanitized = true;
#else
constexpr bool kSanitized = false;
#endif

/// Whether a study over many models runs `name`: every one optimised; under the sanitizers, whose
/// builds run the studies ten times slower, only those in `subset` (the code is the same for all).
inline bool RunsUnderThisBuild(const std::string& name, const std::vector<std::string>& subset) {
  return !kSanitized || std::find(subset.begin(), subset.end(), name) != subset.end();
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

/// Every event type on the ODE routes (doses, infusions, ADDL, resets, steady states, lag, F, R, D,
/// initial states), for tests/test_ode.cc and tests/test_rk.cc.
inline const std::vector<Scenario>& OdeScenarios() {
  static const std::vector<Scenario> s = {
      {"bolus", "1,0,100,0,0,0,0,1,.\n", {}, {}},
      {"infusion", "1,0,100,40,0,0,0,1,.\n", {}, {}},
      {"bolus then infusion", "1,0,60,0,0,0,0,1,.\n1,4,80,20,0,0,0,1,.\n", {}, {}},
      {"addl", "1,0,100,0,6,3,0,1,.\n", {}, {}},
      {"reset", "1,0,100,0,0,0,0,1,.\n1,4,0,0,0,0,0,3,.\n1,4.5,70,0,0,0,0,1,.\n", {}, {}},
      {"ss1 bolus", "1,0,100,0,12,0,1,1,.\n", {}, {}},
      {"ss2 on a dose", "1,0,50,0,0,0,0,1,.\n1,0.2,100,0,12,0,2,1,.\n", {}, {}},
      {"ss1 infusion longer than II", "1,0,100,5,8,0,1,1,.\n", {}, {}},
      {"ss constant infusion", "1,0,0,10,0,0,1,1,.\n", {}, {}},
      {"lag", "1,0,100,0,6,2,0,1,.\n", {"ALAG1"}, {0.7}},
      {"F bolus", "1,0,100,0,0,0,0,1,.\n", {"F1"}, {0.8}},
      {"R", "1,0,100,-1,0,0,0,1,.\n", {"R1"}, {35}},
      {"D and F", "1,0,100,-2,0,0,0,1,.\n", {"D1", "F1"}, {2.2, 0.9}},
      {"ss1 with lag", "1,0,100,0,12,0,1,1,.\n", {"ALAG1"}, {1.3}},
      {"initial state", "1,0,100,0,6,2,0,1,.\n", {"X0_1"}, {30.0}},
  };
  return s;
}

/// Values away from `obj`'s defaults (model parameter i scaled by 1 + 0.05·i), with the scenario's
/// modifiers at their values; every model parameter and modifier free.
inline void ScenarioValues(const pk::Objective& obj, const Scenario& sc, Eigen::VectorXd* values,
                           std::vector<int>* free) {
  *values = obj.DefaultValues();
  free->clear();
  for (int i = 0; i < obj.model().num_parameters(); ++i) {
    (*values)(i) *= 1.0 + 0.05 * i;
    free->push_back(i);
  }
  for (size_t e = 0; e < sc.extra_free.size(); ++e) {
    const int i = obj.ParameterIndex(sc.extra_free[e]);
    REQUIRE(i >= 0);
    (*values)(i) = sc.extra_values[e];
    free->push_back(i);
  }
}

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

/// With the exponential error, whether the scenario predicts 0 at a sample
/// (log ŷ = −∞): only "lag" may, a sample before its lagged first dose, and the
/// evaluation must then fail saying so. False for the other error models.
inline bool NoLogOfZero(const pk::Objective& obj, const Eigen::VectorXd& values, const std::vector<int>& free,
                        const Scenario& sc) {
  if (!obj.options().error_model->log_transformed()) return false;
  const auto value = obj.Evaluate(values, free, pk::Objective::Need::kValue);
  if (value.ok) return false;
  CHECK_THAT(value.message, Catch::Contains("needs a positive prediction"));
  CHECK(std::string(sc.name) == "lag");
  return true;
}

/// Fourth-order central differences of V over `free`, step 1e-3 relative (floor
/// 1e-3). Through an adaptive ODE solver the second-order stencil's noise
/// (≈ rtol/step) would be of the size of the tolerances under test, so the ODE
/// tests difference an objective solved at 1e-12 to check routes run at 1e-10:
/// the reference must be more accurate than what it checks. (At rtol 1e-10 the
/// step sequence, and with it V's error, jumps as θ moves; the stencil's noise
/// reached 1.05e-5 of the gradient on one of 180 cases, while at 1e-12 the
/// differences agree with the forward route to 1e-8.)
inline Eigen::VectorXd CentralDifferences(const pk::Objective& obj, const Eigen::VectorXd& values,
                                          const std::vector<int>& free) {
  Eigen::VectorXd g(free.size());
  for (size_t k = 0; k < free.size(); ++k) {
    const int i = free[k];
    const double h = 1e-3 * std::max(std::fabs(values(i)), 1e-3);
    double v[4];
    const double offsets[4] = {-2, -1, 1, 2};
    for (int j = 0; j < 4; ++j) {
      Eigen::VectorXd x = values;
      x(i) += offsets[j] * h;
      const auto e = obj.Evaluate(x, free, pk::Objective::Need::kValue);
      REQUIRE(e.ok);
      v[j] = e.value;
    }
    g(static_cast<Eigen::Index>(k)) = (v[0] - 8 * v[1] + 8 * v[2] - v[3]) / (12 * h);
  }
  return g;
}

}  // namespace pk_test

#endif  // PK_TESTS_TEST_UTIL_H_
