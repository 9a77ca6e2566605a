// The modal (eigen-coordinate) form of the Φ/Γ recursion against the Padé
// path: loss, predictions, forward Jacobian and adjoint gradient, on every
// linear catalogue model × event scenario, with parameter sets that change over
// time; and its divided differences against an independent matrix exponential.
#include <catch2/catch.hpp>

#include <algorithm>
#include <random>
#include <thread>
#include <tuple>

#include <unsupported/Eigen/MatrixFunctions>

#include "exact/modal.h"
#include "exact/modal_evaluator.h"
#include "pk/catalogue.h"
#include "pk/linear_model.h"
#include "pk/objective.h"
#include "test_util.h"

namespace {

using Need = pk::Objective::Need;

double MaxRel(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  const double scale = std::max(b.cwiseAbs().maxCoeff(), 1e-300);
  return (a - b).cwiseAbs().maxCoeff() / scale;
}

// Fixed (not estimated) dose modifiers: the schedule is recorded with them.
const std::vector<pk_test::Scenario>& FixedModifierScenarios() {
  static const std::vector<pk_test::Scenario> s = {
      {"bolus", "1,0,100,0,0,0,0,1,.\n", {"F1"}, {1.0}},
      {"infusion", "1,0,100,40,0,0,0,1,.\n", {"F1"}, {1.0}},
      {"addl", "1,0,100,0,6,3,0,1,.\n", {"F1"}, {1.0}},
      {"ss1 bolus", "1,0,100,0,12,0,1,1,.\n", {"F1"}, {1.0}},
      {"ss2 on a dose", "1,0,50,0,0,0,0,1,.\n1,0.2,100,0,12,0,2,1,.\n", {"F1"}, {1.0}},
      {"ss1 infusion longer than II", "1,0,100,5,8,0,1,1,.\n", {"F1"}, {1.0}},
      {"ss constant infusion", "1,0,0,10,0,0,1,1,.\n", {"F1"}, {1.0}},
      {"lag (fixed)", "1,0,100,0,6,2,0,1,.\n", {"ALAG1"}, {0.7}},
      {"F (fixed)", "1,0,100,30,0,0,0,1,.\n", {"F1"}, {0.8}},
      {"D (fixed)", "1,0,100,-2,0,0,0,1,.\n", {"D1"}, {2.2}},
      {"ss1 with lag (fixed)", "1,0,100,0,12,0,1,1,.\n", {"ALAG1"}, {1.3}},
      {"initial state (fixed)", "1,0,100,0,6,2,0,1,.\n", {"X0_1"}, {30.0}},
      {"resets (EVID 3, then 4)", "1,0,100,0,0,0,0,1,.\n1,4.0,0,0,0,0,0,3,.\n1,6.5,80,30,0,0,0,4,.\n", {"F1"}, {1.0}},
  };
  return s;
}

struct Routes {
  pk::Objective::Evaluation value, forward, adjoint, jacobian;
};

Routes EvaluateAll(const pk::Objective& objective, const Eigen::VectorXd& values, const std::vector<int>& free) {
  Routes r;
  r.value = objective.Evaluate(values, free, Need::kValue);
  r.forward = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
  r.adjoint = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  r.jacobian = objective.Evaluate(values, free, Need::kJacobian, pk::GradientRoute::kForward);
  return r;
}

void CheckAgree(const Routes& modal, const Routes& pade) {
  for (const auto* e : {&modal.value, &modal.forward, &modal.adjoint, &modal.jacobian, &pade.value, &pade.forward,
                        &pade.adjoint, &pade.jacobian}) {
    REQUIRE(e->ok);
  }
  // The comparison is between two paths only if they were taken.
  CHECK(modal.value.modal);
  CHECK(modal.adjoint.modal);
  CHECK(modal.jacobian.modal);
  CHECK_FALSE(pade.value.modal);
  CHECK_FALSE(pade.adjoint.modal);
  CHECK(modal.value.value == Approx(pade.value.value).epsilon(1e-12));
  CHECK(MaxRel(modal.value.predictions, pade.value.predictions) < 1e-12);
  INFO("modal forward " << modal.forward.gradient.transpose() << "\nmodal adjoint " << modal.adjoint.gradient.transpose()
                        << "\nPadé           " << pade.adjoint.gradient.transpose());
  CHECK(MaxRel(modal.forward.gradient, pade.adjoint.gradient) < 1e-10);
  CHECK(MaxRel(modal.adjoint.gradient, pade.adjoint.gradient) < 1e-10);
  // Least squares returns the residual Jacobian; maximum likelihood the information built from ∂ŷ/∂p.
  REQUIRE(modal.jacobian.jacobian.size() == pade.jacobian.jacobian.size());
  if (pade.jacobian.jacobian.size() > 0) CHECK(MaxRel(modal.jacobian.jacobian, pade.jacobian.jacobian) < 1e-10);
  CHECK(MaxRel(modal.jacobian.information, pade.jacobian.information) < 1e-10);
}

// Every route on both paths, at the catalogue defaults scaled by 1 + step·i, with every model parameter free.
struct ModalAndPade {
  Routes modal, pade;
  ModalAndPade(const std::shared_ptr<const pk::Model>& model, const std::shared_ptr<const pk::Dataset>& data,
               double step) {
    pk::ObjectiveOptions off;
    off.modal_propagation = false;
    const pk::Objective on_path(model, data, 0, pk::ObjectiveOptions()), off_path(model, data, 0, off);
    Eigen::VectorXd values = on_path.DefaultValues();
    std::vector<int> free;
    for (int i = 0; i < model->num_parameters(); ++i) {
      values(i) *= 1.0 + step * i;
      free.push_back(i);
    }
    modal = EvaluateAll(on_path, values, free);
    pade = EvaluateAll(off_path, values, free);
  }
};

}  // namespace

TEST_CASE("divided differences of exp match the exponential of a bidiagonal matrix", "[modal]") {
  // Opitz: exp(h [[a, 1, 0], [0, b, 1], [0, 0, 0]]) has f[a, b] and f[a, b, 0] in its first row.
  const std::vector<double> points = {0.0, -1e-9, -1e-4, -0.03, -0.05, -0.1, -0.35, -0.351, -1.0, -1.0 + 1e-7,
                                      -2.5, -7.0, -40.0, 0.02};
  for (double h : {0.01, 0.3, 1.0, 6.0, 24.0}) {
    for (double a : points) {
      for (double b : points) {
        Eigen::Matrix3d m;
        m << a, 1, 0, 0, b, 1, 0, 0, 0;
        const Eigen::Matrix3d e = (m * h).exp();
        const double ea = std::exp(a * h), eb = std::exp(b * h);
        // With superdiagonal h, the divided differences of e^x at (ah, bh, 0) times h and h² are
        // exactly f[a, b] and f[a, b, 0] of f(λ) = e^{λh}. Padé is accurate relative to ‖exp(hM)‖.
        const double margin = 1e-15 * e.cwiseAbs().maxCoeff();
        INFO("h " << h << " a " << a << " b " << b);
        CHECK(pk::internal::DividedExp2(a, b, ea, eb, h) == Approx(e(0, 1)).epsilon(1e-12).margin(margin));
        CHECK(pk::internal::DividedExp3(a, b, ea, eb, h) == Approx(e(0, 2)).epsilon(1e-12).margin(margin));
      }
    }
  }
}

TEST_CASE("three- and four-point divided differences of exp match the bidiagonal exponential", "[modal][second-order]") {
  // f[a, b, c] and f[a, b, c, 0] of f(λ) = e^{λh}, which the second-order sensitivities take in
  // eigen-coordinates: the first row of exp(h J), J bidiagonal with the points on its diagonal.
  const std::vector<double> points = {0.0, -1e-9, -1e-4, -0.05, -0.35, -0.351, -1.0, -1.0 + 1e-7, -7.0, -40.0, 0.02};
  for (double h : {0.01, 1.0, 24.0}) {
    for (double a : points) {
      for (double b : points) {
        for (double c : points) {
          Eigen::Matrix4d j = Eigen::Matrix4d::Zero();
          j(0, 0) = a, j(1, 1) = b, j(2, 2) = c;
          j(0, 1) = j(1, 2) = j(2, 3) = 1;
          const Eigen::Matrix4d e = (j * h).exp();
          Eigen::Matrix3d j3 = j.topLeftCorner(3, 3);
          const Eigen::Matrix3d e3 = (j3 * h).exp();
          const double margin = 1e-15 * e.cwiseAbs().maxCoeff(), margin3 = 1e-15 * e3.cwiseAbs().maxCoeff();
          INFO("h " << h << " a " << a << " b " << b << " c " << c);
          CHECK(pk::internal::DividedExp3General(a, b, c, h) == Approx(e3(0, 2)).epsilon(1e-11).margin(margin3));
          CHECK(pk::internal::DividedExp4(a, b, c, h) == Approx(e(0, 3)).epsilon(1e-10).margin(margin));
        }
      }
    }
  }
}

TEST_CASE("modal and Padé paths agree on every linear model and event scenario", "[modal]") {
  const auto model_name = GENERATE(as<std::string>{}, "1cmt_iv", "1cmt_oral", "2cmt_iv", "2cmt_oral", "3cmt_iv",
                                   "3cmt_oral");
  const auto model = pk::MakeModel(model_name);
  for (const pk_test::Scenario& sc : FixedModifierScenarios()) {
    const auto error_model = GENERATE(pk::MakeResidualError("least-squares"), pk::MakeResidualError("combined"));
    INFO(model_name << " / " << sc.name << " / " << error_model->name());
    pk::ObjectiveOptions on, off;
    on.error_model = off.error_model = error_model;
    off.modal_propagation = false;
    const auto data = pk_test::ScenarioData(sc);
    const pk::Objective modal(model, data, 0, on), pade(model, data, 0, off);
    Eigen::VectorXd values = modal.DefaultValues();
    std::vector<int> free;
    for (int i = 0; i < model->num_parameters(); ++i) {
      values(i) *= 1.0 + 0.1 * i;
      free.push_back(i);
    }
    for (size_t e = 0; e < sc.extra_free.size(); ++e) values(modal.ParameterIndex(sc.extra_free[e])) = sc.extra_values[e];
    if (std::string(error_model->name()) != "least-squares") free.push_back(modal.ParameterIndex("SIGMA_PROP"));
    CheckAgree(EvaluateAll(modal, values, free), EvaluateAll(pade, values, free));
  }
}

TEST_CASE("modal path: steps that are multiples of shorter ones take their exponentials as powers", "[modal]") {
  // Sampling intervals 0.25, 0.25, 0.75, 1, 2, 4, 8, 8, 12 h: 0.5 = 2 × 0.25 is not among them, 0.75 = 3 × 0.25,
  // 1 = 4 × 0.25, 2 = 2 × 1 (8 × 0.25, the limit), 4 takes exp (16 × 0.25 is over it), 8 = 2 × 4, 12 = 3 × 4;
  // the 1.3 h infusion and the 0.05 h step after it are multiples of nothing.
  const std::string csv =
      "ID,TIME,AMT,RATE,EVID,DV\n"
      "1,0,100,0,1,.\n1,0.25,0,0,0,1.2\n1,0.5,0,0,0,1.9\n1,1.25,0,0,0,2.6\n1,2.25,0,0,0,2.5\n"
      "1,2.25,60,46.153846153846153,1,.\n1,3.6,0,0,0,2.1\n1,4.25,0,0,0,2.0\n1,8.25,0,0,0,1.1\n"
      "1,16.25,0,0,0,0.5\n1,24.25,0,0,0,0.3\n1,36.25,0,0,0,0.1\n";
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(csv, "powers.csv"));
  const auto model_name = GENERATE(as<std::string>{}, "1cmt_oral", "2cmt_oral", "3cmt_iv");
  INFO(model_name);
  const auto model = pk::MakeModel(model_name);
  const pk::ParameterLayout layout(*model);
  const auto prepared = pk::internal::PrepareSubject(*model, layout, *data, 0, layout.Defaults(), false);
  const pk::internal::EventSchedule sched = pk::internal::RecordSchedule(layout, prepared);
  REQUIRE(sched.step_powers.size() == sched.steps.size());
  int derived = 0;
  for (size_t j = 0; j < sched.steps.size(); ++j) {
    const auto& sp = sched.step_powers[j];
    if (sp.base < 0) continue;
    ++derived;
    INFO("step " << sched.steps[j] << " from " << sched.steps[sp.base] << "^" << sp.power);
    CHECK(sp.power * sched.steps[sp.base] == sched.steps[j]);
    CHECK(sched.steps[sp.base] < sched.steps[j]);
    int total = 1;  // the powers along the chain down to a step that takes exp
    for (int b = static_cast<int>(j); sched.step_powers[b].base >= 0; b = sched.step_powers[b].base) {
      total *= sched.step_powers[b].power;
    }
    CHECK(total <= pk::internal::EventSchedule::kMaxStepPower);
  }
  CHECK(derived == 5);  // 0.75, 1, 2, 8, 12
  const ModalAndPade both(model, data, 0.1);
  CheckAgree(both.modal, both.pade);
}

// Parent ⇄ peripheral, parent → metabolite → out: the exchange block is not
// symmetrisable (no flow back from the metabolite), so the decomposition takes
// Eigen's general real solver, on a block smaller than the model when a depot
// is peeled off first.
std::shared_ptr<const pk::LinearModel> ParentMetabolite(bool depot) {
  pk::LinearModelBuilder b(depot ? "parent_metabolite_oral" : "parent_metabolite", "parent with a metabolite");
  const int ka = b.Parameter("KA", 1.3), cl = b.Parameter("CL", 2.0), v = b.Parameter("V", 20.0);
  const int q = b.Parameter("Q", 1.5), vp = b.Parameter("VP", 35.0), km = b.Parameter("KM", 0.08);
  const int kme = b.Parameter("KME", 0.3);
  const int d = depot ? b.Compartment("DEPOT") : -1;
  const int parent = b.Compartment("PARENT", v), periph = b.Compartment("PERIPH", vp);
  const int metab = b.Compartment("METAB");
  if (depot) b.RateFlow(d, parent, ka);
  b.ClearanceFlow(parent, pk::LinearModelBuilder::kOutside, cl);
  b.ClearanceFlow(parent, periph, q);
  b.ClearanceFlow(periph, parent, q);
  b.RateFlow(parent, metab, km);
  b.RateFlow(metab, pk::LinearModelBuilder::kOutside, kme);
  b.SetCentral(parent);
  b.SetDefaultDose(depot ? d : parent);
  return b.Build();
}

TEST_CASE("modal and Padé paths agree where the exchange is not reversible", "[modal]") {
  for (bool depot : {false, true}) {
    const auto model = ParentMetabolite(depot);
    for (const pk_test::Scenario& sc : FixedModifierScenarios()) {
      INFO(model->name() << " / " << sc.name);
      pk::ObjectiveOptions on, off;
      off.modal_propagation = false;
      const auto data = pk_test::ScenarioData(sc);
      const pk::Objective modal(model, data, 0, on), pade(model, data, 0, off);
      Eigen::VectorXd values = modal.DefaultValues();
      std::vector<int> free;
      for (int i = 0; i < model->num_parameters(); ++i) free.push_back(i);
      for (size_t e = 0; e < sc.extra_free.size(); ++e) {
        values(modal.ParameterIndex(sc.extra_free[e])) = sc.extra_values[e];
      }
      CheckAgree(EvaluateAll(modal, values, free), EvaluateAll(pade, values, free));
    }
  }
}

TEST_CASE("modal path: a new schedule when fixed modifiers change", "[modal]") {
  const auto model = pk::MakeModel("2cmt_oral");
  const auto data = pk_test::ScenarioData({"lag", "1,0,100,0,6,2,0,1,.\n", {}, {}});
  pk::ObjectiveOptions off;
  off.modal_propagation = false;
  const pk::Objective modal(model, data, 0, pk::ObjectiveOptions()), pade(model, data, 0, off);
  Eigen::VectorXd values = modal.DefaultValues();
  const std::vector<int> free{0, 1, 2, 3, 4};
  const int lag = modal.ParameterIndex("ALAG1");
  for (double alag : {0.0, 0.7, 2.9, 0.7}) {
    values(lag) = alag;
    INFO("ALAG1 " << alag);
    CheckAgree(EvaluateAll(modal, values, free), EvaluateAll(pade, values, free));
  }
}

TEST_CASE("modal path: one objective evaluated from several threads at once", "[modal]") {
  // Each thread has its own θ and lag (so its own schedule); the evaluators and
  // schedules are pooled across threads, and no result may depend on which one
  // a call was handed.
  const auto model = pk::MakeModel("2cmt_oral");
  const auto data = pk_test::ScenarioData({"lag", "1,0,100,0,6,2,0,1,.\n", {}, {}});
  const pk::Objective objective(model, data, 0, pk::ObjectiveOptions());
  const std::vector<int> free{0, 1, 2, 3, 4};
  const int lag = objective.ParameterIndex("ALAG1");
  constexpr int kThreads = 4;
  std::vector<Eigen::VectorXd> values(kThreads, objective.DefaultValues());
  std::vector<Routes> expected;
  for (int t = 0; t < kThreads; ++t) {
    values[t].head(5) *= 1.0 + 0.1 * t;
    values[t](lag) = 0.3 * t;
    expected.push_back(EvaluateAll(objective, values[t], free));
  }
  std::vector<int> mismatches(kThreads, 0);
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      for (int rep = 0; rep < 200; ++rep) {
        const Routes r = EvaluateAll(objective, values[t], free);
        const Routes& e = expected[t];
        const bool same = r.value.value == e.value.value && r.adjoint.gradient == e.adjoint.gradient &&
                          r.forward.gradient == e.forward.gradient && r.jacobian.jacobian == e.jacobian.jacobian;
        mismatches[t] += same ? 0 : 1;
      }
    });
  }
  for (std::thread& th : threads) th.join();
  for (int t = 0; t < kThreads; ++t) {
    INFO("thread " << t);
    CHECK(expected[t].adjoint.modal);
    CHECK(mismatches[t] == 0);
  }
  // The threads' values differ: a mix-up would show.
  CHECK(expected[0].adjoint.gradient != expected[1].adjoint.gradient);
}

TEST_CASE("modal path: the free list may change from one evaluation to the next", "[modal]") {
  // The evaluator keeps what depends on the free list alone between evaluations; each result must be that
  // of a fresh objective, whatever was asked before (other lists, the same ones reordered, values alone).
  const auto model = pk::MakeModel("2cmt_oral");
  const auto data = pk_test::ScenarioData({"bolus", "1,0,100,0,0,0,0,1,.\n", {}, {}});
  const pk::Objective kept(model, data, 0, pk::ObjectiveOptions());
  Eigen::VectorXd values = kept.DefaultValues();
  const std::vector<std::vector<int>> lists = {{0, 1, 2, 3, 4}, {1, 2}, {2, 1}, {0, 3}, {3, 4}, {}, {0, 1, 2, 3, 4}};
  int call = 0;
  for (const std::vector<int>& free : lists) {
    for (const bool value_between : {false, true}) {
      values.head(5) *= 1.03;  // a new θ each time
      ++call;
      INFO("call " << call << ", " << free.size() << " free");
      if (value_between) kept.Evaluate(values, {0, 1, 2, 3, 4}, Need::kValue);
      const pk::Objective fresh(model, data, 0, pk::ObjectiveOptions());
      for (const auto route : {pk::GradientRoute::kAdjoint, pk::GradientRoute::kForward}) {
        const auto a = kept.Evaluate(values, free, Need::kGradient, route);
        const auto b = fresh.Evaluate(values, free, Need::kGradient, route);
        REQUIRE(a.ok);
        CHECK(a.modal);
        CHECK(a.value == b.value);
        CHECK(a.gradient == b.gradient);
      }
    }
  }
}

TEST_CASE("modal path: parameter sets from a data column switch coordinates", "[modal]") {
  // CL changes at t = 4 and t = 10 (a time-varying covariate), with an infusion
  // running across the first change and a steady-state dose after it.
  const std::string csv =
      "ID,TIME,AMT,RATE,II,SS,EVID,CL,DV\n"
      "1,0,100,30,0,0,1,2.0,.\n"
      "1,1,0,0,0,0,0,2.0,1.5\n"
      "1,3,0,0,0,0,0,2.0,2.5\n"
      "1,5,0,0,0,0,0,3.5,2.0\n"
      "1,6,50,0,8,2,1,3.5,.\n"
      "1,8,0,0,0,0,0,3.5,2.2\n"
      "1,12,0,0,0,0,0,1.2,1.1\n"
      "1,20,0,0,0,0,0,1.2,0.6\n";
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(csv, "cov.csv"));
  const auto model_name = GENERATE(as<std::string>{}, "1cmt_iv", "2cmt_oral", "3cmt_iv");
  INFO(model_name);
  const auto model = pk::MakeModel(model_name);
  // Every model parameter is free; CL comes from the data, so its column of the Jacobian is zero.
  const ModalAndPade both(model, data, 0.07);
  const Routes& m = both.modal;
  CheckAgree(m, both.pade);
  const int cl = pk::Objective(model, data, 0, pk::ObjectiveOptions()).ParameterIndex("CL");
  CHECK(m.adjoint.gradient(cl) == 0);
  CHECK(m.jacobian.jacobian.col(cl).isZero(0.0));
}

TEST_CASE("modal path steps aside where the eigenbasis is ill-conditioned or events move", "[modal]") {
  const auto model = pk::MakeModel("1cmt_oral");
  const auto data = pk_test::ScenarioData({"addl", "1,0,100,0,8,2,0,1,.\n", {}, {}});
  const pk::Objective objective(model, data, 0, pk::ObjectiveOptions());
  Eigen::VectorXd values = objective.DefaultValues();
  std::vector<int> free{0, 1, 2};
  // Flip-flop KA = CL/V: a double eigenvalue, defective A.
  values(0) = 0.1;
  values(1) = 3.0;
  values(2) = 30.0;
  const auto flip = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  REQUIRE(flip.ok);
  CHECK_FALSE(flip.modal);
  // An estimated lag moves the schedule with θ.
  values(0) = 1.1;
  free.push_back(objective.ParameterIndex("ALAG1"));
  values(free.back()) = 0.4;
  const auto lag = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  REQUIRE(lag.ok);
  CHECK_FALSE(lag.modal);
  free.pop_back();
  CHECK(objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint).modal);
}

namespace {

// Compartmental A for rate constants: `flows` lists (from, to, k); elimination from `elim` at ke.
template <int N>
Eigen::Matrix<double, N, N> Compartmental(const std::vector<std::tuple<int, int, double>>& flows, int elim, double ke) {
  Eigen::Matrix<double, N, N> a = Eigen::Matrix<double, N, N>::Zero();
  for (const auto& [from, to, k] : flows) {
    a(to, from) += k;
    a(from, from) -= k;
  }
  a(elim, elim) -= ke;
  return a;
}

// DecomposeSmall against A = V diag(λ) W, W V = I, and the general routine's eigenvalues.
template <int N>
pk::internal::modal_detail::SmallDecomposition CheckSmall(const Eigen::Matrix<double, N, N>& a) {
  using namespace pk::internal::modal_detail;
  Eigen::Matrix<double, N, 1> lambda;
  Eigen::Matrix<double, N, N> v, w;
  const SmallDecomposition result = DecomposeSmall<N>(a, &lambda, &v, &w);
  SmallVec lg;
  SmallMat vg, wg;
  const bool general = Decompose(SmallMat(a), &lg, &vg, &wg);
  if (result == SmallDecomposition::kDone) {
    const double scale = a.cwiseAbs().maxCoeff();
    CHECK((v * lambda.asDiagonal() * w - a).cwiseAbs().maxCoeff() <= 1e-13 * scale);
    CHECK((w * v - Eigen::Matrix<double, N, N>::Identity()).cwiseAbs().maxCoeff() <= 1e-12);
    REQUIRE(general);
    std::vector<double> l1(lambda.data(), lambda.data() + N), l2(lg.data(), lg.data() + N);
    std::sort(l1.begin(), l1.end());
    std::sort(l2.begin(), l2.end());
    for (int i = 0; i < N; ++i) CHECK(std::fabs(l1[i] - l2[i]) <= 1e-13 * scale);
  } else if (result == SmallDecomposition::kUnsuitable) {
    CHECK_FALSE(general);
  }
  return result;
}

}  // namespace

TEST_CASE("fixed-size decomposition of depots and a reversible block matches the general one", "[modal]") {
  using pk::internal::modal_detail::SmallDecomposition;
  std::mt19937 rng(20261123);
  std::uniform_real_distribution<double> log_rate(std::log(1e-2), std::log(1e2));
  const auto k = [&] { return std::exp(log_rate(rng)); };
  int done = 0;
  for (int trial = 0; trial < 300; ++trial) {
    // 2cmt_iv, 1cmt_oral, 2cmt_oral and two depots into a 2-compartment model.
    const SmallDecomposition iv2 = CheckSmall<2>(Compartmental<2>({{0, 1, k()}, {1, 0, k()}}, 0, k()));
    const SmallDecomposition oral1 = CheckSmall<2>(Compartmental<2>({{0, 1, k()}}, 1, k()));
    const SmallDecomposition oral2 = CheckSmall<3>(Compartmental<3>({{0, 1, k()}, {1, 2, k()}, {2, 1, k()}}, 1, k()));
    const SmallDecomposition depots =
        CheckSmall<4>(Compartmental<4>({{0, 2, k()}, {1, 3, k()}, {2, 3, k()}, {3, 2, k()}}, 2, k()));
    const SmallDecomposition iv3 =
        CheckSmall<3>(Compartmental<3>({{0, 1, k()}, {1, 0, k()}, {0, 2, k()}, {2, 0, k()}}, 0, k()));
    const SmallDecomposition oral3 = CheckSmall<4>(
        Compartmental<4>({{0, 1, k()}, {1, 2, k()}, {2, 1, k()}, {1, 3, k()}, {3, 1, k()}}, 1, k()));
    for (SmallDecomposition r : {iv2, oral1, oral2, depots, iv3, oral3}) {
      CHECK(r != SmallDecomposition::kOther);
      done += r == SmallDecomposition::kDone;
    }
  }
  // Most random rates are well conditioned; the others are declined, as by the general routine.
  CHECK(done > 1500);
  // Flip-flop: the depot's rate equals the elimination rate, a defective A.
  CHECK(CheckSmall<2>(Compartmental<2>({{0, 1, 0.5}}, 1, 0.5)) == SmallDecomposition::kUnsuitable);
  // Other structures go to the general routine: one-way transit, a one-way cycle, four exchanging states.
  CHECK(CheckSmall<3>(Compartmental<3>({{0, 1, 1.0}, {1, 2, 2.0}}, 2, 0.5)) == SmallDecomposition::kOther);
  CHECK(CheckSmall<3>(Compartmental<3>({{0, 1, 1.0}, {1, 2, 2.0}, {2, 0, 0.7}}, 2, 0.5)) ==
        SmallDecomposition::kOther);
  CHECK(CheckSmall<4>(Compartmental<4>({{0, 1, 1.0}, {1, 0, 2.0}, {0, 2, 0.3}, {2, 0, 0.1}, {0, 3, 0.2}, {3, 0, 0.4}},
                                       0, 0.5)) == SmallDecomposition::kOther);
}
