// The ODE propagator and its routes: against the exact propagator on every
// linear model, against closed forms, and (a) forward sensitivities, (b) the
// adjoint and central finite differences against each other on every
// catalogue model × event type.
#include <algorithm>
#include <cmath>
#include <sstream>

#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/objective.h"
#include "pk/ode_model.h"
#include "pk/simulate.h"

namespace {

struct Scenario {
  const char* name;
  const char* doses;  // CSV rows (ID,TIME,AMT,RATE,II,ADDL,SS,EVID,DV) before the samples
  std::vector<std::string> extra_free;
  std::vector<double> extra_values;
};

const std::vector<Scenario>& Scenarios() {
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

// The scenario's dose rows merged by time with nine samples (doses first at equal times).
std::shared_ptr<pk::Dataset> MakeData(const Scenario& sc) {
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

pk::ObjectiveOptions OdeOptions(pk::ErrorModel e = pk::ErrorModel::kLeastSquares) {
  pk::ObjectiveOptions o;
  o.error_model = e;
  o.propagator = pk::Propagator::kOde;
  o.ode.relative_tolerance = 1e-10;
  o.ode.absolute_tolerance = 1e-12;
  o.fd_relative_step = 1e-4;
  return o;
}

// Values away from the defaults, with the scenario's modifiers, all free.
void Setup(const pk::Objective& obj, const Scenario& sc, Eigen::VectorXd* values, std::vector<int>* free) {
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

// Fourth-order central differences of V, step 1e-3 relative: through an
// adaptive solver at rtol 1e-10 the second-order stencil's noise (≈ rtol/step)
// would be of the size of the tolerance under test.
Eigen::VectorXd CentralDifferences(const pk::Objective& obj, const Eigen::VectorXd& values,
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

double RelErr(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return (a - b).cwiseAbs().maxCoeff() / std::max(b.cwiseAbs().maxCoeff(), 1e-300);
}

}  // namespace

TEST_CASE("ODE propagator agrees with the exact propagator on every linear model", "[ode]") {
  const auto name = GENERATE(as<std::string>{}, "1cmt_iv", "1cmt_oral", "2cmt_iv", "2cmt_oral", "3cmt_iv",
                             "3cmt_oral", "tf2", "1cmt_oral_transit");
  const auto model = pk::MakeModel(name);
  for (const Scenario& sc : Scenarios()) {
    INFO(name << " / " << sc.name);
    const auto data = MakeData(sc);
    pk::ObjectiveOptions exact_options;
    exact_options.propagator = pk::Propagator::kExact;
    const pk::Objective exact(model, data, 0, exact_options);
    const pk::Objective ode(model, data, 0, OdeOptions());
    Eigen::VectorXd values;
    std::vector<int> free;
    Setup(exact, sc, &values, &free);
    using Need = pk::Objective::Need;
    const auto e = exact.Evaluate(values, free, Need::kJacobian, pk::GradientRoute::kForward);
    const auto o = ode.Evaluate(values, free, Need::kJacobian, pk::GradientRoute::kForward);
    REQUIRE(e.ok);
    REQUIRE(o.ok);
    CHECK(std::string(o.propagator) == "ode");
    // Element-wise, each prediction to 1e-8 of the largest.
    CHECK(RelErr(o.predictions, e.predictions) < 1e-8);
    CHECK((o.jacobian - e.jacobian).cwiseAbs().maxCoeff() < 1e-7 * e.jacobian.cwiseAbs().maxCoeff());
  }
}

TEST_CASE("ODE routes agree: forward sensitivities, adjoint and finite differences", "[ode][gradient]") {
  const auto name = GENERATE(as<std::string>{}, "1cmt_iv_mm", "1cmt_oral_mm", "2cmt_iv_mm", "1cmt_iv_emax",
                             "2cmt_oral", "1cmt_oral_transit");
  const auto model = pk::MakeModel(name);
  for (const Scenario& sc : Scenarios()) {
    const auto error_model = GENERATE(pk::ErrorModel::kLeastSquares, pk::ErrorModel::kCombined);
    INFO(name << " / " << sc.name << " / " << pk::ToString(error_model));
    const pk::Objective obj(model, MakeData(sc), 0, OdeOptions(error_model));
    Eigen::VectorXd values;
    std::vector<int> free;
    Setup(obj, sc, &values, &free);
    if (error_model != pk::ErrorModel::kLeastSquares) {
      free.push_back(obj.ParameterIndex("SIGMA_ADD"));
      free.push_back(obj.ParameterIndex("SIGMA_PROP"));
    }
    using Need = pk::Objective::Need;
    const auto fwd = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
    const auto adj = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
    REQUIRE(fwd.ok);
    INFO(adj.message);
    REQUIRE(adj.ok);
    // The loss does not touch the routes, so differences on least squares suffice.
    const Eigen::VectorXd fd = error_model == pk::ErrorModel::kLeastSquares ? CentralDifferences(obj, values, free)
                                                                           : Eigen::VectorXd(fwd.gradient);
    // Separate integrations (with and without sensitivity error control) agree to the tolerance.
    CHECK(std::fabs(fwd.value - adj.value) <= 1e-8 * std::fabs(fwd.value));
    const double scale = fwd.gradient.cwiseAbs().maxCoeff();
    INFO("forward " << fwd.gradient.transpose() << "\nadjoint " << adj.gradient.transpose() << "\nfd      "
                    << fd.transpose());
    CHECK((fwd.gradient - adj.gradient).cwiseAbs().maxCoeff() <= 1e-7 * scale);
    CHECK((fwd.gradient - fd).cwiseAbs().maxCoeff() <= 1e-5 * scale);
  }
}
