// The ODE propagator and its routes: against the exact propagator on every
// linear model, against closed forms, and (a) forward sensitivities, (b) the
// adjoint and central finite differences against each other on every
// catalogue model × event type.
#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>
#include <thread>

#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/error.h"
#include "pk/fit.h"
#include "pk/fit_subjects.h"
#include "pk/initial_estimates.h"
#include "pk/objective.h"
#include "pk/ode_model.h"
#include "pk/simulate.h"
#include "test_util.h"

namespace {

using pk_test::Scenario;

const std::vector<Scenario>& Scenarios() { return pk_test::OdeScenarios(); }

pk::ObjectiveOptions OdeOptions(std::shared_ptr<const pk::ResidualErrorModel> e = pk::MakeResidualError("least-squares")) {
  pk::ObjectiveOptions o;
  o.error_model = e;
  o.propagator = pk::Propagator::kOde;
  o.ode.relative_tolerance = 1e-10;
  o.ode.absolute_tolerance = 1e-12;
  o.fd_relative_step = 1e-4;
  return o;
}

// The same, solved to 1e-12: the values behind the finite-difference reference.
pk::ObjectiveOptions ReferenceOptions(std::shared_ptr<const pk::ResidualErrorModel> e = pk::MakeResidualError("least-squares")) {
  pk::ObjectiveOptions o = OdeOptions(e);
  o.ode.relative_tolerance = 1e-12;
  o.ode.absolute_tolerance = 1e-14;
  return o;
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
    const auto data = pk_test::ScenarioData(sc);
    pk::ObjectiveOptions exact_options;
    exact_options.propagator = pk::Propagator::kExact;
    const pk::Objective exact(model, data, 0, exact_options);
    const pk::Objective ode(model, data, 0, OdeOptions());
    Eigen::VectorXd values;
    std::vector<int> free;
    pk_test::ScenarioValues(exact, sc, &values, &free);
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
  if (!pk_test::RunsUnderThisBuild(name, {"1cmt_oral_mm", "2cmt_oral"})) return;
  const auto model = pk::MakeModel(name);
  for (const Scenario& sc : Scenarios()) {
    const auto error_model =
        GENERATE(pk::MakeResidualError("least-squares"), pk::MakeResidualError("combined"), pk::MakeResidualError("exponential"));
    INFO(name << " / " << sc.name << " / " << error_model->name());
    const pk::Objective obj(model, pk_test::ScenarioData(sc), 0, OdeOptions(error_model));
    Eigen::VectorXd values;
    std::vector<int> free;
    pk_test::ScenarioValues(obj, sc, &values, &free);
    for (const char* sigma : {"SIGMA_ADD", "SIGMA_PROP", "SIGMA_LOG"}) {
      if (obj.ParameterIndex(sigma) >= 0) free.push_back(obj.ParameterIndex(sigma));
    }
    using Need = pk::Objective::Need;
    if (pk_test::NoLogOfZero(obj, values, free, sc)) continue;
    const auto fwd = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
    const auto adj = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
    REQUIRE(fwd.ok);
    INFO(adj.message);
    REQUIRE(adj.ok);
    // The loss does not touch the routes, so differences on least squares suffice.
    const pk::Objective reference(model, pk_test::ScenarioData(sc), 0, ReferenceOptions(error_model));
    const Eigen::VectorXd fd = std::string(error_model->name()) == "least-squares" ? pk_test::CentralDifferences(reference, values, free)
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

// A sample is not a discontinuity: the plain solve and the forward
// sensitivities continue through it, so twelve samples cost about the steps
// of one at the end: 0.99-1.10 times as many (restarting at each sample,
// CVODES took 1.31-2.33 times as many, and this test failed).
TEST_CASE("ODE solves continue through samples instead of restarting", "[ode]") {
  const auto name = GENERATE(as<std::string>{}, "1cmt_iv_mm", "1cmt_oral_mm", "2cmt_iv_mm");
  const auto model = pk::MakeModel(name);
  const double times[] = {0.25, 0.5, 1, 1.5, 2, 3, 4, 6, 8, 12, 16, 24};
  auto data_with = [](const double* t, int count) {
    std::ostringstream csv;
    csv << "ID,TIME,AMT,EVID,CMT,DV\n1,0,100,1,1,.\n";
    for (int k = 0; k < count; ++k) csv << "1," << t[k] << ",0,0,0,1\n";
    return std::make_shared<pk::Dataset>(pk::ParseDataset(csv.str(), "samples.csv"));
  };
  const pk::Objective many(model, data_with(times, 12), 0, OdeOptions());
  const pk::Objective last(model, data_with(times + 11, 1), 0, OdeOptions());
  std::vector<int> free;
  for (int i = 0; i < many.model().num_parameters(); ++i) free.push_back(i);
  using Need = pk::Objective::Need;
  for (const Need need : {Need::kValue, Need::kJacobian}) {
    const auto a = many.Evaluate(many.DefaultValues(), free, need, pk::GradientRoute::kForward);
    const auto b = last.Evaluate(last.DefaultValues(), free, need, pk::GradientRoute::kForward);
    REQUIRE(a.ok);
    REQUIRE(b.ok);
    INFO(name << (need == Need::kValue ? " value" : " jacobian") << ": 12 samples " << a.ode_statistics.steps
              << " steps, 1 sample " << b.ode_statistics.steps);
    CHECK(a.ode_statistics.steps <= 1.3 * b.ode_statistics.steps);
    // The same trajectory: the last prediction agrees to the tolerance.
    CHECK(a.predictions(11) == Approx(b.predictions(0)).epsilon(1e-8));
  }
}

// Samples long after the drug is gone: each one starts a transient of λ that
// the adjoint's error control need not follow, because an error of λ where x
// (and so x_p) is negligible cannot reach the gradient. The gradient must stay
// as accurate as where the drug is present, and the backward solve must not
// take more steps than the forward one (it took 1.0-2.2 times as many when λ
// was followed to rtol of its own size after every sample; now 0.64-0.86).
TEST_CASE("ODE adjoint: samples after the drug is gone keep the gradient's accuracy and cost few steps",
          "[ode][gradient]") {
  const auto name = GENERATE(as<std::string>{}, "1cmt_iv_mm", "1cmt_oral_mm", "2cmt_iv_mm", "1cmt_iv_emax",
                             "1cmt_oral_transit", "2cmt_oral");
  const auto model = pk::MakeModel(name);
  const double times[] = {0.25, 0.9, 1.7, 3.1, 48, 96, 168, 240, 336};
  std::ostringstream csv;
  csv << "ID,TIME,AMT,EVID,CMT,DV\n1,0,100,1,1,.\n";
  for (int k = 0; k < 9; ++k) csv << "1," << times[k] << ",0,0,0," << 0.5 + 0.4 * k * (k % 3) << "\n";
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(csv.str(), "tail.csv"));
  const pk::Objective obj(model, data, 0, OdeOptions());
  Eigen::VectorXd values;
  std::vector<int> free;
  pk_test::ScenarioValues(obj, pk_test::Scenario{"tail", "", {}, {}}, &values, &free);
  using Need = pk::Objective::Need;
  const auto fwd = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
  const auto adj = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  REQUIRE(fwd.ok);
  REQUIRE(adj.ok);
  const Eigen::VectorXd fd = pk_test::CentralDifferences(pk::Objective(model, data, 0, ReferenceOptions()), values, free);
  const double scale = fwd.gradient.cwiseAbs().maxCoeff();
  INFO(name << "\nforward " << fwd.gradient.transpose() << "\nadjoint " << adj.gradient.transpose() << "\nfd      "
            << fd.transpose());
  CHECK((fwd.gradient - adj.gradient).cwiseAbs().maxCoeff() <= 1e-7 * scale);
  CHECK((fwd.gradient - fd).cwiseAbs().maxCoeff() <= 1e-5 * scale);
  if (model->is_linear()) {
    pk::ObjectiveOptions exact_options;
    exact_options.propagator = pk::Propagator::kExact;
    const pk::Objective exact(model, data, 0, exact_options);
    const auto e = exact.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
    REQUIRE(e.ok);
    CHECK((e.gradient - adj.gradient).cwiseAbs().maxCoeff() <= 1e-7 * e.gradient.cwiseAbs().maxCoeff());
  }
  // Where the last three samples see less than 1e-6 of the peak, the drug is
  // gone (with these values, not in the two-compartment models' slow phase).
  const double peak = fwd.predictions.cwiseAbs().maxCoeff();
  if (fwd.predictions.tail(3).cwiseAbs().maxCoeff() < 1e-6 * peak) {
    INFO("forward steps " << adj.ode_statistics.steps << ", backward steps " << adj.ode_statistics.backward_steps);
    CHECK(adj.ode_statistics.backward_steps <= adj.ode_statistics.steps);
  }
}

namespace {

// A right-hand side that turns non-finite once x < 50.
struct Blowup {
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    using std::sqrt;
    dxdt[0] = -p[0] * sqrt(x[0] - T(50.0));
  }
  template <typename T>
  T Output(int, const T* x, const T*) const { return x[0]; }
};

pk::SimulationOptions TightOde() {
  pk::SimulationOptions o;
  o.propagator = pk::Propagator::kOde;
  o.ode.relative_tolerance = 1e-12;
  o.ode.absolute_tolerance = 1e-14;
  return o;
}

std::shared_ptr<pk::Dataset> Parse(const std::string& csv, const char* name = "test") {
  return std::make_shared<pk::Dataset>(pk::ParseDataset(csv, name));
}

// Noise-free observations of `model` at `values` on the records of `csv` (DV replaced).
std::shared_ptr<pk::Dataset> Synthetic(const pk::Model& model, const std::string& csv, const pk::ParameterValues& v) {
  auto data = Parse(csv);
  const pk::SubjectSimulation sim = pk::SimulateSubject(model, *data, 0, v, TightOde());
  REQUIRE(sim.ok);
  for (const pk::SimulatedRecord& row : sim.rows) {
    pk::Record& r = data->subjects[0].records[row.record];
    if (r.evid == pk::Evid::kObservation) {
      r.dv = row.pred;
      r.dv_missing = false;
      r.mdv = 0;
    }
  }
  return data;
}

}  // namespace

TEST_CASE("Michaelis-Menten IV bolus against its implicit closed form", "[ode][closed-form]") {
  // Km ln(C0/C) + (C0 − C) = (Vmax/V) t
  const auto model = pk::MakeModel("1cmt_iv_mm");
  const double vmax = 12, km = 1.5, v = 25, dose = 150, c0 = dose / v;
  auto data = Parse("ID,TIME,AMT,EVID\n1,0,150,1\n1,0.5,0,2\n1,2,0,2\n1,5,0,2\n1,9,0,2\n1,14,0,2\n1,20,0,2\n");
  const auto sim = pk::SimulateSubject(*model, *data, 0, {{"VMAX", vmax}, {"KM", km}, {"V", v}}, TightOde());
  REQUIRE(sim.ok);
  REQUIRE(sim.rows.size() == 6);
  for (const auto& row : sim.rows) {
    INFO("t = " << row.time << ", C = " << row.cp);
    const double lhs = km * std::log(c0 / row.cp) + (c0 - row.cp);
    CHECK(lhs == Approx(vmax / v * row.time).epsilon(1e-10));
  }
  // C dt = −(V/Vmax)(Km + C) dC, so AUC(t) = (V/Vmax)[Km (C0 − C) + (C0² − C²)/2].
  for (const auto& row : sim.rows) {
    const double c = row.cp;
    CHECK(row.auc == Approx(v / vmax * (km * (c0 - c) + 0.5 * (c0 * c0 - c * c))).epsilon(1e-9));
  }
}

TEST_CASE("nonlinear steady states: Newton's fixed point against long regimens and closed forms", "[ode][ss]") {
  const auto model = pk::MakeModel("1cmt_iv_mm");
  const pk::ParameterValues p = {{"VMAX", 20}, {"KM", 2}, {"V", 30}};
  SECTION("SS=1 bolus equals the 80th dose of a regimen") {
    auto ss = Parse("ID,TIME,AMT,II,ADDL,SS,EVID\n1,0,100,12,0,1,1\n1,3,0,0,0,0,2\n1,11,0,0,0,0,2\n");
    auto train = Parse("ID,TIME,AMT,II,ADDL,SS,EVID\n1,0,100,12,79,0,1\n1,951,0,0,0,0,2\n1,959,0,0,0,0,2\n");
    const auto a = pk::SimulateSubject(*model, *ss, 0, p, TightOde());
    const auto b = pk::SimulateSubject(*model, *train, 0, p, TightOde());
    REQUIRE(a.ok);
    REQUIRE(b.ok);
    for (int k = 0; k < 2; ++k) CHECK(a.rows[k].cp == Approx(b.rows[k].cp).epsilon(1e-8));
  }
  SECTION("SS=1 infusion longer than II equals a long regimen") {
    auto ss = Parse("ID,TIME,AMT,RATE,II,ADDL,SS,EVID\n1,0,100,6,8,0,1,1\n1,5,0,0,0,0,0,2\n");
    auto train = Parse("ID,TIME,AMT,RATE,II,ADDL,SS,EVID\n1,0,100,6,8,119,0,1\n1,957,0,0,0,0,0,2\n");
    const auto a = pk::SimulateSubject(*model, *ss, 0, p, TightOde());
    const auto b = pk::SimulateSubject(*model, *train, 0, p, TightOde());
    REQUIRE(a.ok);
    REQUIRE(b.ok);
    CHECK(a.rows[0].cp == Approx(b.rows[0].cp).epsilon(1e-8));
  }
  SECTION("constant infusion: Vmax C/(Km + C) = R at the record, then it stops") {
    auto ss = Parse("ID,TIME,AMT,RATE,SS,EVID\n1,0,0,10,1,1\n1,0,0,0,0,2\n1,4,0,0,0,2\n");
    const auto a = pk::SimulateSubject(*model, *ss, 0, p, TightOde());
    REQUIRE(a.ok);
    CHECK(a.rows[0].cp == Approx(10.0 * 2 / (20 - 10)).epsilon(1e-10));
    // Free Michaelis–Menten elimination from C₀ = 2: V dC/dt = −VMAX C/(KM + C), so
    // KM log(C₀/C) + (C₀ − C) = (VMAX/V) t. The concentration at t = 4 satisfies it.
    const double c = a.rows[1].cp;
    CHECK(2 * std::log(2.0 / c) + (2.0 - c) == Approx(20.0 / 30 * 4).epsilon(1e-8));
  }
  SECTION("no steady state when the rate exceeds the capacity") {
    auto ss = Parse("ID,TIME,AMT,RATE,SS,EVID\n1,0,0,25,1,1\n1,4,0,0,0,2\n");
    const auto a = pk::SimulateSubject(*model, *ss, 0, p, TightOde());
    CHECK_FALSE(a.ok);
    CHECK(a.message.find("steady state") != std::string::npos);
  }
  SECTION("periodic doses: none above the capacity, and the message says why") {
    // VMAX = 20 per hour removes at most 240 per 12 h cycle.
    auto above = Parse("ID,TIME,AMT,II,SS,EVID\n1,0,300,12,1,1\n1,4,0,0,0,2\n");
    const auto a = pk::SimulateSubject(*model, *above, 0, p, TightOde());
    CHECK_FALSE(a.ok);
    CHECK_THAT(a.message, Catch::Contains("no periodic steady state") &&
                              Catch::Contains("is the dosing rate, AMT/II, above the elimination capacity?"));
    // An interval below the time axis' resolution: the same reason, not CVODES's complaint about its stop time.
    auto instant = Parse("ID,TIME,AMT,II,SS,EVID\n1,0,10,1e-300,1,1\n1,4,0,0,0,2\n");
    const auto c = pk::SimulateSubject(*model, *instant, 0, p, TightOde());
    CHECK_FALSE(c.ok);
    CHECK_THAT(c.message, Catch::Contains("no periodic steady state") && Catch::Contains("elimination capacity") &&
                              !Catch::Contains("CVode"));
    auto below = Parse("ID,TIME,AMT,II,SS,EVID\n1,0,200,12,1,1\n1,4,0,0,0,2\n");
    const auto b = pk::SimulateSubject(*model, *below, 0, p, TightOde());
    REQUIRE(b.ok);
    CHECK(b.rows[0].cp > 0);
  }
}

TEST_CASE("synthetic Michaelis-Menten data (bolus, then infusion) is recovered to 1e-5", "[ode][fit]") {
  const auto model = pk::MakeModel(GENERATE(as<std::string>{}, "1cmt_iv_mm", "2cmt_iv_mm"));
  // The data from CVODES at 1e-12; the fit through CVODES and through Dormand–Prince, also at 1e-12.
  const pk::Propagator propagator = GENERATE(pk::Propagator::kOde, pk::Propagator::kRungeKutta);
  INFO(model->name() << " through " << pk::ToString(propagator));
  pk::ParameterValues truth = {{"VMAX", 30}, {"KM", 1.8}, {"V", 20}};
  if (model->name() == "2cmt_iv_mm") truth = {{"VMAX", 30}, {"KM", 1.8}, {"V1", 20}, {"Q", 6}, {"V2", 45}};
  std::ostringstream csv;
  csv << "ID,TIME,AMT,RATE,EVID,DV\n1,0,200,0,1,.\n";
  for (double t : {0.25, 0.5, 1.0, 2.0, 3.0, 4.0, 6.0}) csv << "1," << t << ",0,0,0,0\n";
  csv << "1,8,300,50,1,.\n";
  for (double t : {8.5, 9.0, 10.0, 12.0, 13.0, 14.0, 16.0, 20.0, 26.0, 32.0}) csv << "1," << t << ",0,0,0,0\n";
  const auto data = Synthetic(*model, csv.str(), truth);
  pk::ObjectiveOptions oo;
  oo.propagator = propagator;
  oo.ode.relative_tolerance = 1e-12;
  oo.ode.absolute_tolerance = 1e-14;
  const pk::Objective objective(model, data, 0, oo);
  std::vector<pk::ParameterSpec> specs;
  for (const auto& kv : truth) {
    pk::ParameterSpec s;
    s.name = kv.first;
    s.initial = kv.second * 1.3;  // a start well away from the truth
    specs.push_back(s);
  }
  const pk::FitSummary fit = pk::Fit(objective, specs, pk::FitOptions());
  INFO(fit.BriefReport());
  REQUIRE(fit.converged());
  CHECK(fit.propagator == pk::ToString(propagator));
  for (const auto& e : fit.estimates) {
    INFO(e.name);
    CHECK(e.estimate == Approx(truth.at(e.name)).epsilon(1e-5));
  }
}

TEST_CASE("ODE fits on several threads give the single-threaded results bit for bit", "[ode][fit][threads]") {
  // Each thread keeps its own recording of f and its own pool of CVODES adjoint memories; the kernels' shared
  // operation table is made once. Forward sensitivities (LM) and the adjoint (BFGS) both run concurrently,
  // through CVODES and through Dormand–Prince.
  for (const bool adjoint : {false, true}) {
   for (const pk::Propagator propagator : {pk::Propagator::kOde, pk::Propagator::kRungeKutta}) {
    INFO((adjoint ? "BFGS, adjoint" : "LM, forward sensitivities") << " through " << pk::ToString(propagator));
    pk::FitSubjectsRequest req;
    req.objective.propagator = propagator;
    req.model = pk::MakeModel("1cmt_iv_mm");
    req.data = std::make_shared<pk::Dataset>(
        pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets/mm_synthetic.csv"));
    for (const std::string& p : req.model->parameter_names()) req.parameters.push_back({p, NAN});
    req.curve_points = 2;
    if (adjoint) {
      req.fit.optimizer = "bfgs";
      req.objective.gradient = pk::GradientRoute::kAdjoint;
    }
    req.jobs = 1;
    const std::vector<pk::SubjectFit> one = pk::FitSubjects(req);
    req.jobs = 3;
    const std::vector<pk::SubjectFit> three = pk::FitSubjects(req);
    REQUIRE(one.size() == three.size());
    REQUIRE(one.size() >= 6);
    for (size_t s = 0; s < one.size(); ++s) {
      INFO("ID " << one[s].id);
      REQUIRE(one[s].ok);
      REQUIRE(three[s].ok);
      CHECK(one[s].summary.propagator == pk::ToString(propagator));
      CHECK(one[s].summary.gradient.rfind(adjoint ? "adjoint" : "forward", 0) == 0);
      CHECK(one[s].summary.objective == three[s].summary.objective);
      CHECK(one[s].summary.evaluations == three[s].summary.evaluations);
      const Eigen::VectorXd& a = one[s].summary.values;
      const Eigen::VectorXd& b = three[s].summary.values;
      REQUIRE(a.size() == b.size());
      int differ = 0;  // entries not identical (NaN, an unused σ, equals NaN)
      for (Eigen::Index i = 0; i < a.size(); ++i) differ += !(a(i) == b(i) || (std::isnan(a(i)) && std::isnan(b(i))));
      CHECK(differ == 0);
    }
   }
  }
}

TEST_CASE("effect compartment: DVID selects the output, concentration and effect are fitted together",
          "[ode][fit][emax]") {
  const auto model = pk::MakeModel("1cmt_iv_emax");
  const pk::ParameterValues truth = {{"CL", 4},   {"V", 25},    {"KE0", 0.7}, {"E0", 8},
                                     {"EMAX", 60}, {"EC50", 1.2}, {"HILL", 2.2}};
  std::ostringstream csv;
  csv << "ID,TIME,AMT,RATE,EVID,DVID,DV\n1,0,100,50,1,.,.\n";
  for (double t : {0.5, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0}) {
    csv << "1," << t << ",0,0,0,1,0\n1," << t << ",0,0,0,2,0\n";
  }
  const auto data = Synthetic(*model, csv.str(), truth);
  // Output 2 is the effect: E0 + EMAX Ce^h/(EC50^h + Ce^h), well above E0 at 2 h.
  const auto& recs = data->subjects[0].records;
  CHECK(recs[6].dv > 20);
  CHECK(recs[5].dv < 5);
  pk::ObjectiveOptions oo;
  oo.ode.relative_tolerance = 1e-11;
  oo.ode.absolute_tolerance = 1e-13;
  const pk::Objective objective(model, data, 0, oo);
  CHECK(objective.propagator() == pk::Propagator::kRungeKutta);  // auto's choice for a nonlinear model
  CHECK(objective.sample_outputs() == std::vector<int>({1, 2, 1, 2, 1, 2, 1, 2, 1, 2, 1, 2, 1, 2, 1, 2, 1, 2, 1, 2}));
  std::vector<pk::ParameterSpec> specs;
  for (const auto& kv : truth) {
    pk::ParameterSpec s;
    s.name = kv.first;
    s.initial = kv.second * 1.15;
    specs.push_back(s);
  }
  const pk::FitSummary fit = pk::Fit(objective, specs, pk::FitOptions());
  INFO(fit.BriefReport());
  REQUIRE(fit.converged());
  for (const auto& e : fit.estimates) {
    INFO(e.name);
    CHECK(e.estimate == Approx(truth.at(e.name)).epsilon(1e-5));
  }
  // A DVID the model does not have is an input error naming line and column.
  auto bad = Parse("ID,TIME,AMT,EVID,DVID,DV\n1,0,100,1,.,.\n1,1,0,0,3,2\n", "bad.csv");
  try {
    pk::Objective o(model, bad, 0, oo);
    FAIL("expected an InputError");
  } catch (const pk::InputError& e) {
    CHECK(std::string(e.what()).find("bad.csv:3:5") != std::string::npos);
  }
}

TEST_CASE("the exact propagator refuses nonlinear models, solver failures are reported, not thrown",
          "[ode][errors]") {
  const auto model = pk::MakeModel("1cmt_iv_mm");
  auto data = Parse("ID,TIME,AMT,EVID,DV\n1,0,100,1,.\n1,2,0,0,2\n1,50,0,0,1\n");
  pk::ObjectiveOptions exact;
  exact.propagator = pk::Propagator::kExact;
  CHECK_THROWS_AS(pk::Objective(model, data, 0, exact), pk::InputError);

  // An observation's CMT other than the central compartment has no meaning for a nonlinear model, whose
  // outputs are chosen by DVID; it used to be ignored, so a peripheral observation was fitted as CP.
  const auto two = pk::MakeModel("2cmt_iv_mm");
  const auto peripheral = Parse("ID,TIME,AMT,EVID,DV,CMT\n1,0,100,1,.,1\n1,1,0,0,3,1\n1,2,0,0,2,2\n", "obs.csv");
  CHECK_THROWS_WITH(pk::Objective(two, peripheral, 0, pk::ObjectiveOptions()),
                    Catch::Contains("obs.csv:4:6: CMT 2 on an observation") && Catch::Contains("DVID"));
  for (const char* ok : {"ID,TIME,AMT,EVID,DV,CMT\n1,0,100,1,.,1\n1,1,0,0,3,1\n1,2,0,0,2,0\n",
                         "ID,TIME,AMT,EVID,DV,CMT,DVID\n1,0,100,1,.,1,.\n1,2,0,0,2,2,1\n"}) {
    CHECK_NOTHROW(pk::Objective(two, Parse(ok), 0, pk::ObjectiveOptions()));
  }

  pk::ObjectiveOptions few;
  few.propagator = pk::Propagator::kOde;
  few.ode.max_steps = 3;  // far too few: CVODES stops with "too much work"
  const pk::Objective obj(model, data, 0, few);
  for (auto route : {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint, pk::GradientRoute::kFiniteDifference}) {
    const auto ev = obj.Evaluate(obj.DefaultValues(), {0, 1, 2}, pk::Objective::Need::kGradient, route);
    CHECK_FALSE(ev.ok);
    CHECK(ev.message.find("mxstep") != std::string::npos);
  }
  // Dormand–Prince's own limit, on a short non-stiff segment.
  pk::ObjectiveOptions few_rk = few;
  few_rk.propagator = pk::Propagator::kRungeKutta;
  const pk::Objective short_rk(model, Parse("ID,TIME,AMT,EVID,DV\n1,0,100,1,.\n1,2,0,0,2\n"), 0, few_rk);
  for (auto route : {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint}) {
    const auto ev = short_rk.Evaluate(short_rk.DefaultValues(), {0, 1, 2}, pk::Objective::Need::kGradient, route);
    CHECK_FALSE(ev.ok);
    CHECK(ev.message.find("too much work: more than 3 Dormand–Prince steps") != std::string::npos);
  }

  // A right-hand side that turns non-finite ends the evaluation with a reason.
  pk::OdeModelSpec spec;
  spec.name = "blowup";
  spec.compartments = {"CENTRAL"};
  spec.parameters = {{"K", 30}};
  const auto blowup = pk::MakeOdeModel(spec, Blowup());
  pk::ObjectiveOptions cvodes;
  cvodes.propagator = pk::Propagator::kOde;
  const pk::Objective bo(blowup, data, 0, cvodes);
  const auto ev = bo.Evaluate(bo.DefaultValues(), {0}, pk::Objective::Need::kJacobian);
  CHECK_FALSE(ev.ok);
  CHECK(ev.message.find("ODE solver failed") != std::string::npos);
  // Through auto (Dormand–Prince, or CVODES for a stretch it finds stiff): a failure with a reason.
  const pk::Objective bo_auto(blowup, data, 0, pk::ObjectiveOptions());
  const auto ev_auto = bo_auto.Evaluate(bo_auto.DefaultValues(), {0}, pk::Objective::Need::kJacobian);
  CHECK_FALSE(ev_auto.ok);
  CHECK_FALSE(ev_auto.message.empty());
}

// Two models of the same sizes: a right-hand side that differs only in its functor's constant.
struct Scaled {
  double c;
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    dxdt[0] = -p[0] * x[0] * x[1] / (p[1] + x[0]);
    dxdt[1] = c * p[0] * x[0] / (p[1] + x[0]) - p[1] * x[1] * x[1];
  }
  template <typename T>
  T Output(int, const T* x, const T*) const { return x[1]; }
};

// f, f_x and f_θ of the functor by pk::Dual directly, independent of the model's recording.
void DualJacobians(const Scaled& functor, const Eigen::VectorXd& x, const Eigen::VectorXd& theta, Eigen::VectorXd* f,
                   Eigen::MatrixXd* jx, Eigen::MatrixXd* jt) {
  pk::Dual xd[2], td[2], fd[2];
  for (int i = 0; i < 2; ++i) {
    xd[i] = pk::Dual(x(i), 4, i);
    td[i] = pk::Dual(theta(i), 4, 2 + i);
  }
  functor.Rhs(xd, td, fd);
  f->resize(2);
  jx->resize(2, 2);
  jt->resize(2, 2);
  for (int i = 0; i < 2; ++i) {
    (*f)(i) = fd[i].value();
    jx->row(i) = fd[i].derivatives().head(2).transpose();
    jt->row(i) = fd[i].derivatives().tail(2).transpose();
  }
}

TEST_CASE("products with f_x and f_θ reuse a recording of f only at the same model, x and θ", "[ode][gradient]") {
  // The adjoint's backward solve asks for wᵀf_x and wᵀf_θ several times at one (x, θ), and the Jacobians and
  // forward sensitivities for f_x dx + f_θ dθ; the model keeps its last recording of f per thread and sweeps
  // it. Each product must equal pk::Dual's on the functor, whatever was asked before.
  pk::OdeModelSpec spec;
  spec.name = "scaled";
  spec.compartments = {"A", "B"};
  spec.parameters = {{"K", 1.3}, {"KM", 0.7}};
  const auto one = pk::MakeOdeModel(spec, Scaled{1.0});
  const auto two = pk::MakeOdeModel(spec, Scaled{2.5});
  const Eigen::VectorXd x0 = (Eigen::VectorXd(2) << 0.8, 1.9).finished();
  const Eigen::VectorXd t0 = (Eigen::VectorXd(2) << 1.3, 0.7).finished();
  Eigen::VectorXd x1 = x0, t1 = t0;
  x1(1) += 0.25;
  t1(0) *= 1.5;
  const Eigen::VectorXd w0 = (Eigen::VectorXd(2) << 0.3, -1.1).finished();
  const Eigen::VectorXd w1 = (Eigen::VectorXd(2) << 2.0, 0.5).finished();
  struct Ask {
    const pk::OdeModel* model;
    const Eigen::VectorXd *x, *theta, *w;
  };
  // Same point with new weights, then a changed x, a changed θ, the other model at the same point, and back.
  const std::vector<Ask> asks = {{one.get(), &x0, &t0, &w0}, {one.get(), &x0, &t0, &w1}, {one.get(), &x1, &t0, &w1},
                                 {one.get(), &x1, &t1, &w1}, {two.get(), &x1, &t1, &w1}, {two.get(), &x1, &t1, &w0},
                                 {one.get(), &x1, &t1, &w0}, {one.get(), &x0, &t0, &w0}};
  // Three directions (dx; dθ) for the directional products.
  const Eigen::MatrixXd dx = (Eigen::MatrixXd(2, 3) << 1, 0.5, 0, -2, 0, 1).finished();
  const Eigen::MatrixXd dt = (Eigen::MatrixXd(2, 3) << 0, 0.3, 1, 1, -1, 0).finished();
  for (const Ask& a : asks) {
    const Scaled& functor = static_cast<const pk::AutoDiffOdeModel<Scaled>&>(*a.model).functor();
    Eigen::VectorXd f, wfx, wft, fd, fr;
    Eigen::MatrixXd jx, jt, df;
    DualJacobians(functor, *a.x, *a.theta, &fd, &jx, &jt);
    a.model->RhsVectorJacobian(*a.x, *a.theta, *a.w, &f, &wfx, &wft);
    CHECK((f - fd).norm() <= 1e-15 * fd.norm());
    CHECK((wfx - jx.transpose() * *a.w).norm() <= 1e-14 * (jx.norm() * a.w->norm()));
    CHECK((wft - jt.transpose() * *a.w).norm() <= 1e-14 * (jt.norm() * a.w->norm()));
    a.model->RhsDirectional(*a.x, *a.theta, dx, dt, &fr, &df);
    CHECK((fr - fd).norm() <= 1e-15 * fd.norm());
    const Eigen::MatrixXd expected = jx * dx + jt * dt;
    CHECK((df - expected).norm() <= 1e-14 * (jx.norm() * dx.norm() + jt.norm() * dt.norm()));
  }
}

TEST_CASE("gradient auto with the ODE propagator: forward sensitivities for few parameters, the adjoint beyond",
          "[ode][gradient]") {
  // pk::kOdeAdjointThreshold is the crossover pkbench measures (docs/performance.md).
  const auto model = pk::MakeModel("1cmt_iv_emax");  // CL, V, KE0, E0, EMAX, EC50, HILL
  auto data = Parse("ID,TIME,AMT,EVID,DVID,DV\n1,0,100,1,1,.\n1,1,0,0,1,3\n1,2,0,0,2,40\n1,6,0,0,1,1\n");
  const pk::Objective obj(model, data, 0, pk::ObjectiveOptions());
  using Need = pk::Objective::Need;
  for (int m = 1; m <= 7; ++m) {
    std::vector<int> free;
    for (int i = 0; i < m; ++i) free.push_back(i);
    INFO("m = " << m);
    const auto ev = obj.Evaluate(obj.DefaultValues(), free, Need::kGradient, pk::GradientRoute::kAuto);
    REQUIRE(ev.ok);
    CHECK(std::string(ev.route) == (m > pk::kOdeAdjointThreshold ? "adjoint" : "forward"));
    // The Jacobian always comes from forward sensitivities.
    CHECK(std::string(obj.Evaluate(obj.DefaultValues(), free, Need::kJacobian, pk::GradientRoute::kAuto).route) ==
          "forward");
  }
}

TEST_CASE("noisy Michaelis-Menten fits reach R's optimum (optim + deSolve)", "[ode][fit][reference]") {
  // tests/reference/make_mm_reference.R wrote the reference objectives.
  std::ifstream in(std::string(PK_SOURCE_DIR) + "/tests/reference/mm_optim_reference.csv");
  REQUIRE(in.good());
  std::string line;
  std::getline(in, line);
  const auto model = pk::MakeModel("1cmt_iv_mm");
  const auto data = std::make_shared<pk::Dataset>(pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets/mm_synthetic.csv"));
  int subjects = 0;
  while (std::getline(in, line)) {
    std::istringstream row(line);
    double id, objective, vmax, km, v;
    char c;
    row >> id >> c >> objective >> c >> vmax >> c >> km >> c >> v;
    INFO("ID " << id);
    int subject = -1;
    for (size_t i = 0; i < data->subjects.size(); ++i) {
      if (data->subjects[i].id == id) subject = static_cast<int>(i);
    }
    REQUIRE(subject >= 0);
    pk::ObjectiveOptions oo;
    oo.ode.relative_tolerance = 1e-11;
    oo.ode.absolute_tolerance = 1e-13;
    const pk::Objective obj(model, data, subject, oo);
    std::vector<pk::ParameterSpec> specs(3);
    specs[0].name = "VMAX";
    specs[1].name = "KM";
    specs[2].name = "V";
    for (auto& s : specs) s.initial = NAN;  // catalogue defaults, not R's answer
    const pk::FitSummary fit = pk::Fit(obj, specs, pk::FitOptions());
    INFO(fit.BriefReport());
    REQUIRE(fit.converged());
    // No higher than the independent optimum (beyond its own integration error), and the same point.
    CHECK(fit.objective <= objective * (1 + 1e-7));
    CHECK(fit.estimates[0].estimate == Approx(vmax).epsilon(1e-4));
    CHECK(fit.estimates[1].estimate == Approx(km).epsilon(1e-4));
    CHECK(fit.estimates[2].estimate == Approx(v).epsilon(1e-4));
    ++subjects;
  }
  CHECK(subjects == 6);
}

TEST_CASE("continuous records (CONT=1): the seed's dF/dt part, by forward, adjoint and differences",
          "[ode][gradient][continuous]") {
  // Concentrations sampled (jumps of F), the effect monitored continuously.
  const auto model = pk::MakeModel("1cmt_iv_emax");
  const auto scenario = GENERATE(as<std::string>{}, "bolus", "infusion", "addl", "lag");
  std::ostringstream csv;
  csv << "ID,TIME,AMT,RATE,II,ADDL,EVID,DVID,CONT,DV\n";
  if (scenario == std::string("bolus")) csv << "1,0,100,0,0,0,1,.,.,.\n";
  if (scenario == std::string("infusion")) csv << "1,0,100,40,0,0,1,.,.,.\n";
  if (scenario == std::string("addl")) csv << "1,0,100,0,6,2,1,.,.,.\n";
  // An estimated lag moves the dose times inside the continuous record.
  if (scenario == std::string("lag")) csv << "1,0,100,0,6,2,1,.,.,.\n";
  for (int k = 1; k <= 48; ++k) {
    const double t = 0.25 * k;
    if (k % 6 == 0) csv << "1," << t << ",0,0,0,0,0,1,0," << 3.0 * std::exp(-0.1 * t) << "\n";
    csv << "1," << t << ",0,0,0,0,0,2,1," << 10 + 30 * std::sin(0.3 * t) * std::sin(0.3 * t) << "\n";
  }
  INFO(scenario);
  const auto data = Parse(csv.str());
  pk::ObjectiveOptions oo = OdeOptions();
  const pk::Objective obj(model, data, 0, oo);
  CHECK(obj.has_continuous_records());
  CHECK(obj.num_samples() == 8);
  Eigen::VectorXd values;
  std::vector<int> free;
  pk_test::ScenarioValues(obj, Scenarios()[scenario == std::string("lag") ? 9 : 0], &values, &free);
  REQUIRE((scenario != std::string("lag") || obj.parameter_names()[free.back()] == "ALAG1"));
  using Need = pk::Objective::Need;
  const auto fwd = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
  const auto adj = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  REQUIRE(fwd.ok);
  REQUIRE(adj.ok);
  // The discrete part alone is smaller than V: the continuous record contributes.
  const double discrete = 0.5 * (obj.observations() - fwd.predictions).squaredNorm();
  CHECK(fwd.value > discrete + 1);
  const Eigen::VectorXd fd = pk_test::CentralDifferences(obj, values, free);
  const double scale = fwd.gradient.cwiseAbs().maxCoeff();
  INFO("forward " << fwd.gradient.transpose() << "\nadjoint " << adj.gradient.transpose() << "\nfd      "
                  << fd.transpose());
  CHECK(std::fabs(fwd.value - adj.value) <= 1e-8 * fwd.value);
  CHECK((fwd.gradient - adj.gradient).cwiseAbs().maxCoeff() <= 1e-7 * scale);
  CHECK((fwd.gradient - fd).cwiseAbs().maxCoeff() <= 1e-5 * scale);
  // No residual vector: Levenberg-Marquardt's Jacobian is refused with a reason.
  const auto jac = obj.Evaluate(values, free, Need::kJacobian);
  CHECK_FALSE(jac.ok);
  CHECK(jac.message.find("CONT") != std::string::npos);
}

TEST_CASE("continuous records of a linear model: auto integrates them, exact refuses them", "[ode][continuous]") {
  // Φ/Γ has no continuous part of F: under auto a linear model's subject with CONT=1 rows takes
  // Dormand–Prince, whose objective it then is; --propagator exact names the column.
  const auto model = pk::MakeModel("1cmt_iv");
  std::ostringstream csv;
  csv << "ID,TIME,AMT,EVID,CONT,DV\n1,0,100,1,.,.\n";
  for (int k = 1; k <= 24; ++k) csv << "1," << 0.5 * k << ",0,0," << (k % 4 == 0 ? 0 : 1) << "," << 3 * std::exp(-0.08 * k) << "\n";
  const auto data = Parse(csv.str());
  pk::ObjectiveOptions automatic, rk, exact;
  rk.propagator = pk::Propagator::kRungeKutta;
  exact.propagator = pk::Propagator::kExact;
  const pk::Objective a(model, data, 0, automatic), b(model, data, 0, rk);
  const auto ea = a.Evaluate(a.DefaultValues(), {0, 1}, pk::Objective::Need::kGradient);
  const auto eb = b.Evaluate(b.DefaultValues(), {0, 1}, pk::Objective::Need::kGradient);
  REQUIRE((ea.ok && eb.ok));
  CHECK(a.has_continuous_records());
  CHECK(std::string(ea.propagator) == "rk");
  CHECK(ea.value == eb.value);
  CHECK(ea.gradient == eb.gradient);
  try {
    pk::Objective(model, data, 0, exact);
    FAIL("the exact propagator took a continuous record");
  } catch (const pk::InputError& e) {
    CHECK(e.column() == 5);
    CHECK_THAT(e.message(), Catch::Contains("need the ODE propagator"));
  }
  // Without CONT rows the same model stays on Φ/Γ.
  const pk::Objective c(model, Parse("ID,TIME,AMT,EVID,CONT,DV\n1,0,100,1,.,.\n1,1,0,0,0,3\n"), 0, automatic);
  CHECK(std::string(c.Evaluate(c.DefaultValues(), {0, 1}, pk::Objective::Need::kValue).propagator) == "exact");
}

TEST_CASE("a continuous effect record identifies the PD parameters", "[ode][fit][continuous]") {
  const auto model = pk::MakeModel("1cmt_iv_emax");
  const pk::ParameterValues truth = {{"CL", 4},   {"V", 25},    {"KE0", 0.7}, {"E0", 8},
                                     {"EMAX", 60}, {"EC50", 1.2}, {"HILL", 2.2}};
  std::ostringstream csv;
  csv << "ID,TIME,AMT,RATE,EVID,DVID,CONT,DV\n1,0,150,100,1,.,.,.\n";
  for (int k = 1; k <= 160; ++k) {
    const double t = 0.05 * k;
    if (k % 16 == 0) csv << "1," << t << ",0,0,0,1,0,0\n";
    csv << "1," << t << ",0,0,0,2,1,0\n";
  }
  const auto data = Synthetic(*model, csv.str(), truth);
  pk::ObjectiveOptions oo;
  oo.ode.relative_tolerance = 1e-9;
  oo.ode.absolute_tolerance = 1e-11;
  const pk::Objective obj(model, data, 0, oo);
  std::vector<pk::ParameterSpec> specs;
  for (const auto& kv : truth) {
    pk::ParameterSpec s;
    s.name = kv.first;
    s.initial = kv.second * 1.05;
    specs.push_back(s);
  }
  pk::FitOptions fo;
  fo.optimizer = "bfgs";
  const pk::FitSummary fit = pk::Fit(obj, specs, fo);
  INFO(fit.BriefReport());
  // The record's linear interpolation leaves V(truth) > 0; the optimum can only be lower.
  Eigen::VectorXd at_truth = obj.DefaultValues();
  for (const auto& kv : truth) at_truth(obj.ParameterIndex(kv.first)) = kv.second;
  const auto v_truth = obj.Evaluate(at_truth, {}, pk::Objective::Need::kValue);
  REQUIRE(v_truth.ok);
  CHECK(fit.objective <= v_truth.value);
  CHECK(v_truth.value < 1e-3 * fit.initial_objective);
  // y_m interpolates the record linearly every 0.05 h, so the optimum sits
  // within that interpolation error of the truth.
  for (const auto& e : fit.estimates) {
    INFO(e.name);
    CHECK(e.estimate == Approx(truth.at(e.name)).epsilon(2e-3));
  }
}

TEST_CASE("Michaelis-Menten starting values come from the linear counterpart", "[ode][initial]") {
  const auto data = pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets/mm_synthetic.csv");
  for (const char* name : {"1cmt_iv_mm", "2cmt_iv_mm"}) {
    INFO(name);
    const auto model = pk::MakeModel(name);
    const pk::InitialEstimate e = pk::EstimateInitialValues(*model, data, 0);
    INFO(e.message);
    REQUIRE(e.ok);
    REQUIRE(e.values.size() == static_cast<size_t>(model->num_parameters()));
    for (const std::string& p : model->parameter_names()) {
      REQUIRE(e.values.count(p) == 1);
      CHECK(e.values.at(p) > 0);
    }
    // KM is the median concentration; the truth's KM (3.0) is of that order, VMAX/KM ≈ 2 CL.
    CHECK(e.values.at("KM") > 1);
    CHECK(e.values.at("KM") < 20);
  }
  // Subject 1's truth (datasets/mm_synthetic_truth.csv): V = 21.2; the linear fit sees a similar volume.
  const pk::InitialEstimate e = pk::EstimateInitialValues(*pk::MakeModel("1cmt_iv_mm"), data, 0);
  CHECK(e.values.at("V") > 0.5 * 21.2);
  CHECK(e.values.at("V") < 2 * 21.2);
}

TEST_CASE("pksim through CVODES: AUC and amounts equal the exact propagator's", "[ode][simulate]") {
  const auto model = pk::MakeModel("2cmt_oral");
  auto data = Parse("ID,TIME,AMT,RATE,II,ADDL,SS,EVID\n1,0,100,0,12,3,0,1\n1,5,0,0,0,0,0,2\n1,20,0,0,0,0,0,2\n"
                    "1,30,50,25,0,0,0,1\n1,40,0,0,0,0,0,2\n1,60,0,0,0,0,0,2\n");
  const pk::ParameterValues p = {{"KA", 1.3}, {"CL", 4}, {"V2", 25}, {"Q", 6}, {"V3", 60}};
  pk::SimulationOptions exact;
  exact.propagator = pk::Propagator::kExact;
  const auto a = pk::SimulateSubject(*model, *data, 0, p, exact);
  const auto b = pk::SimulateSubject(*model, *data, 0, p, TightOde());
  REQUIRE(a.ok);
  REQUIRE(b.ok);
  REQUIRE(a.rows.size() == b.rows.size());
  for (size_t k = 0; k < a.rows.size(); ++k) {
    INFO("t = " << a.rows[k].time);
    CHECK(b.rows[k].auc == Approx(a.rows[k].auc).epsilon(1e-9));
    CHECK(b.rows[k].cp == Approx(a.rows[k].cp).epsilon(1e-9));
    const auto col = static_cast<Eigen::Index>(k);
    for (int c = 0; c < 3; ++c) CHECK(b.amounts(c, col) == Approx(a.amounts(c, col)).epsilon(1e-9).margin(1e-12));
  }
  // The exposure metrics see the same doses.
  REQUIRE(a.doses.size() == b.doses.size());
  for (size_t k = 0; k < a.doses.size(); ++k) CHECK(b.doses[k].auc_before == Approx(a.doses[k].auc_before).epsilon(1e-9));
}

TEST_CASE("finite differences through CVODES use a step matched to the tolerance", "[ode][gradient]") {
  const auto model = pk::MakeModel("1cmt_iv_mm");
  auto data = Parse("ID,TIME,AMT,EVID,DV\n1,0,100,1,.\n1,1,0,0,3\n1,4,0,0,2\n1,8,0,0,1\n1,12,0,0,0.5\n");
  pk::ObjectiveOptions oo;  // rtol 1e-8: the automatic step is 1e-8^(1/3) ≈ 2e-3
  const pk::Objective obj(model, data, 0, oo);
  const auto fd = obj.Evaluate(obj.DefaultValues(), {0, 1, 2}, pk::Objective::Need::kGradient,
                               pk::GradientRoute::kFiniteDifference);
  const auto fwd = obj.Evaluate(obj.DefaultValues(), {0, 1, 2}, pk::Objective::Need::kGradient,
                                pk::GradientRoute::kForward);
  REQUIRE(fd.ok);
  REQUIRE(fwd.ok);
  CHECK((fd.gradient - fwd.gradient).cwiseAbs().maxCoeff() < 1e-4 * fwd.gradient.cwiseAbs().maxCoeff());
}

TEST_CASE("adjoint memories sized to their trajectories give the same bits whatever the pool held",
          "[ode][gradient][storage][threads]") {
  // A CVODES adjoint memory starts small and is made again, with the segments
  // integrated again, when its trajectory outgrows it below checkpoint_steps.
  // Each thread pools its memories, so a fresh thread starts from nothing.
  const auto model = pk::MakeModel("2cmt_iv_mm");
  auto regimen = [](int doses) {
    std::ostringstream csv;
    csv << "ID,TIME,AMT,EVID,DV\n";
    for (int d = 0; d < doses; ++d) {
      csv << "1," << 24 * d << ",100,1,.\n";
      for (double t : {0.5, 1.0, 2.0, 4.0, 8.0, 12.0, 23.0}) csv << "1," << 24 * d + t << ",0,0," << 4 * std::exp(-0.1 * t) << "\n";
    }
    return Parse(csv.str());
  };
  const pk::Objective obj(model, regimen(2), 0, OdeOptions()), longer(model, regimen(4), 0, OdeOptions());
  std::vector<int> free(model->num_parameters());
  for (int i = 0; i < model->num_parameters(); ++i) free[i] = i;
  const Eigen::VectorXd values = obj.DefaultValues();
  using Need = pk::Objective::Need;
  auto in_new_thread = [&](bool warm) {
    std::vector<pk::Objective::Evaluation> out;
    std::thread t([&] {
      if (warm) longer.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
      for (int c = 0; c < 2; ++c) out.push_back(obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint));
    });
    t.join();
    return out;
  };
  const auto cold = in_new_thread(false), warm = in_new_thread(true);
  for (const auto* e : {&cold[0], &cold[1], &warm[0], &warm[1]}) REQUIRE(e->ok);
  // The cold thread's first evaluation outgrew its memories and integrated them again; the warm thread's did not.
  CHECK(cold[0].ode_statistics.steps > cold[1].ode_statistics.steps);
  CHECK(warm[0].ode_statistics.steps == cold[1].ode_statistics.steps);
  const double scale = cold[1].gradient.cwiseAbs().maxCoeff();
  const auto fwd = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
  REQUIRE(fwd.ok);
  CHECK((cold[1].gradient - fwd.gradient).cwiseAbs().maxCoeff() <= 1e-7 * scale);
  for (const auto* e : {&cold[0], &warm[0], &warm[1]}) {
    CHECK(e->value == cold[1].value);
    CHECK(e->ode_statistics.backward_steps == cold[1].ode_statistics.backward_steps);
    CHECK(e->ode_statistics.peak_adjoint_bytes == cold[1].ode_statistics.peak_adjoint_bytes);
    int differ = 0;
    for (int i = 0; i < e->gradient.size(); ++i) differ += e->gradient(i) != cold[1].gradient(i);
    CHECK(differ == 0);
  }
}

TEST_CASE("the adjoint's storage modes give the same gradient and store what they say", "[ode][gradient][storage]") {
  const auto model = pk::MakeModel("2cmt_iv_mm");
  for (int index : {2, 5, 9}) {  // bolus then infusion, ss1 bolus, lag
    const Scenario& sc = Scenarios()[index];
    INFO(sc.name);
    const auto data = pk_test::ScenarioData(sc);
    pk::ObjectiveOptions store_all = OdeOptions(), one_segment = OdeOptions(), short_checks = OdeOptions();
    one_segment.ode.adjoint_store_all_segments = false;
    short_checks.ode.checkpoint_steps = 3;  // CVODES recomputes within each segment
    const pk::Objective a(model, data, 0, store_all), b(model, data, 0, one_segment), c(model, data, 0, short_checks);
    Eigen::VectorXd values;
    std::vector<int> free;
    pk_test::ScenarioValues(a, sc, &values, &free);
    using Need = pk::Objective::Need;
    const auto fwd = a.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
    const auto ga = a.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
    const auto gb = b.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
    const auto gc = c.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
    REQUIRE(fwd.ok);
    REQUIRE(ga.ok);
    REQUIRE(gb.ok);
    REQUIRE(gc.ok);
    const double scale = fwd.gradient.cwiseAbs().maxCoeff();
    CHECK((ga.gradient - fwd.gradient).cwiseAbs().maxCoeff() <= 1e-7 * scale);
    CHECK((gb.gradient - fwd.gradient).cwiseAbs().maxCoeff() <= 1e-7 * scale);
    CHECK((gc.gradient - fwd.gradient).cwiseAbs().maxCoeff() <= 1e-7 * scale);
    // Keeping one segment at a time holds less than keeping them all, and integrates forward twice.
    CHECK(ga.ode_statistics.peak_adjoint_bytes > 0);
    CHECK(gb.ode_statistics.peak_adjoint_bytes < ga.ode_statistics.peak_adjoint_bytes);
    CHECK(gb.ode_statistics.steps > ga.ode_statistics.steps);
    CHECK(ga.ode_statistics.backward_steps > 0);
  }
}
