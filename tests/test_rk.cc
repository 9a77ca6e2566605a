// The one-step integrator (--propagator rk, Dormand–Prince 5(4)): against CVODES solved to 1e-12 on
// every catalogue ODE model × event type, against the exact propagator on every linear model, its
// forward sensitivities and discrete adjoint against central differences of its own objective, steps
// that samples do not shorten, simulation, and stiff segments handed to RODAS4. (Its fit of synthetic
// Michaelis–Menten data is tests/test_ode.cc's, run through both integrators.)
#include <algorithm>
#include <cmath>
#include <sstream>

#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/objective.h"
#include "pk/simulate.h"
#include "test_util.h"

namespace {

using Need = pk::Objective::Need;

pk::ObjectiveOptions Options(pk::Propagator propagator, double rtol,
                             std::shared_ptr<const pk::ResidualErrorModel> e = pk::MakeResidualError("least-squares")) {
  pk::ObjectiveOptions o;
  o.error_model = e;
  o.propagator = propagator;
  o.ode.relative_tolerance = rtol;
  o.ode.absolute_tolerance = rtol * 1e-2;
  o.fd_relative_step = 1e-4;
  return o;
}

double MaxAbs(const Eigen::MatrixXd& m) { return m.cwiseAbs().maxCoeff(); }

// Dormand–Prince against CVODES (at a tighter tolerance): predictions to 1e-8, and the forward and
// adjoint gradients to 1e-6 of CVODES' forward one. Returns the steps of rk's forward Jacobian.
long AgreesWithCvodes(const pk::Objective& rk, const pk::Objective& cvodes, const Eigen::VectorXd& values,
                      const std::vector<int>& free) {
  const auto reference = cvodes.Evaluate(values, free, Need::kJacobian, pk::GradientRoute::kForward);
  REQUIRE(reference.ok);
  const auto a = rk.Evaluate(values, free, Need::kJacobian, pk::GradientRoute::kForward);
  INFO(a.message);
  REQUIRE(a.ok);
  CHECK(MaxAbs(a.predictions - reference.predictions) < 1e-8 * MaxAbs(reference.predictions));
  const auto g = cvodes.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
  for (const auto route : {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint}) {
    const auto e = rk.Evaluate(values, free, Need::kGradient, route);
    INFO(pk::ToString(route) << ": " << e.message);
    REQUIRE(e.ok);
    CHECK(MaxAbs(e.gradient - g.gradient) <= 1e-6 * MaxAbs(g.gradient));
  }
  return a.ode_statistics.steps;
}

}  // namespace

// Every event scenario through Dormand–Prince at rtol 1e-10 against `reference`: each prediction and
// sensitivity to 1e-9 of the largest (the requested 1e-10, and the global error).
void CheckAgainst(const std::string& name, pk::Propagator reference, double reference_rtol) {
  const auto model = pk::MakeModel(name);
  for (const pk_test::Scenario& sc : pk_test::OdeScenarios()) {
    INFO(name << " / " << sc.name);
    const auto data = pk_test::ScenarioData(sc);
    const pk::Objective rk(model, data, 0, Options(pk::Propagator::kRungeKutta, 1e-10));
    const pk::Objective other(model, data, 0, Options(reference, reference_rtol));
    Eigen::VectorXd values;
    std::vector<int> free;
    pk_test::ScenarioValues(rk, sc, &values, &free);
    const auto a = rk.Evaluate(values, free, Need::kJacobian, pk::GradientRoute::kForward);
    const auto b = other.Evaluate(values, free, Need::kJacobian, pk::GradientRoute::kForward);
    INFO(a.message);
    REQUIRE(a.ok);
    REQUIRE(b.ok);
    CHECK(std::string(a.propagator) == "rk");
    CHECK(MaxAbs(a.predictions - b.predictions) < 1e-9 * MaxAbs(b.predictions));
    CHECK(MaxAbs(a.jacobian - b.jacobian) < 1e-9 * MaxAbs(b.jacobian));
    // The discrete adjoint (its stage products: recorded for a nonlinear model, formed at the stage
    // points for a linear one) against the reference's forward gradient.
    const auto adjoint = rk.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
    const auto forward = other.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
    REQUIRE(adjoint.ok);
    CHECK(std::string(adjoint.route) == "adjoint");
    CHECK(MaxAbs(adjoint.gradient - forward.gradient) < 1e-8 * MaxAbs(forward.gradient));
  }
}

TEST_CASE("Dormand-Prince agrees with CVODES at 1e-12 on every catalogue ODE model and event type", "[rk]") {
  const auto name = GENERATE(as<std::string>{}, "1cmt_iv_mm", "1cmt_oral_mm", "2cmt_iv_mm", "1cmt_iv_emax", "2cmt_oral",
                             "1cmt_oral_transit");
  if (!pk_test::RunsUnderThisBuild(name, {"1cmt_oral_mm", "1cmt_iv_emax", "2cmt_oral"})) return;
  CheckAgainst(name, pk::Propagator::kOde, 1e-12);
}

TEST_CASE("Dormand-Prince agrees with the exact propagator on every linear model", "[rk]") {
  CheckAgainst(GENERATE(as<std::string>{}, "1cmt_iv", "1cmt_oral", "2cmt_iv", "3cmt_oral", "tf2"),
               pk::Propagator::kExact, 1e-10);
}

TEST_CASE("Dormand-Prince forward sensitivities and discrete adjoint against differences of its own objective",
          "[rk][gradient]") {
  const auto name = GENERATE(as<std::string>{}, "1cmt_iv_mm", "1cmt_oral_mm", "2cmt_iv_mm", "1cmt_iv_emax",
                             "1cmt_oral_transit");
  if (!pk_test::RunsUnderThisBuild(name, {"1cmt_oral_mm", "1cmt_iv_emax"})) return;
  const auto model = pk::MakeModel(name);
  for (const pk_test::Scenario& sc : pk_test::OdeScenarios()) {
    INFO(name << " / " << sc.name);
    const auto data = pk_test::ScenarioData(sc);
    const pk::Objective obj(model, data, 0, Options(pk::Propagator::kRungeKutta, 1e-10));
    Eigen::VectorXd values;
    std::vector<int> free;
    pk_test::ScenarioValues(obj, sc, &values, &free);
    const auto fwd = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
    const auto adj = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
    REQUIRE(fwd.ok);
    REQUIRE(adj.ok);
    CHECK(std::string(adj.route) == "adjoint");
    // Differences of the same integrator's objective, solved to 1e-12 so that their noise is below 1e-8.
    const pk::Objective tight(model, data, 0, Options(pk::Propagator::kRungeKutta, 1e-12));
    const Eigen::VectorXd fd = pk_test::CentralDifferences(tight, values, free);
    const double scale = MaxAbs(fwd.gradient);
    INFO("forward " << fwd.gradient.transpose() << "\nadjoint " << adj.gradient.transpose() << "\nfd      "
                    << fd.transpose());
    CHECK(MaxAbs(fwd.gradient - fd) <= 1e-6 * scale);
    CHECK(MaxAbs(adj.gradient - fd) <= 1e-6 * scale);
    CHECK(MaxAbs(adj.gradient - fwd.gradient) <= 1e-8 * scale);  // measured: at most 2e-10
    // The two routes' losses come from differently stepped integrations, each to the tolerance.
    CHECK(std::fabs(fwd.value - adj.value) <= 1e-8 * std::fabs(fwd.value));
  }
}

TEST_CASE("Dormand-Prince: samples do not shorten steps", "[rk]") {
  const auto model = pk::MakeModel(GENERATE(as<std::string>{}, "1cmt_iv_mm", "1cmt_oral_mm", "2cmt_iv_mm"));
  const double times[] = {0.25, 0.5, 1, 1.5, 2, 3, 4, 6, 8, 12, 16, 24};
  auto data_with = [](const double* t, int count) {
    std::ostringstream csv;
    csv << "ID,TIME,AMT,EVID,CMT,DV\n1,0,100,1,1,.\n";
    for (int k = 0; k < count; ++k) csv << "1," << t[k] << ",0,0,0,1\n";
    return std::make_shared<pk::Dataset>(pk::ParseDataset(csv.str(), "samples.csv"));
  };
  const auto options = Options(pk::Propagator::kRungeKutta, 1e-10);
  const pk::Objective many(model, data_with(times, 12), 0, options);
  const pk::Objective last(model, data_with(times + 11, 1), 0, options);
  std::vector<int> free;
  for (int i = 0; i < many.model().num_parameters(); ++i) free.push_back(i);
  for (const Need need : {Need::kValue, Need::kJacobian}) {
    const auto a = many.Evaluate(many.DefaultValues(), free, need, pk::GradientRoute::kForward);
    const auto b = last.Evaluate(last.DefaultValues(), free, need, pk::GradientRoute::kForward);
    REQUIRE(a.ok);
    REQUIRE(b.ok);
    INFO(model->name() << ": 12 samples " << a.ode_statistics.steps << " steps, 1 sample " << b.ode_statistics.steps);
    // The same steps whatever the samples: each is read from the dense output.
    CHECK(a.ode_statistics.steps == b.ode_statistics.steps);
    CHECK(a.predictions(11) == b.predictions(0));
  }
}

TEST_CASE("Dormand-Prince: continuous records (CONT=1), forward sensitivities against differences",
          "[rk][gradient][continuous]") {
  const auto model = pk::MakeModel("1cmt_iv_emax");
  std::ostringstream csv;
  csv << "ID,TIME,AMT,RATE,II,ADDL,EVID,DVID,CONT,DV\n1,0,100,0,6,2,1,.,.,.\n";
  for (int k = 1; k <= 48; ++k) {
    const double t = 0.25 * k;
    if (k % 6 == 0) csv << "1," << t << ",0,0,0,0,0,1,0," << 3.0 * std::exp(-0.1 * t) << "\n";
    csv << "1," << t << ",0,0,0,0,0,2,1," << 10 + 30 * std::sin(0.3 * t) * std::sin(0.3 * t) << "\n";
  }
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(csv.str(), "cont.csv"));
  const pk::Objective rk(model, data, 0, Options(pk::Propagator::kRungeKutta, 1e-10));
  const pk::Objective cvodes(model, data, 0, Options(pk::Propagator::kOde, 1e-12));
  REQUIRE(rk.has_continuous_records());
  Eigen::VectorXd values;
  std::vector<int> free;
  pk_test::ScenarioValues(rk, pk_test::OdeScenarios()[0], &values, &free);
  const auto a = rk.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
  const auto b = cvodes.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
  REQUIRE(a.ok);
  REQUIRE(b.ok);
  // The discrete adjoint does not cover continuous records: an adjoint request takes route (a).
  const auto adjoint = rk.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  REQUIRE(adjoint.ok);
  CHECK(std::string(adjoint.route) == "forward");
  CHECK(std::fabs(a.value - b.value) <= 1e-9 * b.value);
  const pk::Objective tight(model, data, 0, Options(pk::Propagator::kRungeKutta, 1e-12));
  const Eigen::VectorXd fd = pk_test::CentralDifferences(tight, values, free);
  INFO("forward " << a.gradient.transpose() << "\nfd      " << fd.transpose());
  CHECK(MaxAbs(a.gradient - fd) <= 1e-6 * MaxAbs(a.gradient));
  CHECK(MaxAbs(a.gradient - b.gradient) <= 1e-8 * MaxAbs(b.gradient));
}

TEST_CASE("pksim through Dormand-Prince: AUC and amounts equal the exact propagator's", "[rk][simulate]") {
  const auto model = pk::MakeModel("2cmt_oral");
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(
      "ID,TIME,AMT,RATE,II,ADDL,SS,EVID\n1,0,100,0,12,3,0,1\n1,5,0,0,0,0,0,2\n1,20,0,0,0,0,0,2\n"
      "1,30,50,25,0,0,0,1\n1,40,0,0,0,0,0,2\n1,60,0,0,0,0,0,2\n",
      "sim.csv"));
  const pk::ParameterValues p = {{"KA", 1.3}, {"CL", 4}, {"V2", 25}, {"Q", 6}, {"V3", 60}};
  pk::SimulationOptions exact, rk;
  exact.propagator = pk::Propagator::kExact;
  rk.propagator = pk::Propagator::kRungeKutta;
  rk.ode.relative_tolerance = 1e-11;
  rk.ode.absolute_tolerance = 1e-13;
  const auto a = pk::SimulateSubject(*model, *data, 0, p, exact);
  const auto b = pk::SimulateSubject(*model, *data, 0, p, rk);
  REQUIRE(a.ok);
  REQUIRE(b.ok);
  REQUIRE(a.rows.size() == b.rows.size());
  for (size_t k = 0; k < a.rows.size(); ++k) {
    INFO("t = " << a.rows[k].time);
    CHECK(b.rows[k].auc == Approx(a.rows[k].auc).epsilon(1e-9));
    CHECK(b.rows[k].cp == Approx(a.rows[k].cp).epsilon(1e-9));
  }
  CHECK(MaxAbs(b.amounts - a.amounts) <= 1e-9 * MaxAbs(a.amounts));
}

TEST_CASE("Dormand-Prince hands stiff segments to RODAS4, in every route", "[rk]") {
  // Exchange 10⁵ times faster than elimination: the explicit method's stability limit, not accuracy,
  // would bound its steps (some 10⁶ for 24 h). Each such segment goes to the Rosenbrock method.
  const auto model = pk::MakeModel("2cmt_iv");
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(
      "ID,TIME,AMT,EVID,DV\n1,0,100,1,.\n1,1,0,0,3\n1,6,0,0,2\n1,12,80,1,.\n1,24,0,0,1\n", "stiff.csv"));
  pk::ObjectiveOptions o = Options(pk::Propagator::kRungeKutta, 1e-10);
  o.ode.max_steps = 20000;  // Dormand–Prince alone would end with "too much work"
  const pk::Objective rk(model, data, 0, o);
  const pk::Objective cvodes(model, data, 0, Options(pk::Propagator::kOde, 1e-12));
  Eigen::VectorXd values = rk.DefaultValues();
  values(rk.ParameterIndex("Q")) = 1e6;
  const std::vector<int> free = {0, 1, 2, 3};
  CHECK(AgreesWithCvodes(rk, cvodes, values, free) < 20000);
  // BDF at the same tolerance, for the number of steps.
  const pk::Objective bdf(model, data, 0, Options(pk::Propagator::kOde, 1e-10));
  for (const auto need : {Need::kValue, Need::kJacobian}) {
    const auto e = rk.Evaluate(values, free, need, pk::GradientRoute::kForward);
    const auto c = bdf.Evaluate(values, free, need, pk::GradientRoute::kForward);
    REQUIRE(e.ok);
    REQUIRE(c.ok);
    INFO("steps " << e.ode_statistics.steps << ", of them RODAS4's " << e.ode_statistics.stiff_steps << "; BDF's "
                  << c.ode_statistics.steps);
    CHECK(e.ode_statistics.stiff_steps > 0);
    CHECK(e.ode_statistics.steps < 2 * c.ode_statistics.steps);  // measured: 1.1 and 1.3 times BDF's
  }
  // RODAS4's adjoint of a stiff segment is the derivative of its own computed segment: it equals
  // central differences of the rk objective itself (least squares, so the loss adds nothing).
  const auto adj = rk.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  REQUIRE(adj.ok);
  const Eigen::VectorXd fd = pk_test::CentralDifferences(rk, values, free);
  INFO("adjoint " << adj.gradient.transpose() << "\nfd      " << fd.transpose());
  CHECK(MaxAbs(adj.gradient - fd) <= 1e-6 * MaxAbs(fd));
}

TEST_CASE("Dormand-Prince: a free lag at 0 (an empty segment that carries a derivative)", "[rk][gradient]") {
  // The engine advances by h = ALAG = 0 with ∂h/∂ALAG = 1: no time passes, and the derivative
  // enters by the lag term. An integrator that stepped an empty segment gave NaN here.
  const auto model = pk::MakeModel("1cmt_oral_mm");
  const auto data = pk_test::ScenarioData(pk_test::OdeScenarios()[0]);
  const pk::Objective rk(model, data, 0, Options(pk::Propagator::kRungeKutta, 1e-10));
  const pk::Objective cvodes(model, data, 0, Options(pk::Propagator::kOde, 1e-12));
  Eigen::VectorXd values = rk.DefaultValues();
  std::vector<int> free;
  for (int i = 0; i < model->num_parameters(); ++i) free.push_back(i);
  const int lag = rk.ParameterIndex("ALAG1");
  REQUIRE(lag >= 0);
  values(lag) = 0;
  free.push_back(lag);
  const auto reference = cvodes.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
  REQUIRE(reference.ok);
  for (const auto route : {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint}) {
    const auto e = rk.Evaluate(values, free, Need::kGradient, route);
    INFO(pk::ToString(route) << ": " << e.message);
    REQUIRE(e.ok);
    REQUIRE(e.gradient.allFinite());
    CHECK(MaxAbs(e.gradient - reference.gradient) <= 1e-7 * MaxAbs(reference.gradient));
  }
}

TEST_CASE("Dormand-Prince: a system that stiffens as the drug clears, and a steady state, handed over midway",
          "[rk][gradient]") {
  // Michaelis–Menten with KM far below the concentrations: f_x = −VMAX·KM/(V(KM + C)²) is small after
  // the dose and reaches −VMAX/(V·KM) once the drug is gone, so a segment that starts non-stiff
  // ends stiff: the periodic stiffness checks send it to RODAS4 from its start, long before the step
  // budget would. The steady-state dose (SS=1) adds cycles that replay in the adjoint.
  const auto model = pk::MakeModel("1cmt_iv_mm");
  const char* texts[] = {
      "ID,TIME,AMT,II,SS,EVID,DV\n1,0,100,0,0,1,.\n1,0.5,0,0,0,0,4\n1,2,0,0,0,0,3\n1,48,0,0,0,0,0.01\n"
      "1,72,0,0,0,0,0.001\n",
      "ID,TIME,AMT,II,SS,EVID,DV\n1,0,100,24,1,1,.\n1,0.5,0,0,0,0,4\n1,6,0,0,0,0,2\n1,23,0,0,0,0,0.5\n"};
  for (const char* text : texts) {
    const bool steady = std::string(text).find(",24,1,1,") != std::string::npos;
    INFO(text);
    const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(text, "stiffening.csv"));
    const pk::Objective rk(model, data, 0, Options(pk::Propagator::kRungeKutta, 1e-10));
    const pk::Objective cvodes(model, data, 0, Options(pk::Propagator::kOde, 1e-12));
    Eigen::VectorXd values = rk.DefaultValues();
    values(rk.ParameterIndex("KM")) = 0.002;
    const std::vector<int> free = {0, 1, 2};
    AgreesWithCvodes(rk, cvodes, values, free);
    const pk::OdeStatistics stats = rk.Evaluate(values, free, Need::kValue).ode_statistics;
    INFO("steps " << stats.steps << ", of them RODAS4's " << stats.stiff_steps);
    CHECK(stats.stiff_steps > 0);
    // Dormand–Prince's steps, the wasted ones included, fewer than the budget's 1000 (a steady state's
    // cycles are stepped again at every Newton iteration, so only without one).
    if (!steady) CHECK(stats.steps - stats.stiff_steps < 1000);
  }
}

// ---------------------------------------------------------------------------------------------
// RODAS4 and the pieces it rests on, directly.

#include "hyper_dual_number.h"
#include "ode/ode_system.h"
#include "ode/rosenbrock.h"
#include "ode/rk_solver.h"

TEST_CASE("the stacked sensitivity Jacobian's blocks B_a equal differences of f_x s_a + f_θ θ_a", "[rk][stiff]") {
  for (const char* name : {"1cmt_iv_emax", "2cmt_iv_mm", "1cmt_oral_mm", "2cmt_iv"}) {
    INFO(name);
    const auto model = pk::MakeModel(name);
    const pk::internal::OdeSystem sys(*model);
    const int n = sys.n(), m = sys.num_theta(), k = 3;
    Eigen::VectorXd theta(m);
    for (int i = 0; i < m; ++i) theta(i) = model->default_parameters()(i) * (1 + 0.1 * i);
    Eigen::VectorXd x(n);
    for (int i = 0; i < n; ++i) x(i) = 5.0 + 3.0 * i;
    Eigen::MatrixXd s(n, k), dtheta(m, k);
    for (int i = 0; i < n; ++i) {
      for (int a = 0; a < k; ++a) s(i, a) = std::sin(1.0 + i + 2.0 * a);
    }
    for (int i = 0; i < m; ++i) {
      for (int a = 0; a < k; ++a) dtheta(i, a) = std::cos(0.5 + i + a);
    }
    std::vector<Eigen::MatrixXd> b;
    sys.SensitivityJacobians(x, theta, s, dtheta, &b);
    REQUIRE(b.size() == static_cast<size_t>(k));
    for (int j = 0; j < n; ++j) {
      const double h = 1e-5 * std::max(1.0, std::abs(x(j)));
      Eigen::VectorXd xp = x, xm = x, f;
      xp(j) += h;
      xm(j) -= h;
      Eigen::MatrixXd dp, dm;
      sys.RhsDirectional(xp, theta, s, dtheta, &f, &dp);
      sys.RhsDirectional(xm, theta, s, dtheta, &f, &dm);
      const Eigen::MatrixXd fd = (dp - dm) / (2 * h);  // column a: ∂(f_x s_a + f_θ θ_a)/∂x_j
      for (int a = 0; a < k; ++a) {
        const double scale = std::max(1.0, fd.col(a).cwiseAbs().maxCoeff());
        CHECK((b[static_cast<size_t>(a)].col(j) - fd.col(a)).cwiseAbs().maxCoeff() <= 1e-7 * scale);
      }
    }
  }
}

TEST_CASE("RODAS4's adjoint of a segment is the derivative of the computed map along its steps", "[rk][stiff]") {
  // At rtol 1e-3 the steps are few and long, so the discrete map differs from the exact flow by far more
  // than the check's tolerance: only the derivative of the computed map passes (a missing or wrong B_a
  // would make it the derivative of another method).
  for (const char* name : {"1cmt_oral_mm", "2cmt_iv_mm", "1cmt_iv_emax"}) {
    INFO(name);
    const auto model = pk::MakeModel(name);
    const pk::internal::OdeSystem sys(*model);
    const int n = sys.n(), m = sys.num_theta();
    pk::OdeOptions opt;
    opt.relative_tolerance = 1e-3;
    opt.absolute_tolerance = 1e-5;
    pk::OdeStatistics stats;
    pk::internal::Rosenbrock rodas(sys, opt, &stats);
    pk::internal::SegmentInput in;
    in.h = 12;
    in.u = Eigen::VectorXd::Zero(n);
    in.u(0) = 2;  // an infusion, so that ∂u/∂p enters too
    in.theta = model->default_parameters().head(m);
    in.dtheta = Eigen::MatrixXd::Identity(m, m + 1);
    in.du = Eigen::MatrixXd::Zero(n, m + 1);
    in.du(0, m) = 1;  // the last parameter is the infusion rate
    Eigen::VectorXd x0(n);
    for (int i = 0; i < n; ++i) x0(i) = 40.0 / (1 + i);
    Eigen::VectorXd x = x0;
    std::vector<double> steps;
    rodas.Advance(in, &x, &steps);
    REQUIRE(steps.size() >= 2);
    REQUIRE(steps.size() < 60);
    Eigen::VectorXd lambda(n);
    for (int i = 0; i < n; ++i) lambda(i) = 0.3 + 0.7 * i;
    Eigen::VectorXd lambda0;
    Eigen::RowVectorXd q;
    rodas.AdjointSegment(in, x0, steps, lambda, &lambda0, &q);
    // Central differences of λᵀx(h) along the same steps.
    const auto value = [&](const Eigen::VectorXd& start, const pk::internal::SegmentInput& seg) {
      Eigen::VectorXd y = start;
      rodas.AdvanceAlong(seg, &y, steps);
      return lambda.dot(y);
    };
    for (int i = 0; i < n; ++i) {
      const double h = 1e-6 * x0(i);
      Eigen::VectorXd up = x0, down = x0;
      up(i) += h;
      down(i) -= h;
      const double fd = (value(up, in) - value(down, in)) / (2 * h);
      CHECK(std::abs(lambda0(i) - fd) <= 1e-7 * std::max(1.0, std::abs(fd)));
    }
    for (int a = 0; a <= m; ++a) {
      pk::internal::SegmentInput up = in, down = in;
      const double h = a < m ? 1e-6 * in.theta(a) : 1e-6;
      if (a < m) {
        up.theta(a) += h;
        down.theta(a) -= h;
      } else {
        up.u(0) += h;
        down.u(0) -= h;
      }
      const double fd = (value(x0, up) - value(x0, down)) / (2 * h);
      INFO("parameter " << a << ": adjoint " << q(a) << ", differences " << fd);
      CHECK(std::abs(q(a) - fd) <= 1e-6 * std::max(1.0, std::abs(fd)));
    }
  }
}

TEST_CASE("Dormand-Prince: a stored segment swept twice gives the same λ and parameter products",
          "[rk][adjoint]") {
  // Two seeds of one forward pass (OdeAdjoint::Gradient twice): the second backward sweep must not add to
  // the first's θ products, with kept stages and with stages recomputed. Against central differences
  // of λᵀx(h) too, so that both sweeps are right and not merely alike.
  const auto model = pk::MakeModel("1cmt_oral_mm");
  const pk::internal::OdeSystem sys(*model);
  const int n = sys.n(), m = sys.num_theta();
  pk::internal::SegmentInput in;
  in.h = 6;
  in.u = Eigen::VectorXd::Zero(n);
  in.theta = model->default_parameters().head(m);
  in.dtheta = Eigen::MatrixXd::Identity(m, m);
  in.du = Eigen::MatrixXd(n, 0);
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n);
  x0(0) = 100;
  Eigen::VectorXd lambda(n);
  for (int i = 0; i < n; ++i) lambda(i) = 0.3 + 0.7 * i;
  for (const bool keep : {true, false}) {
    INFO("kept stages " << keep);
    pk::OdeOptions opt;
    opt.adjoint_keeps_stages = keep;
    pk::internal::RkSolver rk(sys, opt, true);
    Eigen::VectorXd x = x0;
    const int handle = rk.StoreSegment(in, &x);
    Eigen::VectorXd lambda0, again;
    Eigen::RowVectorXd q, q_again;
    rk.BackwardStored(handle, pk::internal::AdjointScales(), lambda, &lambda0, &q);
    rk.BackwardStored(handle, pk::internal::AdjointScales(), lambda, &again, &q_again);
    CHECK(again == lambda0);
    CHECK(q_again == q);
    for (int a = 0; a < m; ++a) {
      const double h = 1e-6 * in.theta(a);
      pk::internal::SegmentInput up = in, down = in;
      up.theta(a) += h;
      down.theta(a) -= h;
      Eigen::VectorXd xu = x0, xd = x0;
      pk::internal::RkSolver plain(sys, opt, true);
      plain.Advance(up, &xu);
      plain.Advance(down, &xd);
      const double fd = (lambda.dot(xu) - lambda.dot(xd)) / (2 * h);
      INFO("parameter " << a << ": adjoint " << q(a) << ", differences " << fd);
      CHECK(std::abs(q(a) - fd) <= 1e-5 * std::max(1.0, std::abs(fd)));
    }
  }
}

TEST_CASE("hyper-dual parts along a direction that does not move x stay 0 where f' or f'' is infinite",
          "[second-order]") {
  const pk::HyperDual zero(0.0, 0.0, 1.0, 0.0);  // x = 0, moved along ε₂ only
  for (const pk::HyperDual& y : {sqrt(pk::HyperDual(0.0)), pow(zero, 1.5), pow(pk::HyperDual(0.0, 0.0, 0.0, 1.0), 1.5)}) {
    CHECK(y.value() == 0);
    CHECK(y.e1() == 0);
    CHECK(std::isfinite(y.e2()));
    CHECK(y.e12() == 0);
  }
}

// ---------------------------------------------------------------------------------------------
// The discrete adjoint's pieces: StageTape's recordings, the outputs' gradients, and the stepping
// choices made for it.

namespace {

// f and outputs that end, in turn, on a parameter's node, a state's, a constant and an operation:
// every kind of node a recording can end on.
struct Corners {
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    dxdt[0] = p[0];
    dxdt[1] = x[0];
    dxdt[2] = T(3.0);
    dxdt[3] = p[1] * x[1] * x[2] / (p[2] + x[3]);
  }
  template <typename T>
  T Output(int output, const T* x, const T* p) const {
    if (output == 1) return x[3] / p[2];
    if (output == 2) return x[1];
    if (output == 3) return p[0];
    return T(2.0);
  }
};

std::shared_ptr<const pk::Model> CornersModel() {
  pk::OdeModelSpec spec;
  spec.name = "corners";
  spec.compartments = {"A", "B", "C", "D"};
  spec.parameters = {{"R", 2}, {"K", 0.5}, {"V", 10}};
  spec.outputs = {"Y1", "Y2", "Y3", "Y4"};
  return pk::MakeOdeModel(spec, Corners());
}

// pkbench's saturable chain: x_i flows to x_{i+1} at VMAX_i x_i/(KM_i + x_i); θ = (VMAX, KM).
struct SaturableChain {
  int n;
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    T inflow(0.0);
    for (int i = 0; i < n; ++i) {
      const T out = p[i] * x[i] / (p[n + i] + x[i]);
      dxdt[i] = inflow - out;
      inflow = out;
    }
  }
  template <typename T>
  T Output(int, const T* x, const T*) const {
    return x[n - 1];
  }
};

std::shared_ptr<const pk::Model> Chain(int n, double vmax_scale) {
  pk::OdeModelSpec spec;
  spec.name = "chain";
  for (int i = 1; i <= n; ++i) spec.compartments.push_back("X" + std::to_string(i));
  for (int i = 1; i <= n; ++i) spec.parameters.push_back({"VMAX" + std::to_string(i), vmax_scale * (40.0 + i)});
  for (int i = 1; i <= n; ++i) spec.parameters.push_back({"KM" + std::to_string(i), 5.0 + 0.1 * i});
  spec.central = n;
  return pk::MakeOdeModel(spec, SaturableChain{n});
}

std::shared_ptr<pk::Dataset> ChainData() {
  std::ostringstream csv;
  csv << "ID,TIME,AMT,EVID,CMT,DV\n1,0,100,1,1,.\n";
  for (double t : {0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0}) {
    csv << "1," << t << ",0,0,0," << 5 * std::exp(-0.1 * t) + 0.3 << "\n";
  }
  return std::make_shared<pk::Dataset>(pk::ParseDataset(csv.str(), "chain.csv"));
}

Eigen::VectorXd Spread(const pk::Model& model) {
  Eigen::VectorXd theta = model.default_parameters();
  for (Eigen::Index i = 0; i < theta.size(); ++i) theta(i) *= 1 + 0.1 * static_cast<double>(i);
  return theta;
}

}  // namespace

TEST_CASE("StageTape: each stage's products equal a recording of its own, over several steps", "[rk][adjoint]") {
  for (const auto& model : {CornersModel(), pk::MakeModel("1cmt_iv_emax"), pk::MakeModel("2cmt_iv_mm"),
                            pk::MakeModel("2cmt_iv"), pk::MakeModel("3cmt_oral")}) {
    INFO(model->name());
    const pk::internal::OdeSystem sys(*model);
    const int n = sys.n();
    const Eigen::VectorXd theta = Spread(*model);
    // Two steps of three stages; the references first (they record on the thread's tape themselves).
    const int steps = 2, stages = 3;
    std::vector<Eigen::VectorXd> points, weights, f_ref, wfx_ref;
    Eigen::VectorXd theta_ref = Eigen::VectorXd::Zero(theta.size());
    for (int k = 0; k < steps * stages; ++k) {
      Eigen::VectorXd x(n), w(n), f, wfx, wft;
      for (int i = 0; i < n; ++i) {
        x(i) = 5.0 + 3.0 * i + 0.7 * k;
        w(i) = std::sin(1.0 + i + 2.0 * k);
      }
      sys.RhsVectorJacobian(x, theta, w, &f, &wfx, &wft);
      points.push_back(x);
      weights.push_back(w);
      f_ref.push_back(f);
      wfx_ref.push_back(wfx);
      theta_ref += wft;
    }
    for (const bool compressed : {false, true}) {
      INFO("compressed " << compressed);
      pk::internal::StageTape tape(sys, theta, compressed);
      CHECK(tape.compressed() == (compressed && !sys.is_linear()));  // every nonlinear one here compresses
      for (int step = 0; step < steps; ++step) {
        tape.NewStep();
        for (int s = 0; s < stages; ++s) {
          Eigen::VectorXd f;
          tape.Record(points[step * stages + s], &f);
          CHECK(MaxAbs(f - f_ref[step * stages + s]) <= 1e-14 * (1 + MaxAbs(f_ref[step * stages + s])));
        }
        for (int s = stages - 1; s >= 0; --s) {
          Eigen::VectorXd wfx;
          tape.Sweep(s, weights[step * stages + s], &wfx);
          CHECK(MaxAbs(wfx - wfx_ref[step * stages + s]) <= 1e-14 * (1 + MaxAbs(wfx_ref[step * stages + s])));
        }
      }
      CHECK(MaxAbs(tape.ThetaProduct() - theta_ref) <= 1e-14 * (1 + MaxAbs(theta_ref)));
    }
  }
}

TEST_CASE("StageTape: a recording made on the thread's tape meanwhile is caught", "[rk][adjoint]") {
  const auto model = pk::MakeModel("1cmt_oral_mm");
  const pk::internal::OdeSystem sys(*model);
  const Eigen::VectorXd theta = Spread(*model), x = Eigen::VectorXd::Constant(sys.n(), 2.0);
  pk::internal::StageTape tape(sys, theta, /*compressed=*/false);  // recorded: the compressed one uses no tape
  REQUIRE_FALSE(tape.compressed());
  Eigen::VectorXd f, wfx, wft;
  tape.Record(x, &f);
  sys.RhsVectorJacobian(x * 1.5, theta, x, &f, &wfx, &wft);  // records f on the same tape
  CHECK_THROWS_AS(tape.Sweep(0, x, &wfx), std::logic_error);
}

TEST_CASE("an output's gradient by reverse mode equals its directional derivatives", "[rk][adjoint]") {
  const std::pair<std::shared_ptr<const pk::Model>, std::vector<int>> cases[] = {
      {CornersModel(), {1, 2, 3, 4}},
      {pk::MakeModel("1cmt_iv_emax"), {1, 2}},
      {pk::MakeModel("2cmt_iv_mm"), {1}},
      {pk::MakeModel("2cmt_iv"), {1, 2}},  // a linear model's compartments (keys 1…n)
      {pk::MakeModel("1cmt_oral"), {1, 2}}};
  for (const auto& c : cases) {
    const pk::internal::OdeSystem sys(*c.first);
    const int n = sys.n(), m = sys.num_theta();
    const Eigen::VectorXd theta = Spread(*c.first);
    Eigen::VectorXd x(n);
    for (int i = 0; i < n; ++i) x(i) = 4.0 + 2.5 * i;
    Eigen::MatrixXd dx = Eigen::MatrixXd::Zero(n, n + m), dtheta = Eigen::MatrixXd::Zero(m, n + m);
    dx.leftCols(n).setIdentity();
    dtheta.rightCols(m).setIdentity();
    for (int key : c.second) {
      INFO(c.first->name() << " output " << key);
      double y_ref = 0;
      Eigen::RowVectorXd dy;
      sys.ObserveDirectional(key, x, theta, dx, dtheta, &y_ref, &dy);
      Eigen::VectorXd gx, gtheta;
      const double y = sys.ObserveGradient(key, x, theta, &gx, &gtheta);
      CHECK(std::fabs(y - y_ref) <= 1e-15 * (1 + std::fabs(y_ref)));
      REQUIRE(gx.size() == n);
      REQUIRE(gtheta.size() == m);
      // The same partials multiplied in another order: equal to rounding.
      CHECK(MaxAbs(gx.transpose() - dy.head(n)) <= 1e-13 * (1 + MaxAbs(dy)));
      CHECK(MaxAbs(gtheta.transpose() - dy.tail(m)) <= 1e-13 * (1 + MaxAbs(dy)));
    }
  }
}

TEST_CASE("Dormand-Prince: a saturable chain is not judged stiff, and the adjoint's pass takes the solve's steps",
          "[rk][adjoint]") {
  pk::ObjectiveOptions o;
  o.propagator = pk::Propagator::kRungeKutta;
  // Its bidiagonal Jacobian's row-sum norm is twice its spectral radius: one stiffness check alone sent
  // the late segments of 32 compartments to RODAS4.
  const auto data = ChainData();
  {
    const pk::Objective chain(Chain(32, 1.0), data, 0, o);
    const auto e = chain.Evaluate(chain.DefaultValues(), {}, Need::kValue);
    REQUIRE(e.ok);
    CHECK(e.ode_statistics.stiff_steps == 0);
  }
  // A segment that continues the last one (a sample between them) carries its step into the adjoint's
  // forward pass, which steps each segment to its end; restarting from a small step at every sample
  // took 1.29 times the solve's steps here.
  const pk::Objective chain(Chain(4, 0.1), data, 0, o);
  std::vector<int> free(8);
  for (int i = 0; i < 8; ++i) free[static_cast<size_t>(i)] = i;
  const auto values = chain.Evaluate(chain.DefaultValues(), free, Need::kValue);
  const auto adjoint = chain.Evaluate(chain.DefaultValues(), free, Need::kGradient, pk::GradientRoute::kAdjoint);
  REQUIRE(adjoint.ok);
  INFO("steps: solve " << values.ode_statistics.steps << ", adjoint's pass " << adjoint.ode_statistics.steps);
  CHECK(adjoint.ode_statistics.steps <= 1.15 * values.ode_statistics.steps);
}


TEST_CASE("Dormand-Prince: a trial step whose error estimate is NaN is rejected, not accepted", "[rk]") {
  // z' = −z, written so that f is NaN wherever z < 0 (0·√z), which the true solution never reaches. A
  // first trial step of 20 puts the second stage at 1 − 20/5 < 0: its error estimate is NaN, which
  // Odeint's own control accepted (NaN > 1 is false), and the solution became NaN. Rejected, the step
  // is retried five times shorter until the stages stay where f is defined.
  const auto rhs = [](const Eigen::VectorXd& z, Eigen::VectorXd* f) {
    *f = -z + 0.0 * z.array().sqrt().matrix();
  };
  Eigen::VectorXd z = Eigen::VectorXd::Ones(1);
  double first_step = 0;  // try the whole interval first
  pk::internal::DormandPrinceTo(rhs, 20.0, 1e-14, 1e-10, 100000, &z, &first_step);
  REQUIRE(std::isfinite(z(0)));
  CHECK(std::fabs(z(0) - std::exp(-20.0)) <= 1e-8 * std::exp(-20.0) + 1e-13);
}

TEST_CASE("SameMatrix and SharedMatrix::Equals compare shapes before values", "[rk]") {
  // The continuation checks compare ∂u/∂p, which has no columns when no rate depends on p, with the
  // last segment's; Eigen's == on unequal shapes is undefined in a Release build. A 2×3 and a 3×2
  // matrix hold the same six numbers in memory here, so a comparison of the numbers alone says equal.
  Eigen::MatrixXd wide(2, 3), tall(3, 2);
  wide << 1, 3, 5, 2, 4, 6;
  tall << 1, 4, 2, 5, 3, 6;
  REQUIRE(std::equal(wide.data(), wide.data() + 6, tall.data()));
  CHECK_FALSE(pk::internal::SameMatrix(wide, tall));
  CHECK_FALSE(pk::internal::SameMatrix(Eigen::MatrixXd(3, 0), Eigen::MatrixXd(0, 3)));
  CHECK(pk::internal::SameMatrix(Eigen::MatrixXd(3, 0), Eigen::MatrixXd(3, 0)));
  CHECK(pk::internal::SameMatrix(wide, Eigen::MatrixXd(wide)));
  Eigen::MatrixXd other = wide;
  other(1, 2) = 7;
  CHECK_FALSE(pk::internal::SameMatrix(wide, other));

  const pk::internal::SharedMatrix a(wide), b(tall), a_copy{Eigen::MatrixXd(wide)}, empty;
  const pk::internal::SharedMatrix a_again = a;
  CHECK(a_again.SameAs(a));
  CHECK_FALSE(a_copy.SameAs(a));
  CHECK(a_copy.Equals(a));  // equal values, another object
  CHECK_FALSE(a.Equals(b));
  CHECK_FALSE(a.Equals(empty));
  CHECK(empty.Equals(pk::internal::SharedMatrix()));
  CHECK(empty->size() == 0);
}
