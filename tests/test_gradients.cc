// Every gradient route against central finite differences and against each
// other, on every catalogue model × every event type.

#include <catch2/catch.hpp>

#include <unsupported/Eigen/MatrixFunctions>

#include "exact/jet_exponential.h"
#include "hyper_dual_number.h"
#include "pk/catalogue.h"
#include "pk/linear_model.h"
#include "pk/model_file.h"
#include "pk/ode_model.h"
#include "pk/objective.h"
#include "test_util.h"

namespace {

using pk_test::Scenario;

const std::vector<Scenario>& Scenarios() {
  static const std::vector<Scenario> s = {
      {"bolus", "1,0,100,0,0,0,0,1,.\n", {}, {}},
      {"infusion", "1,0,100,40,0,0,0,1,.\n", {}, {}},
      {"addl", "1,0,100,0,6,3,0,1,.\n", {}, {}},
      {"ss1 bolus", "1,0,100,0,12,0,1,1,.\n", {}, {}},
      {"ss2 on a dose", "1,0,50,0,0,0,0,1,.\n1,0.2,100,0,12,0,2,1,.\n", {}, {}},
      {"ss1 infusion longer than II", "1,0,100,5,8,0,1,1,.\n", {}, {}},
      {"ss constant infusion", "1,0,0,10,0,0,1,1,.\n", {}, {}},
      {"lag", "1,0,100,0,6,2,0,1,.\n", {"ALAG1"}, {0.7}},
      {"F bolus", "1,0,100,0,0,0,0,1,.\n", {"F1"}, {0.8}},
      {"F infusion", "1,0,100,30,0,0,0,1,.\n", {"F1"}, {0.8}},
      {"R", "1,0,100,-1,0,0,0,1,.\n", {"R1"}, {35}},
      {"D and F", "1,0,100,-2,0,0,0,1,.\n", {"D1", "F1"}, {2.2, 0.9}},
      {"ss1 with lag", "1,0,100,0,12,0,1,1,.\n", {"ALAG1"}, {1.3}},
      {"ss1 infusion with lag and D", "1,0,100,-2,8,0,1,1,.\n", {"ALAG1", "D1"}, {0.6, 11.0}},
      {"initial state", "1,0,100,0,6,2,0,1,.\n", {"X0_1"}, {30.0}},
  };
  return s;
}

double MaxAbs(const Eigen::VectorXd& v) { return v.cwiseAbs().maxCoeff(); }

}  // namespace

TEST_CASE("gradient routes agree: forward, adjoint and finite differences", "[gradient]") {
  const auto model_name = GENERATE(as<std::string>{}, "1cmt_iv", "1cmt_oral", "2cmt_iv", "2cmt_oral", "3cmt_iv",
                                   "3cmt_oral");
  const auto model = pk::MakeModel(model_name);
  for (const Scenario& sc : Scenarios()) {
    const auto error_model =
        GENERATE(pk::MakeResidualError("least-squares"), pk::MakeResidualError("combined"), pk::MakeResidualError("exponential"));
    INFO(model_name << " / " << sc.name << " / " << error_model->name());
    pk::ObjectiveOptions options;
    options.error_model = error_model;
    const pk::Objective objective(model, pk_test::ScenarioData(sc), 0, options);
    Eigen::VectorXd values = objective.DefaultValues();
    std::vector<int> free;
    for (int i = 0; i < model->num_parameters(); ++i) {
      values(i) *= 1.0 + 0.1 * i;  // away from the catalogue's round numbers
      free.push_back(i);
    }
    for (size_t e = 0; e < sc.extra_free.size(); ++e) {
      const int i = objective.ParameterIndex(sc.extra_free[e]);
      REQUIRE(i >= 0);
      values(i) = sc.extra_values[e];
      free.push_back(i);
    }
    for (const char* sigma : {"SIGMA_ADD", "SIGMA_PROP", "SIGMA_LOG"}) {
      if (objective.ParameterIndex(sigma) >= 0) free.push_back(objective.ParameterIndex(sigma));
    }
    using Need = pk::Objective::Need;
    if (pk_test::NoLogOfZero(objective, values, free, sc)) continue;
    const auto fwd = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
    const auto adj = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
    const auto fd = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kFiniteDifference);
    REQUIRE(fwd.ok);
    REQUIRE(adj.ok);
    REQUIRE(fd.ok);
    CHECK(fwd.value == Approx(adj.value).epsilon(1e-13));
    const double scale = MaxAbs(fd.gradient);
    REQUIRE(scale > 0);
    INFO("forward " << fwd.gradient.transpose() << "\nadjoint " << adj.gradient.transpose() << "\nfd      "
                    << fd.gradient.transpose());
    CHECK(MaxAbs(fwd.gradient - fd.gradient) / scale < 1e-6);
    CHECK(MaxAbs(adj.gradient - fd.gradient) / scale < 1e-6);
    CHECK(MaxAbs(fwd.gradient - adj.gradient) / scale < 1e-9);
    // The residual Jacobian by the forward route against finite differences.
    if (std::string(error_model->name()) == "least-squares") {
      const auto jf = objective.Evaluate(values, free, Need::kJacobian, pk::GradientRoute::kForward);
      const auto jd = objective.Evaluate(values, free, Need::kJacobian, pk::GradientRoute::kFiniteDifference);
      REQUIRE(jf.ok);
      REQUIRE(jd.ok);
      const double jscale = jd.jacobian.cwiseAbs().maxCoeff();
      CHECK((jf.jacobian - jd.jacobian).cwiseAbs().maxCoeff() / jscale < 1e-6);
      CHECK((jf.jacobian.transpose() * jf.residuals - fwd.gradient).cwiseAbs().maxCoeff() / scale < 1e-12);
    }
  }
}

TEST_CASE("flip-flop (KA = CL/V): defective A falls back to block exponentials and stays exact", "[gradient]") {
  const auto model = pk::MakeModel("1cmt_oral");
  Scenario sc{"flip-flop", "1,0,100,0,8,2,0,1,.\n", {}, {}};
  const pk::Objective objective(model, pk_test::ScenarioData(sc), 0, pk::ObjectiveOptions());
  Eigen::VectorXd values = objective.DefaultValues();
  values(0) = 0.1;  // KA
  values(1) = 3.0;  // CL
  values(2) = 30.0; // V: CL/V = KA, a double eigenvalue
  const std::vector<int> free{0, 1, 2};
  using Need = pk::Objective::Need;
  const auto fwd = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
  const auto adj = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  const auto fd = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kFiniteDifference);
  REQUIRE(fwd.ok);
  REQUIRE(adj.ok);
  const double scale = MaxAbs(fd.gradient);
  CHECK(MaxAbs(fwd.gradient - fd.gradient) / scale < 1e-6);
  CHECK(MaxAbs(adj.gradient - fd.gradient) / scale < 1e-6);
  CHECK(MaxAbs(fwd.gradient - adj.gradient) / scale < 1e-9);
  // The prediction at the double eigenvalue: C(t) = F·D·k t e^{−kt} / V.
  const double k = 0.1;
  for (int s = 0; s < 3; ++s) {
    const double t = std::vector<double>{0.25, 0.9, 1.7}[s];
    CHECK(fwd.predictions(s) == Approx(100 * k * t * std::exp(-k * t) / 30).epsilon(1e-10));
  }
}

TEST_CASE("companion route: tf1..tf4 agree with forward, adjoint and finite differences", "[gradient][companion]") {
  const auto model_name = GENERATE(as<std::string>{}, "tf1", "tf2", "tf3", "tf4");
  const auto model = pk::MakeModel(model_name);
  const int n = model->num_compartments();
  for (const Scenario& sc : Scenarios()) {
    if (!sc.extra_free.empty()) continue;  // the companion route differentiates a_i, b_i only
    INFO(model_name << " / " << sc.name);
    const pk::Objective objective(model, pk_test::ScenarioData(sc), 0, pk::ObjectiveOptions());
    Eigen::VectorXd values = objective.DefaultValues();
    std::vector<int> free;
    for (int i = 0; i < 2 * n; ++i) {
      values(i) *= 1.0 + 0.05 * i;
      free.push_back(i);
    }
    using Need = pk::Objective::Need;
    const auto comp = objective.Evaluate(values, free, Need::kJacobian, pk::GradientRoute::kCompanion);
    const auto fwd = objective.Evaluate(values, free, Need::kJacobian, pk::GradientRoute::kForward);
    const auto adj = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
    const auto fd = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kFiniteDifference);
    REQUIRE(comp.ok);
    REQUIRE(fwd.ok);
    REQUIRE(adj.ok);
    REQUIRE(fd.ok);
    CHECK(std::string(comp.route) == "companion");
    const double scale = MaxAbs(fd.gradient);
    INFO("companion " << comp.gradient.transpose() << "\nforward   " << fwd.gradient.transpose() << "\nfd        "
                      << fd.gradient.transpose());
    CHECK(MaxAbs(comp.gradient - fd.gradient) / scale < 1e-7);
    CHECK(MaxAbs(comp.gradient - fwd.gradient) / scale < 1e-9);
    CHECK(MaxAbs(comp.gradient - adj.gradient) / scale < 1e-9);
    const double jscale = fwd.jacobian.cwiseAbs().maxCoeff();
    CHECK((comp.jacobian - fwd.jacobian).cwiseAbs().maxCoeff() / jscale < 1e-9);
  }
}

TEST_CASE("companion route refuses what it cannot differentiate", "[gradient][companion]") {
  {
    const Scenario sc0{"bolus", "1,0,100,0,0,0,0,1,.\n", {}, {}};
    const pk::Objective tf0(pk::MakeModel("tf2"), pk_test::ScenarioData(sc0), 0, pk::ObjectiveOptions());
    Eigen::VectorXd v = tf0.DefaultValues();
    v(tf0.ParameterIndex("X0_1")) = 3;
    const auto ev0 = tf0.Evaluate(v, {0, 1}, pk::Objective::Need::kGradient, pk::GradientRoute::kCompanion);
    CHECK(!ev0.ok);
    CHECK_THAT(ev0.message, Catch::Contains("zero initial state"));
  }
  const Scenario sc{"bolus", "1,0,100,0,0,0,0,1,.\n", {}, {}};
  const pk::Objective compartmental(pk::MakeModel("2cmt_iv"), pk_test::ScenarioData(sc), 0, pk::ObjectiveOptions());
  const auto ev = compartmental.Evaluate(compartmental.DefaultValues(), {0, 1}, pk::Objective::Need::kGradient,
                                         pk::GradientRoute::kCompanion);
  CHECK(!ev.ok);
  CHECK_THAT(ev.message, Catch::Contains("tf<n> models only"));
  const pk::Objective tf(pk::MakeModel("tf2"), pk_test::ScenarioData(sc), 0, pk::ObjectiveOptions());
  const auto lag = tf.Evaluate(tf.DefaultValues(), {0, tf.ParameterIndex("F1")}, pk::Objective::Need::kGradient,
                               pk::GradientRoute::kCompanion);
  CHECK(!lag.ok);
}

namespace {

// ∂ŷ/∂p by the forward route (the least-squares residual Jacobian is −∂ŷ/∂p).
Eigen::MatrixXd PredictionJacobian(const pk::Objective& obj, const Eigen::VectorXd& values, const std::vector<int>& free) {
  const auto ev = obj.Evaluate(values, free, pk::Objective::Need::kJacobian, pk::GradientRoute::kForward);
  INFO(ev.message);
  REQUIRE(ev.ok);
  return -ev.jacobian.topRows(ev.predictions.size());
}

// ∂²ŷ/∂p_a∂p_b (column b of ∂J/∂p_a) by central differences of the exact Jacobian at h and h/2,
// Richardson-extrapolated: error O(h⁴).
Eigen::MatrixXd JacobianDifferences(const pk::Objective& obj, const Eigen::VectorXd& values, const std::vector<int>& free,
                                    int a) {
  Eigen::MatrixXd d[2];
  for (int level = 0; level < 2; ++level) {
    const double h = 1e-3 * std::max(std::abs(values(free[static_cast<size_t>(a)])), 0.1) / (1 << level);
    Eigen::VectorXd plus = values, minus = values;
    plus(free[static_cast<size_t>(a)]) += h;
    minus(free[static_cast<size_t>(a)]) -= h;
    d[level] = (PredictionJacobian(obj, plus, free) - PredictionJacobian(obj, minus, free)) / (2 * h);
  }
  return (4 * d[1] - d[0]) / 3;
}

// A model file with η in its rates (bound as parameters): derived coefficients −CL/V, 1/V.
const char* const kEtaRates =
    "$PROBLEM eta_rates  one compartment, oral, log-normal η on CL and V\n"
    "$PARAM\nTVKA = 1.2\nTVCL = 3\nTVV = 30\n"
    "$OMEGA\nETA_CL ~ 0.1\nETA_V ~ 0.1\n"
    "$CMT\nDEPOT dose\nCENTRAL central\n"
    "$PK\nCL = TVCL * exp(ETA_CL)\nV = TVV * exp(ETA_V)\n"
    "$ODE\nd/dt(DEPOT) = -TVKA * DEPOT\nd/dt(CENTRAL) = TVKA * DEPOT - CL / V * CENTRAL\n"
    "$OUTPUT\nCP = CENTRAL / V\n";

// A model file whose dose modifiers move with η: a bioavailability, a lag and a modelled duration
// computed in $PK (exact/moving_events.h).
const char* const kMovingDoses =
    "$PROBLEM moving_doses  one compartment, oral, F1, ALAG1 and D1 computed from η\n"
    "$PARAM\nKA = 1.2\nCL = 3\nV = 30\nTLAG = 0.6\nTVD = 2.5\n"
    "$OMEGA\nETA_F ~ 0.1\nETA_L ~ 0.1\nETA_D ~ 0.1\n"
    "$CMT\nDEPOT dose\nCENTRAL central\n"
    "$PK\nF1 = 1 / (1 + exp(-1 - ETA_F))\nALAG1 = TLAG * exp(ETA_L)\nD1 = TVD * exp(ETA_D)\n"
    "$ODE\nd/dt(DEPOT) = -KA * DEPOT\nd/dt(CENTRAL) = KA * DEPOT - CL / V * CENTRAL\n"
    "$OUTPUT\nCP = CENTRAL / V\n";

// The scenarios a model's higher derivatives are checked on: every one of Scenarios() for the
// catalogue and kEtaRates (F, ALAG, R and D estimated too); for kMovingDoses, which computes its
// modifiers, those that estimate none, and modelled durations (RATE=-2) its D1 serves.
std::vector<Scenario> HigherOrderScenarios(const pk::Model& model) {
  if (model.declarations().computed_modifiers.empty()) {
    // Moving doses through a reset, modelled and constant rates into steady states.
    std::vector<Scenario> s = Scenarios();
    s.push_back({"reset with a lag", "1,0,100,0,0,0,0,1,.\n1,4,0,0,0,0,0,3,.\n1,4.5,70,0,0,0,0,1,.\n", {"ALAG1"}, {0.7}});
    s.push_back({"ss1 constant infusion at a modelled rate", "1,0,0,-1,0,0,1,1,.\n", {"R1"}, {12.0}});
    s.push_back({"ss2 constant infusion after a lagged dose", "1,0,50,0,0,0,0,1,.\n1,0.2,0,10,0,0,2,1,.\n", {"ALAG1"}, {0.1}});
    s.push_back({"a constant input", "1,0,100,0,6,2,0,1,.\n", {"K0_1"}, {0.8}});
    s.push_back({"ss1 constant infusion with a constant input", "1,0,0,10,0,0,1,1,.\n", {"K0_1"}, {0.8}});
    return s;
  }
  std::vector<Scenario> s;
  for (const Scenario& sc : Scenarios()) {
    if (sc.extra_free.empty()) s.push_back(sc);
  }
  s.push_back({"modelled duration", "1,0,100,-2,0,0,0,1,.\n1,7,80,-2,0,0,0,1,.\n", {}, {}});
  s.push_back({"ss1 modelled duration, then ADDL", "1,0,100,-2,8,2,1,1,.\n", {}, {}});
  return s;
}

// η at values away from 0, so that every part of a computed modifier is exercised.
void MoveEtas(const pk::Model& model, const std::vector<int>& free, Eigen::VectorXd* values) {
  for (int i : free) {
    if (i < model.num_parameters() && model.is_eta(i)) (*values)(i) = i % 2 ? 0.15 : -0.2;
  }
}

// The scale each pair's second derivative is compared on: its differences' largest entry, or, for a
// derivative that vanishes (C_ss of a constant infusion along V, say), the others' scale per unit of
// relative change of the parameters (as CheckThirdDerivatives takes it), 1e-4 of the largest: the
// differences' own noise sits below that.
std::vector<double> PairScales(const Eigen::VectorXd& values, const std::vector<int>& free,
                               const std::vector<std::pair<int, int>>& pairs,
                               const std::vector<Eigen::VectorXd>& differences) {
  const auto unit = [&](const std::pair<int, int>& ab) {
    return std::max(std::abs(values(free[static_cast<size_t>(ab.first)])), 0.1) *
           std::max(std::abs(values(free[static_cast<size_t>(ab.second)])), 0.1);
  };
  double largest = 0;
  for (size_t k = 0; k < pairs.size(); ++k) largest = std::max(largest, unit(pairs[k]) * differences[k].cwiseAbs().maxCoeff());
  std::vector<double> scales;
  for (size_t k = 0; k < pairs.size(); ++k) {
    scales.push_back(std::max(differences[k].cwiseAbs().maxCoeff(), 1e-4 * largest / unit(pairs[k])));
  }
  return scales;
}

}  // namespace

TEST_CASE("exact second derivatives of the predictions agree with differences of the exact Jacobian",
          "[gradient][second-order]") {
  std::vector<std::pair<std::string, std::shared_ptr<const pk::Model>>> models;
  for (const char* name : {"1cmt_iv", "1cmt_oral", "2cmt_oral", "3cmt_iv"}) models.emplace_back(name, pk::MakeModel(name));
  models.emplace_back("eta_rates.pkm", pk::ParseModel(kEtaRates, "eta_rates.pkm", pk::RandomEffects::kParameters));
  models.emplace_back("moving_doses.pkm", pk::ParseModel(kMovingDoses, "moving_doses.pkm", pk::RandomEffects::kParameters));
  int compared = 0, moving = 0;
  for (const auto& [name, model] : models) {
    for (const Scenario& sc : HigherOrderScenarios(*model)) {
     // Eigen-coordinates (but steady states) or e^{Mh}; when a dose moves, the jet engine either way.
     const bool moves = !sc.extra_free.empty() || !model->declarations().computed_modifiers.empty();
     for (const bool modal : {true, false}) {
      if (moves && modal) continue;
      INFO(name << " / " << sc.name << (modal ? " / eigen-coordinates" : " / e^{Mh}"));
      pk::ObjectiveOptions options;
      options.modal_propagation = modal;
      const pk::Objective obj(model, pk_test::ScenarioData(sc), 0, options);
      Eigen::VectorXd values;
      std::vector<int> free;
      pk_test::ScenarioValues(obj, sc, &values, &free);
      MoveEtas(*model, free, &values);
      std::vector<std::pair<int, int>> pairs;
      const int p = static_cast<int>(free.size());
      for (int a = 0; a < p; ++a) {
        for (int b = a; b < p; ++b) pairs.emplace_back(a, b);
      }
      std::vector<Eigen::VectorXd> second;
      std::string why;
      REQUIRE(obj.SecondDerivatives(values, free, pairs, &second, &why));
      REQUIRE(second.size() == pairs.size());
      std::vector<Eigen::MatrixXd> fd;
      for (int a = 0; a < p; ++a) fd.push_back(JacobianDifferences(obj, values, free, a));
      std::vector<Eigen::VectorXd> differences;
      for (const auto& [a, b] : pairs) differences.push_back(fd[static_cast<size_t>(a)].col(b));
      const std::vector<double> scales = PairScales(values, free, pairs, differences);
      for (size_t k = 0; k < pairs.size(); ++k) {
        const auto [a, b] = pairs[k];
        const Eigen::VectorXd want = fd[static_cast<size_t>(a)].col(b), other = fd[static_cast<size_t>(b)].col(a);
        const double scale = scales[k];
        INFO("pair " << a << "," << b << "\nexact " << second[k].transpose() << "\nfd    " << want.transpose());
        CHECK((second[k] - want).cwiseAbs().maxCoeff() / scale < 1e-7);
        CHECK((second[k] - other).cwiseAbs().maxCoeff() / scale < 1e-7);  // symmetric
        ++compared;
        moving += moves;
      }
     }
    }
  }
  CHECK(compared > 200);
  CHECK(moving > 150);
}

TEST_CASE("exact second derivatives refuse what they cannot differentiate", "[gradient][second-order]") {
  const Scenario& lag = Scenarios()[7];
  REQUIRE(std::string(lag.name) == "lag");
  const pk::Objective obj(pk::MakeModel("1cmt_oral"), pk_test::ScenarioData(lag), 0, pk::ObjectiveOptions());
  Eigen::VectorXd values;
  std::vector<int> free;
  pk_test::ScenarioValues(obj, lag, &values, &free);
  std::vector<Eigen::VectorXd> second;
  std::string why;
  std::vector<int> with_sigma = free;
  with_sigma.push_back(static_cast<int>(values.size()));  // σ: beyond the layout
  CHECK_FALSE(obj.SecondDerivatives(values, with_sigma, {{0, 0}}, &second, &why));
  CHECK_THAT(why, Catch::Contains("not σ"));
  // Continuous records on the ODE propagator have none.
  const auto cont = std::make_shared<pk::Dataset>(pk::ParseDataset(
      "ID,TIME,AMT,DV,CONT\n1,0,100,.,0\n1,1,0,3,1\n1,2,0,2,1\n1,3,0,1.5,0\n", "cont.csv"));
  const pk::Objective ode(pk::MakeModel("1cmt_iv_mm"), cont, 0, pk::ObjectiveOptions());
  values = ode.DefaultValues();
  for (const std::vector<int>& along : {std::vector<int>{0, 1}, std::vector<int>{0, ode.ParameterIndex("F1")}}) {
    CHECK_FALSE(ode.SecondDerivatives(values, along, {{0, 1}}, &second, &why));
    CHECK_THAT(why, Catch::Contains("continuous records"));
  }
}

namespace {

// The catalogue's 1cmt_oral as a nonlinear functor (θ = KA, CL, V): its ODE second order must equal
// the linear model's exact one.
struct OralAsOde {
  template <typename T>
  void Rhs(const T* x, const T* theta, T* dxdt) const {
    dxdt[0] = -theta[0] * x[0];
    dxdt[1] = theta[0] * x[0] - theta[1] / theta[2] * x[1];
  }
  template <typename T>
  T Output(int, const T* x, const T* theta) const { return x[1] / theta[2]; }
};

// ∂²ŷ/∂p_a∂p_b for every pair a ≤ b of `free`'s positions, with what each is checked against:
// column b of the Richardson differences of the Jacobian in p_a.
struct PairsAgainstDifferences {
  std::vector<std::pair<int, int>> pairs;
  std::vector<Eigen::VectorXd> second, differences;
};

PairsAgainstDifferences AllPairs(const pk::Objective& obj, const Eigen::VectorXd& values, const std::vector<int>& free) {
  PairsAgainstDifferences c;
  const int p = static_cast<int>(free.size());
  for (int a = 0; a < p; ++a) {
    for (int b = a; b < p; ++b) c.pairs.emplace_back(a, b);
  }
  std::string why;
  REQUIRE(obj.SecondDerivatives(values, free, c.pairs, &c.second, &why));
  std::vector<Eigen::MatrixXd> fd;
  for (int a = 0; a < p; ++a) fd.push_back(JacobianDifferences(obj, values, free, a));
  for (const auto& [a, b] : c.pairs) c.differences.push_back(fd[static_cast<size_t>(a)].col(b));
  return c;
}

// Each of c's pairs against its differences, to `tolerance` on its PairScales scale; how many.
int CheckPairs(const PairsAgainstDifferences& c, const Eigen::VectorXd& values, const std::vector<int>& free,
               double tolerance) {
  const std::vector<double> scales = PairScales(values, free, c.pairs, c.differences);
  for (size_t k = 0; k < c.pairs.size(); ++k) {
    INFO("pair " << c.pairs[k].first << "," << c.pairs[k].second << "\nexact " << c.second[k].transpose() << "\nfd    "
                 << c.differences[k].transpose());
    CHECK((c.second[k] - c.differences[k]).cwiseAbs().maxCoeff() / scales[k] < tolerance);
  }
  return static_cast<int>(c.pairs.size());
}

std::shared_ptr<const pk::Model> OralOdeTwin() {
  pk::OdeModelSpec spec;
  spec.name = "1cmt_oral_ode";
  spec.compartments = {"DEPOT", "CENTRAL"};
  spec.parameters = {{"KA", 1.5}, {"CL", 3.0}, {"V", 30.0}};
  spec.central = 2;
  spec.default_dose = 1;
  return pk::MakeOdeModel(spec, OralAsOde());
}

}  // namespace

TEST_CASE("second-order sensitivities of a second output, with an effect sample at Ce = 0", "[gradient][second-order][ode]") {
  // 1cmt_iv_emax's effect E = E0 + EMAX·Ce^HILL/(EC50^HILL + Ce^HILL) at t = 0, before Ce moves: the
  // hyper-dual power meets 0^HILL with infinite second derivative along directions that do not move
  // Ce, which must give 0, not NaN.
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(
      "ID,TIME,AMT,DVID,DV\n1,0,100,.,.\n1,0,0,2,10\n1,1,0,2,30\n1,2,0,1,2\n1,4,0,2,25\n1,8,0,1,1\n", "e.csv"));
  pk::ObjectiveOptions tight;
  tight.ode.relative_tolerance = 1e-12;
  tight.ode.absolute_tolerance = 1e-14;
  const pk::Objective obj(pk::MakeModel("1cmt_iv_emax"), data, 0, tight);
  Eigen::VectorXd values = obj.DefaultValues();
  const int hill = obj.ParameterIndex("HILL");
  REQUIRE(hill >= 0);
  values(hill) = 1.5;  // f'' of Ce^1.5 is infinite at Ce = 0
  std::vector<int> free;
  for (int i = 0; i < obj.model().num_parameters(); ++i) free.push_back(i);
  const PairsAgainstDifferences c = AllPairs(obj, values, free);
  const std::vector<Eigen::VectorXd>& second = c.second;
  for (size_t k = 0; k < c.pairs.size(); ++k) {
    const auto [a, b] = c.pairs[k];
    const Eigen::VectorXd& want = c.differences[k];
    REQUIRE(second[k].allFinite());
    CHECK(second[k](0) == 0);  // the sample at Ce = 0 does not move with any parameter but E0 (linear)
    const double scale = std::max(want.cwiseAbs().maxCoeff(), 1e-12);
    INFO("pair " << a << "," << b << "\node " << second[k].transpose() << "\nfd  " << want.transpose());
    CHECK((second[k] - want).cwiseAbs().maxCoeff() / scale < 1e-6);
  }
}

TEST_CASE("second-order sensitivities on the ODE propagator agree with differences and with Φ/Γ's",
          "[gradient][second-order][ode]") {
  pk::ObjectiveOptions tight;
  tight.ode.relative_tolerance = 1e-12;
  tight.ode.absolute_tolerance = 1e-14;
  int compared = 0;
  for (const Scenario& sc : pk_test::OdeScenarios()) {
    // F, ALAG, R, D and X0 estimated move the doses: the pairs along them take the jet engine.
    for (const pk::Propagator integrator : {pk::Propagator::kRungeKutta, pk::Propagator::kOde}) {
      if (pk_test::kSanitized && integrator == pk::Propagator::kOde) continue;  // the route is the same
      if (integrator == pk::Propagator::kOde && !sc.extra_free.empty()) continue;  // and so is its jet pass
      // The sanitizer build takes the jets on one moving scenario here (the other tests cover more).
      if (pk_test::kSanitized && !sc.extra_free.empty() && sc.name != std::string("lag")) continue;
      tight.propagator = integrator;
      // Nonlinear models against central differences of their forward-sensitivity Jacobian.
      for (const char* name : {"1cmt_iv_mm", "1cmt_oral_mm", "1cmt_iv_emax"}) {
        if (!pk_test::RunsUnderThisBuild(name, {"1cmt_oral_mm"})) continue;
        INFO(name << " / " << sc.name << (integrator == pk::Propagator::kOde ? " / CVODES" : " / Dormand-Prince"));
        const pk::Objective obj(pk::MakeModel(name), pk_test::ScenarioData(sc), 0, tight);
        Eigen::VectorXd values;
        std::vector<int> free;
        pk_test::ScenarioValues(obj, sc, &values, &free);
        compared += CheckPairs(AllPairs(obj, values, free), values, free, 1e-6);
      }
      // A linear model written as ODEs against the linear model's exact second order (with moving
      // doses: the two jet engines, ODE and Φ/Γ, against each other).
      INFO("1cmt_oral as ODEs / " << sc.name);
      const auto data = pk_test::ScenarioData(sc);
      const pk::Objective ode(OralOdeTwin(), data, 0, tight);
      const pk::Objective exact(pk::MakeModel("1cmt_oral"), data, 0, pk::ObjectiveOptions());
      Eigen::VectorXd at_ode, at_exact;
      std::vector<int> free, free_exact;
      pk_test::ScenarioValues(ode, sc, &at_ode, &free);
      pk_test::ScenarioValues(exact, sc, &at_exact, &free_exact);
      REQUIRE(free == free_exact);
      at_ode.head(3) << 1.3, 2.7, 24.0;
      at_exact.head(3) = at_ode.head(3);
      std::vector<std::pair<int, int>> pairs;
      for (int i = 0; i < static_cast<int>(free.size()); ++i) {
        for (int j = i; j < static_cast<int>(free.size()); ++j) pairs.emplace_back(i, j);
      }
      std::vector<Eigen::VectorXd> a, b;
      std::string why;
      REQUIRE(ode.SecondDerivatives(at_ode, free, pairs, &a, &why));
      REQUIRE(exact.SecondDerivatives(at_exact, free, pairs, &b, &why));
      for (size_t k = 0; k < pairs.size(); ++k) {
        const double scale = std::max(b[k].cwiseAbs().maxCoeff(), 1e-12);
        CHECK((a[k] - b[k]).cwiseAbs().maxCoeff() / scale < 1e-8);
        ++compared;
      }
    }
  }
  CHECK(compared > (pk_test::kSanitized ? 50 : 100));  // the sanitizer build checks a subset
}

namespace {

// ∂³ŷ/∂p_a∂p_b∂p_c by Richardson-extrapolated central differences, in p_c, of the exact second
// derivatives of pair (a, b).
Eigen::VectorXd SecondDifferences(const pk::Objective& obj, const Eigen::VectorXd& values, const std::vector<int>& free,
                                  int a, int b, int c) {
  Eigen::VectorXd d[2];
  std::string why;
  for (int level = 0; level < 2; ++level) {
    const auto fc = static_cast<size_t>(c);
    const double h = 1e-3 * std::max(std::abs(values(free[fc])), 0.1) / (1 << level);
    Eigen::VectorXd plus = values, minus = values;
    plus(free[fc]) += h;
    minus(free[fc]) -= h;
    std::vector<Eigen::VectorXd> up, down;
    REQUIRE(obj.SecondDerivatives(plus, free, {{a, b}}, &up, &why));
    REQUIRE(obj.SecondDerivatives(minus, free, {{a, b}}, &down, &why));
    d[level] = (up[0] - down[0]) / (2 * h);
  }
  return (4 * d[1] - d[0]) / 3;
}

// Every sorted triple of `free`'s positions against differences of the second derivatives; returns
// how many were compared.
int CheckThirdDerivatives(const pk::Objective& obj, const Eigen::VectorXd& values, const std::vector<int>& free,
                          double tolerance) {
  std::vector<std::array<int, 3>> triples;
  const int p = static_cast<int>(free.size());
  for (int a = 0; a < p; ++a) {
    for (int b = a; b < p; ++b) {
      for (int c = b; c < p; ++c) triples.push_back({a, b, c});
    }
  }
  std::vector<Eigen::VectorXd> third;
  std::string why;
  INFO(why);
  REQUIRE(obj.ThirdDerivatives(values, free, triples, &third, &why));
  REQUIRE(third.size() == triples.size());
  // A triple whose derivative vanishes is compared on the scale of the others, each taken per unit of
  // relative change of its parameters (∂³ŷ·|p_a p_b p_c|, the differences' own scale).
  const auto unit = [&](const std::array<int, 3>& t) {
    double u = 1;
    for (int i : t) u *= std::max(std::abs(values(free[static_cast<size_t>(i)])), 0.1);
    return u;
  };
  double largest = 0;
  for (size_t t = 0; t < triples.size(); ++t) largest = std::max(largest, unit(triples[t]) * third[t].cwiseAbs().maxCoeff());
  for (size_t t = 0; t < triples.size(); ++t) {
    const auto [a, b, c] = triples[t];
    const Eigen::VectorXd want = SecondDifferences(obj, values, free, a, b, c);
    const double scale = std::max(want.cwiseAbs().maxCoeff(), 1e-6 * largest / unit(triples[t]));
    INFO("triple " << a << "," << b << "," << c << "\nexact " << third[t].transpose() << "\nfd    " << want.transpose());
    CHECK((third[t] - want).cwiseAbs().maxCoeff() / scale < tolerance);
  }
  return static_cast<int>(triples.size());
}

}  // namespace

TEST_CASE("third derivatives of the predictions agree with differences of the second ones", "[gradient][second-order]") {
  int compared = 0;
  // Linear models on Φ/Γ: catalogue ones and a file with η in its rates (derived coefficients).
  std::vector<std::pair<std::string, std::shared_ptr<const pk::Model>>> linear;
  for (const char* name : {"1cmt_iv", "1cmt_oral", "2cmt_oral"}) linear.emplace_back(name, pk::MakeModel(name));
  linear.emplace_back("eta_rates.pkm", pk::ParseModel(kEtaRates, "eta_rates.pkm", pk::RandomEffects::kParameters));
  linear.emplace_back("moving_doses.pkm", pk::ParseModel(kMovingDoses, "moving_doses.pkm", pk::RandomEffects::kParameters));
  for (const auto& [name, model] : linear) {
    for (const Scenario& sc : HigherOrderScenarios(*model)) {
      // A moving dose takes a pass per triple: the sanitizer build checks a few of those.
      const bool moves = !sc.extra_free.empty() || !model->declarations().computed_modifiers.empty();
      if (pk_test::kSanitized && moves && name != "moving_doses.pkm" && name != "1cmt_oral") continue;
      INFO(name << " / " << sc.name);
      const pk::Objective obj(model, pk_test::ScenarioData(sc), 0, pk::ObjectiveOptions());
      Eigen::VectorXd values;
      std::vector<int> free;
      pk_test::ScenarioValues(obj, sc, &values, &free);
      MoveEtas(*model, free, &values);
      compared += CheckThirdDerivatives(obj, values, free, 1e-6);
    }
  }
  // Nonlinear models on the ODE propagator, steady states included.
  pk::ObjectiveOptions tight;
  tight.ode.relative_tolerance = 1e-12;
  tight.ode.absolute_tolerance = 1e-14;
  for (const Scenario& sc : pk_test::OdeScenarios()) {
    for (const char* name : {"1cmt_iv_mm", "1cmt_iv_emax"}) {
      // A moving dose takes a pass per triple (ode/moving_events.h): 1cmt_iv_mm covers them.
      if (!sc.extra_free.empty() && (name != std::string("1cmt_iv_mm") || pk_test::kSanitized)) continue;
      INFO(name << " / " << sc.name);
      const pk::Objective obj(pk::MakeModel(name), pk_test::ScenarioData(sc), 0, tight);
      Eigen::VectorXd values;
      std::vector<int> free;
      pk_test::ScenarioValues(obj, sc, &values, &free);
      if (free.size() > 3) free.resize(3);  // 1cmt_iv_emax: the PK parameters and E0's neighbour
      compared += CheckThirdDerivatives(obj, values, free, 1e-5);
    }
  }
  CHECK(compared > 300);
}

TEST_CASE("higher derivatives of a nonlinear model file whose doses move with η (ODE jets)",
          "[gradient][second-order][ode]") {
  // kMovingDoses with Michaelis–Menten elimination: F1, ALAG1 and D1 computed from η, on
  // Dormand–Prince; pairs and triples along the η take ode/moving_events.h, the others
  // second_order.h's stacked pass.
  std::string text = kMovingDoses;
  const auto replace = [&](const std::string& from, const std::string& to) { text.replace(text.find(from), from.size(), to); };
  replace("CL = 3\n", "VMAX = 20\nKM = 3\n");
  replace("CL / V * CENTRAL", "VMAX * CENTRAL / (KM * V + CENTRAL)");
  const auto model = pk::ParseModel(text, "moving_mm.pkm", pk::RandomEffects::kParameters);
  REQUIRE_FALSE(model->is_linear());
  pk::ObjectiveOptions tight;
  tight.propagator = pk::Propagator::kRungeKutta;
  tight.ode.relative_tolerance = 1e-12;
  tight.ode.absolute_tolerance = 1e-14;
  int compared = 0;
  for (const Scenario& sc : HigherOrderScenarios(*model)) {
    if (pk_test::kSanitized && compared > 0) break;  // one scenario under the sanitizers
    INFO(sc.name);
    const pk::Objective obj(model, pk_test::ScenarioData(sc), 0, tight);
    Eigen::VectorXd values;
    std::vector<int> all;
    pk_test::ScenarioValues(obj, sc, &values, &all);
    MoveEtas(*model, all, &values);
    std::vector<int> free;
    for (const char* name : {"VMAX", "TLAG", "ETA_F", "ETA_L", "ETA_D"}) free.push_back(obj.ParameterIndex(name));
    compared += CheckPairs(AllPairs(obj, values, free), values, free, 1e-6);
    free.erase(free.begin() + 1);  // the triples along VMAX and the three η
    compared += CheckThirdDerivatives(obj, values, free, 1e-5);
  }
  CHECK(compared >= (pk_test::kSanitized ? 35 : 200));
}

namespace {

// A file whose F1 and ALAG1 read η and a weight that changes between doses (two parameter sets), with
// two outputs chosen by DVID and 40 samples at distinct intervals (more distinct steps than the jet
// visitor caches); `nonlinear` puts Michaelis–Menten elimination on the ODE propagator instead.
std::shared_ptr<const pk::Model> MovingCovariateModel(bool nonlinear) {
  std::string text =
      "$PROBLEM moving_cov  oral, F1 and ALAG1 from η and a time-varying weight, two outputs\n"
      "$PARAM\nKA = 1.2\nCL = 3\nV = 30\nTLAG = 0.4\nKM = 2\n$COVARIATE\nWT kg\n"
      "$OMEGA\nETA_F ~ 0.1\nETA_L ~ 0.1\n$CMT\nDEPOT dose\nCENTRAL central\n"
      "$PK\nF1 = exp(ETA_F) * (WT / 70)^0.5\nALAG1 = TLAG * exp(ETA_L)\nCLI = CL * (WT / 70)^0.75\n"
      "$ODE\nd/dt(DEPOT) = -KA * DEPOT\nd/dt(CENTRAL) = KA * DEPOT - CLI / V * CENTRAL * KM\n"
      "$OUTPUT\nCP = CENTRAL / V\nAD = DEPOT\n";
  if (nonlinear) {
    text.replace(text.find("CLI / V * CENTRAL * KM"), 22, "CLI * CENTRAL / (V + CENTRAL / KM)");
  }
  return pk::ParseModel(text, "moving_cov.pkm", pk::RandomEffects::kParameters);
}

// modelled_rate: the doses at 12 and 24 h are infusions at the rate R1 (RATE = -1).
std::shared_ptr<pk::Dataset> MovingCovariateData(bool modelled_rate = false) {
  std::vector<std::pair<double, std::string>> rows = {
      {0, "1,0,100,0,0,0,0,1,.,1,60"}, {12, std::string("1,12,100,") + (modelled_rate ? "-1" : "0") + ",12,1,0,1,.,1,75"}};
  for (int k = 1; k <= 40; ++k) {
    const double t = 0.2 * std::pow(k, 1.4);
    std::ostringstream row;
    row << "1," << t << ",0,0,0,0,0,0," << 1 + 0.1 * k << "," << (k % 5 == 0 ? 2 : 1) << "," << (t < 10 ? 60 : 75);
    rows.push_back({t, row.str()});
  }
  std::stable_sort(rows.begin(), rows.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  std::string csv = "ID,TIME,AMT,RATE,II,ADDL,SS,EVID,DV,DVID,WT\n";
  for (const auto& r : rows) csv += r.second + "\n";
  return std::make_shared<pk::Dataset>(pk::ParseDataset(csv, "moving_cov.csv"));
}

}  // namespace

TEST_CASE("moving doses with a time-varying covariate, two outputs and many distinct steps (jets)",
          "[gradient][second-order]") {
  int compared = 0;
  for (const bool nonlinear : {false, true}) {
    if (pk_test::kSanitized && nonlinear) continue;
    INFO((nonlinear ? "Michaelis-Menten on Dormand-Prince" : "linear on Φ/Γ"));
    const auto model = MovingCovariateModel(nonlinear);
    REQUIRE(model->is_linear() == !nonlinear);
    pk::ObjectiveOptions options;
    options.propagator = nonlinear ? pk::Propagator::kRungeKutta : pk::Propagator::kAuto;
    options.ode.relative_tolerance = 1e-12;
    options.ode.absolute_tolerance = 1e-14;
    const pk::Objective obj(model, MovingCovariateData(), 0, options);
    Eigen::VectorXd values = obj.DefaultValues();
    values(obj.ParameterIndex("ETA_F")) = -0.2;
    values(obj.ParameterIndex("ETA_L")) = 0.15;
    std::vector<int> free;
    for (const char* name : {"KA", "CL", "TLAG", "ETA_F", "ETA_L"}) free.push_back(obj.ParameterIndex(name));
    compared += CheckPairs(AllPairs(obj, values, free), values, free, nonlinear ? 1e-6 : 1e-7);
    if (nonlinear) free = {free[1], free[3], free[4]};
    compared += CheckThirdDerivatives(obj, values, free, nonlinear ? 1e-5 : 1e-6);
  }
  CHECK(compared >= (pk_test::kSanitized ? 50 : 75));
}

TEST_CASE("Dormand-Prince's adjoint where du/dp changes between segments (infusions at a modelled rate)",
          "[gradient][rk][adjoint]") {
  // The adjoint's stored segments share ∂θ/∂p and ∂u/∂p with the segment before while they are the
  // same, and hold their own from where they change: ∂u/∂R1 is nonzero during the infusions at the
  // modelled rate R1 and zero between them, and the weight changes at 10 h. The gradient must see
  // each segment's own. Also with every segment replayed (adjoint_store_all_segments = false).
  using Need = pk::Objective::Need;
  for (const bool store_all : {true, false}) {
    INFO("store all segments: " << store_all);
    pk::ObjectiveOptions options;
    options.propagator = pk::Propagator::kRungeKutta;
    options.ode.relative_tolerance = 1e-11;
    options.ode.absolute_tolerance = 1e-13;
    options.ode.adjoint_store_all_segments = store_all;
    const pk::Objective obj(MovingCovariateModel(true), MovingCovariateData(true), 0, options);
    Eigen::VectorXd values = obj.DefaultValues();
    values(obj.ParameterIndex("ETA_F")) = -0.2;
    values(obj.ParameterIndex("ETA_L")) = 0.15;
    values(obj.ParameterIndex("R1")) = 35;
    std::vector<int> free;
    for (int i = 0; i < static_cast<int>(values.size()); ++i) free.push_back(i);
    const auto fwd = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
    const auto adj = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
    REQUIRE(fwd.ok);
    REQUIRE(adj.ok);
    const double scale = fwd.gradient.cwiseAbs().maxCoeff();
    INFO("forward " << fwd.gradient.transpose() << "\nadjoint " << adj.gradient.transpose());
    CHECK((adj.gradient - fwd.gradient).cwiseAbs().maxCoeff() <= 1e-7 * scale);
  }
}

TEST_CASE("higher derivatives of an output with a baseline (its offset d(θ) by AD)", "[gradient][second-order]") {
  // Oral with an effect compartment; E's baseline reads a time-varying weight and two η (a derived
  // coefficient of the offset), and F1 = exp(ETA_F) moves the doses (the jets' pairs and triples).
  const auto model = pk::ParseModel(
      "$PROBLEM baseline_cov  oral with an effect compartment, E = E0·(WT/70)^0.3·exp(ETA_E + ETA_CL/2) + SLOPE·CE\n"
      "$PARAM\nKA = 1.2\nCL = 3\nV = 30\nKE0 = 0.4\nE0 = 10\nSLOPE = 2\n$COVARIATE\nWT kg\n"
      "$OMEGA\nETA_CL ~ 0.1\nETA_E ~ 0.1\nETA_F ~ 0.1\n$CMT\nDEPOT dose\nCENTRAL central\nEFFECT\n"
      "$PK\nCLI = CL * exp(ETA_CL) * (WT / 70)^0.75\nF1 = exp(ETA_F)\n"
      "$ODE\nC = CENTRAL / V\nd/dt(DEPOT) = -KA * DEPOT\nd/dt(CENTRAL) = KA * DEPOT - CLI * C\n"
      "d/dt(EFFECT) = KE0 * (C - EFFECT)\n"
      "$OUTPUT\nCP = C\nE = E0 * (WT / 70)^0.3 * exp(ETA_E + ETA_CL / 2) + SLOPE * EFFECT\n",
      "baseline_cov.pkm", pk::RandomEffects::kParameters);
  const auto* linear = dynamic_cast<const pk::LinearModel*>(model.get());
  INFO(pk::WhyNotLinear(*model));
  REQUIRE(linear != nullptr);
  REQUIRE(linear->has_output_offsets());
  const pk::Objective obj(model, MovingCovariateData(), 0, pk::ObjectiveOptions());
  Eigen::VectorXd values = obj.DefaultValues();
  values(obj.ParameterIndex("ETA_CL")) = 0.1;
  values(obj.ParameterIndex("ETA_E")) = -0.15;
  values(obj.ParameterIndex("ETA_F")) = -0.2;
  std::vector<int> free;
  for (const char* name : {"KA", "CL", "E0", "SLOPE", "ETA_CL", "ETA_E", "ETA_F"}) free.push_back(obj.ParameterIndex(name));
  // The first order: the Jacobian against Richardson differences of the predictions.
  const Eigen::MatrixXd jacobian = PredictionJacobian(obj, values, free);
  for (size_t a = 0; a < free.size(); ++a) {
    Eigen::VectorXd d[2];
    for (int level = 0; level < 2; ++level) {
      const double h = 1e-3 * std::max(std::abs(values(free[a])), 0.1) / (1 << level);
      Eigen::VectorXd plus = values, minus = values, up, down;
      plus(free[a]) += h;
      minus(free[a]) -= h;
      std::string why;
      REQUIRE(obj.Sensitivities(plus, free, &up, nullptr, &why));
      REQUIRE(obj.Sensitivities(minus, free, &down, nullptr, &why));
      d[level] = (up - down) / (2 * h);
    }
    const Eigen::VectorXd want = (4 * d[1] - d[0]) / 3;
    INFO("parameter " << a << "\nexact " << jacobian.col(static_cast<Eigen::Index>(a)).transpose() << "\nfd    "
                      << want.transpose());
    CHECK((jacobian.col(static_cast<Eigen::Index>(a)) - want).cwiseAbs().maxCoeff() / want.cwiseAbs().maxCoeff() <
          1e-8);
  }
  // The adjoint routes (Padé and eigen-coordinates, without the moving ETA_F) against the forward one.
  for (const bool moving : {true, false}) {
    std::vector<int> along = free;
    if (!moving) along.pop_back();
    for (const bool modal : {true, false}) {
      pk::ObjectiveOptions options;
      options.modal_propagation = modal;
      const pk::Objective route(model, MovingCovariateData(), 0, options);
      const auto forward = route.Evaluate(values, along, pk::Objective::Need::kGradient, pk::GradientRoute::kForward);
      const auto adjoint = route.Evaluate(values, along, pk::Objective::Need::kGradient, pk::GradientRoute::kAdjoint);
      REQUIRE((forward.ok && adjoint.ok));
      INFO("moving " << moving << ", modal " << modal << "\nforward " << forward.gradient.transpose() << "\nadjoint "
                     << adjoint.gradient.transpose());
      CHECK((forward.gradient - adjoint.gradient).cwiseAbs().maxCoeff() / forward.gradient.cwiseAbs().maxCoeff() <
            1e-10);
    }
  }
  // The same objective integrated (Dormand–Prince, c·x + d in its output function) at rtol 1e-12: its
  // predictions and gradient sample the time-varying weight's sets as Φ/Γ's post-correction does;
  // its higher orders are Φ/Γ's with the offset's part whatever the propagator.
  pk::ObjectiveOptions integrated;
  integrated.propagator = pk::Propagator::kRungeKutta;
  integrated.ode.relative_tolerance = 1e-12;
  integrated.ode.absolute_tolerance = 1e-14;
  const pk::Objective ode(model, MovingCovariateData(), 0, integrated);
  {
    const auto a = obj.Evaluate(values, free, pk::Objective::Need::kGradient, pk::GradientRoute::kForward);
    const auto b = ode.Evaluate(values, free, pk::Objective::Need::kGradient, pk::GradientRoute::kForward);
    REQUIRE((a.ok && b.ok));
    CHECK(std::string(b.propagator) == "rk");
    CHECK((a.predictions - b.predictions).cwiseAbs().maxCoeff() < 1e-9 * a.predictions.cwiseAbs().maxCoeff());
    CHECK((a.gradient - b.gradient).cwiseAbs().maxCoeff() < 1e-7 * a.gradient.cwiseAbs().maxCoeff());
    // Central differences of the predictions (the finite-difference route's Jacobian) add ∂d exactly.
    const auto fdj = obj.Evaluate(values, free, pk::Objective::Need::kJacobian, pk::GradientRoute::kFiniteDifference);
    REQUIRE(fdj.ok);
    const Eigen::MatrixXd jf = fdj.jacobian.topRows(fdj.predictions.size());
    CHECK((jf + jacobian).cwiseAbs().maxCoeff() < 1e-5 * jacobian.cwiseAbs().maxCoeff());
    std::vector<Eigen::VectorXd> exact2, ode2;
    std::string why;
    const std::vector<std::pair<int, int>> pairs = {{2, 5}, {4, 5}, {5, 5}, {1, 6}};
    REQUIRE(obj.SecondDerivatives(values, free, pairs, &exact2, &why));
    REQUIRE(ode.SecondDerivatives(values, free, pairs, &ode2, &why));
    for (size_t k = 0; k < pairs.size(); ++k) CHECK((exact2[k] - ode2[k]).cwiseAbs().maxCoeff() == 0);
    CHECK(exact2[2].cwiseAbs().maxCoeff() > 0);  // ∂²/∂ETA_E² of E = E0·…·exp(ETA_E + …)
  }
  int compared = CheckPairs(AllPairs(obj, values, free), values, free, 1e-7);
  free = {free[1], free[2], free[4], free[5], free[6]};
  compared += CheckThirdDerivatives(obj, values, free, 1e-6);
  CHECK(compared == 28 + 35);
}

TEST_CASE("a zero lag carrying a derivative: the ODE and Φ/Γ jets agree", "[gradient][second-order][ode]") {
  // ALAG1 = 0 and free: each dose's step has length 0 with a part (a one-sided derivative, which
  // central differences cannot check), so the two exact routes are checked against each other.
  const Scenario sc{"zero lag", "1,0,100,0,6,2,0,1,.\n1,14,0,0,0,0,0,3,.\n1,14.5,60,0,0,0,0,1,.\n", {"ALAG1"}, {0.0}};
  const auto data = pk_test::ScenarioData(sc);
  pk::ObjectiveOptions tight;
  tight.propagator = pk::Propagator::kRungeKutta;
  tight.ode.relative_tolerance = 1e-12;
  tight.ode.absolute_tolerance = 1e-14;
  const pk::Objective ode(OralOdeTwin(), data, 0, tight);
  const pk::Objective exact(pk::MakeModel("1cmt_oral"), data, 0, pk::ObjectiveOptions());
  Eigen::VectorXd at_ode, at_exact;
  std::vector<int> free, free_exact;
  pk_test::ScenarioValues(ode, sc, &at_ode, &free);
  pk_test::ScenarioValues(exact, sc, &at_exact, &free_exact);
  at_exact.head(3) = at_ode.head(3);
  std::vector<std::pair<int, int>> pairs;
  std::vector<std::array<int, 3>> triples;
  const int p = static_cast<int>(free.size());
  for (int i = 0; i < p; ++i) {
    for (int j = i; j < p; ++j) {
      pairs.emplace_back(i, j);
      for (int k = j; k < p; ++k) triples.push_back({i, j, k});
    }
  }
  std::vector<Eigen::VectorXd> a, b, a3, b3;
  std::string why;
  REQUIRE(ode.SecondDerivatives(at_ode, free, pairs, &a, &why));
  REQUIRE(exact.SecondDerivatives(at_exact, free, pairs, &b, &why));
  REQUIRE(ode.ThirdDerivatives(at_ode, free, triples, &a3, &why));
  REQUIRE(exact.ThirdDerivatives(at_exact, free, triples, &b3, &why));
  const auto agree = [](const std::vector<Eigen::VectorXd>& x, const std::vector<Eigen::VectorXd>& y) {
    double largest = 0;
    for (const Eigen::VectorXd& v : y) largest = std::max(largest, v.cwiseAbs().maxCoeff());
    for (size_t k = 0; k < y.size(); ++k) {
      INFO("tuple " << k << "\node   " << x[k].transpose() << "\nexact " << y[k].transpose());
      CHECK((x[k] - y[k]).cwiseAbs().maxCoeff() <= 1e-8 * std::max(y[k].cwiseAbs().maxCoeff(), 1e-4 * largest));
    }
  };
  agree(a, b);
  agree(a3, b3);
  // The lag's own derivatives are not zero: the dose's step carries them.
  CHECK(b[pairs.size() - 1].cwiseAbs().maxCoeff() > 0);
}

TEST_CASE("hyper-dual numbers give a function's value, two directional derivatives and the mixed one", "[second-order]") {
  using pk::internal::HyperDualNumber;
  // f(x, y) = x^y · log(x) / sqrt(x + y) + exp(-x y), along u = (1, 0.5) (ε₁) and v = (0.3, -2) (ε₂).
  const auto f = [](auto x, auto y) { return pow(x, y) * log(x) / sqrt(x + y) + exp(-(x * y)); };
  const double x0 = 1.7, y0 = 0.6, u[2] = {1, 0.5}, v[2] = {0.3, -2};
  const HyperDualNumber r = f(HyperDualNumber(x0, u[0], v[0], 0), HyperDualNumber(y0, u[1], v[1], 0));
  const auto g = [&](double s, double t) {
    using std::exp, std::log, std::pow, std::sqrt;
    return f(x0 + s * u[0] + t * v[0], y0 + s * u[1] + t * v[1]);
  };
  const double h = 1e-4;
  CHECK(r.value() == Approx(g(0, 0)).epsilon(1e-15));
  CHECK(r.e1() == Approx((g(h, 0) - g(-h, 0)) / (2 * h)).epsilon(1e-7));
  CHECK(r.e2() == Approx((g(0, h) - g(0, -h)) / (2 * h)).epsilon(1e-7));
  CHECK(r.e12() == Approx((g(h, h) - g(h, -h) - g(-h, h) + g(-h, -h)) / (4 * h * h)).epsilon(1e-6));
  // A base of 0 with a moving exponent: x^y = 0 near y = 2, its derivatives in x are those of x².
  const HyperDualNumber z = pow(HyperDualNumber(0.0, 1, 1, 0), HyperDualNumber(2.0, 0.5, 0, 0));
  CHECK(z.value() == 0);
  CHECK(z.e1() == 0);
  CHECK(z.e12() == 2);  // ∂²(x²)/∂x² · u_x v_x
  CHECK(std::isfinite(z.e2()));
}

TEST_CASE("a jet's exponential equals the dense exponential of its stacked matrix", "[second-order]") {
  // Parts of three directions, 3×3 each (a depot-like column, exchange, an input), at a short and a
  // long step: e^{Mh} of the 24×24 stacked matrix (block (S, T) = X_{S∖T}) against the parts of
  // JetExponential, written out the same way.
  for (const double h : {0.3, 40.0}) {
    pk::internal::Jet x(8);
    for (int s = 0; s < 8; ++s) {
      Eigen::Matrix3d part;
      part << -1.2 - 0.1 * s, 0.3, 0.05 * s, 1.2, -0.4 - 0.02 * s, 0.2, 0.01 * s, 0.1, -0.25;
      x[static_cast<size_t>(s)] = (s == 0 ? 1.0 : 0.3) * part * h;
    }
    Eigen::MatrixXd stacked = Eigen::MatrixXd::Zero(24, 24);
    for (int s = 0; s < 8; ++s) {
      for (int t = s;; t = (t - 1) & s) {
        stacked.block(3 * s, 3 * t, 3, 3) = x[static_cast<size_t>(s & ~t)];
        if (t == 0) break;
      }
    }
    const Eigen::MatrixXd dense = stacked.exp();
    pk::internal::JetProducts subsets;  // dual numbers in three directions: e_S e_T = e_{S∪T}, S ∩ T = ∅
    subsets.parts = 8;
    for (int s = 0; s < 8; ++s) {
      for (int t = s;; t = (t - 1) & s) {
        subsets.entries.push_back({s, t, s & ~t});
        if (t == 0) break;
      }
    }
    pk::internal::Jet e = x;
    pk::internal::JetExponential(subsets, &e);
    for (int s = 0; s < 8; ++s) {
      INFO("h " << h << ", part " << s << ": " << (e[static_cast<size_t>(s)] - dense.block(3 * s, 0, 3, 3)).cwiseAbs().maxCoeff() << " of " << dense.cwiseAbs().maxCoeff());
      const Eigen::MatrixXd want = dense.block(3 * s, 0, 3, 3);
      // Both sides square their scaled exponential, about 10 times at h = 40, each squaring doubling
      // the error of the one before: agreement to a few 1e-13 of the largest entry is what both can give.
      CHECK((e[static_cast<size_t>(s)] - want).cwiseAbs().maxCoeff() <= 1e-12 * std::max(1.0, dense.cwiseAbs().maxCoeff()));
    }
  }
}

TEST_CASE("third-order hyper-dual numbers give every mixed derivative along three directions", "[second-order]") {
  // f(x, y) as above, along u (ε₁), v (ε₂) and w (ε₃). Each pair's part must equal HyperDual's for
  // that pair, and the ε₁ε₂ε₃ part the central difference, along w, of HyperDual's mixed part.
  const auto f = [](auto x, auto y) { return pow(x, y) * log(x) / sqrt(x + y) + exp(-(x * y)) + pow(x, 2.5) / y; };
  const double x0 = 1.7, y0 = 0.6, d[3][2] = {{1, 0.5}, {0.3, -2}, {-0.7, 1.1}};
  pk::HyperDual3 x(x0), y(y0);
  for (int k = 0; k < 3; ++k) {
    x.part(1 << k) = d[k][0];
    y.part(1 << k) = d[k][1];
  }
  const pk::HyperDual3 r = f(x, y);
  using pk::HyperDual;
  const auto pair = [&](int a, int b, double shift) {  // HyperDual along a and b, at a shift along the third
    const int c = 3 - a - b;
    const double xs = x0 + shift * d[c][0], ys = y0 + shift * d[c][1];
    return f(HyperDual(xs, d[a][0], d[b][0], 0), HyperDual(ys, d[a][1], d[b][1], 0));
  };
  CHECK(r.value() == Approx(pair(0, 1, 0).value()).epsilon(1e-15));
  for (const auto& [a, b] : {std::pair<int, int>{0, 1}, {0, 2}, {1, 2}}) {
    const HyperDual p = pair(a, b, 0);
    CHECK(r.part(1 << a) == Approx(p.e1()).epsilon(1e-14));
    CHECK(r.part(1 << b) == Approx(p.e2()).epsilon(1e-14));
    CHECK(r.part((1 << a) | (1 << b)) == Approx(p.e12()).epsilon(1e-14));
  }
  const double h = 1e-5;
  const double third = (pair(0, 1, h).e12() - pair(0, 1, -h).e12()) / (2 * h);
  CHECK(r.part(7) == Approx(third).epsilon(1e-8));
  CHECK(std::abs(r.part(7)) > 0.1);
  // x³ along three directions: 6·u·v·w exactly; a base of 0 with a moving exponent stays finite.
  const pk::HyperDual3 cube = pow(x, 3.0);
  CHECK(cube.part(7) == Approx(6 * d[0][0] * d[1][0] * d[2][0]).epsilon(1e-14));
  pk::HyperDual3 zero(0.0), two(2.0);
  zero.part(1) = zero.part(2) = zero.part(4) = 1;
  two.part(1) = 0.5;
  const pk::HyperDual3 z = pow(zero, two);
  CHECK(z.part(3) == 2);
  CHECK(z.part(7) == 0);  // x² has no third derivative
  for (int s = 0; s < 8; ++s) CHECK(std::isfinite(z.part(s)));
}
