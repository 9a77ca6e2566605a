// The registries of error models and optimisers, and the library's parsing of option names:
// what a new entry must satisfy, checked for every entry.
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/error.h"
#include "pk/fit.h"
#include "pk/objective.h"
#include "pk/regimen.h"
#include "pk/residual_error.h"
#include "pk/two_stage.h"

namespace {

std::shared_ptr<const pk::Dataset> Indomethacin() {
  return std::make_shared<pk::Dataset>(pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets/indomethacin.csv"));
}

// Each catalogue error model's variance as its documentation writes it (pk/residual_error.h),
// written again here rather than taken from the model.
double DocumentedVariance(const std::string& name, double yhat, const std::vector<double>& s) {
  if (name == "additive" || name == "exponential") return s[0] * s[0];
  if (name == "proportional") return std::pow(s[0] * yhat, 2);
  if (name == "combined") return s[0] * s[0] + std::pow(s[1] * yhat, 2);
  return NAN;
}

}  // namespace

TEST_CASE("every registered error model: its name, its σ and its variance's derivatives", "[registry]") {
  const std::vector<std::string> names = pk::ResidualErrorNames();
  REQUIRE(names.size() >= 5);
  CHECK(names.front() == "least-squares");
  for (const std::string& name : names) {
    INFO(name);
    const auto model = pk::MakeResidualError(name);
    CHECK(model->name() == name);
    if (!model->is_likelihood()) {
      CHECK(model->sigma_names().empty());
      continue;
    }
    const std::vector<std::string> sigma = model->sigma_names();
    REQUIRE_FALSE(sigma.empty());
    const Eigen::VectorXd dv = (Eigen::VectorXd(3) << 1.0, 4.0, 7.0).finished();
    std::vector<double> s;
    for (size_t j = 0; j < sigma.size(); ++j) {
      CHECK(pk::IsResidualErrorName(sigma[j]));
      const double start = model->DefaultSigma(static_cast<int>(j), dv);
      CHECK(std::isfinite(start));
      CHECK(start > 0);
      s.push_back(0.3 + 0.2 * static_cast<double>(j));
    }
    for (const double yhat : {0.5, 3.0, 20.0}) {
      double v, dv_dy;
      std::vector<double> dv_ds(sigma.size());
      model->Variance(yhat, s.data(), &v, &dv_dy, dv_ds.data());
      CHECK(v > 0);
      const double documented = DocumentedVariance(name, yhat, s);
      if (std::isfinite(documented)) CHECK(v == Approx(documented).epsilon(1e-14));
      // ∂v/∂ŷ and ∂v/∂σ_j against central differences.
      const double h = 1e-6;
      double vp, vm, unused;
      std::vector<double> scratch(sigma.size());
      model->Variance(yhat + h, s.data(), &vp, &unused, scratch.data());
      model->Variance(yhat - h, s.data(), &vm, &unused, scratch.data());
      CHECK(dv_dy == Approx((vp - vm) / (2 * h)).epsilon(1e-7).margin(1e-10));
      for (size_t j = 0; j < sigma.size(); ++j) {
        std::vector<double> sp = s, sm = s;
        sp[j] += h;
        sm[j] -= h;
        model->Variance(yhat, sp.data(), &vp, &unused, scratch.data());
        model->Variance(yhat, sm.data(), &vm, &unused, scratch.data());
        CHECK(dv_ds[j] == Approx((vp - vm) / (2 * h)).epsilon(1e-7).margin(1e-10));
      }
    }
  }
}

TEST_CASE("error models by name: aliases, case, and an unknown name listing the registered ones", "[registry]") {
  CHECK(pk::MakeResidualError("LS")->name() == std::string("least-squares"));
  CHECK(pk::MakeResidualError("none")->name() == std::string("least-squares"));
  CHECK(pk::MakeResidualError("Additive")->name() == std::string("additive"));
  CHECK(pk::LeastSquares()->name() == std::string("least-squares"));
  CHECK_THROWS_WITH(pk::MakeResidualError("poisson"),
                    Catch::Contains("expected least-squares, additive, proportional, combined, exponential") &&
                        Catch::Contains("'poisson'"));
}

TEST_CASE("the likelihood every error model gives is the normal one of its documented variance", "[registry]") {
  // Subject 1 of indomethacin at fixed values: V = Σ ½[log 2πv + (T(y) − T(ŷ))²/v] (+ log y under the log
  // transform), summed here from the predictions and the documented variance.
  const auto data = Indomethacin();
  for (const std::string& name : pk::ResidualErrorNames()) {
    pk::ObjectiveOptions options;
    options.error_model = pk::MakeResidualError(name);
    if (!options.error_model->is_likelihood()) continue;
    INFO(name);
    const pk::Objective objective(pk::MakeModel("1cmt_iv"), data, 0, options);
    Eigen::VectorXd values = objective.DefaultValues();
    values.head(2) << 9.0, 12.0;
    std::vector<double> s;
    for (int i : objective.sigma_indices()) {
      values(i) = 0.25 + 0.5 * static_cast<double>(s.size());
      s.push_back(values(i));
    }
    const auto ev = objective.Evaluate(values, {}, pk::Objective::Need::kValue);
    const bool log_scale = options.error_model->log_transformed();
    double expected = 0;
    int used = 0;
    for (Eigen::Index k = 0; k < ev.predictions.size(); ++k) {
      const double y = objective.observations()(k), yhat = ev.predictions(k);
      const double v = DocumentedVariance(name, yhat, s);
      const double r = log_scale ? std::log(y) - std::log(yhat) : y - yhat;
      expected += 0.5 * (std::log(2 * M_PI * v) + r * r / v) + (log_scale ? std::log(y) : 0.0);
      ++used;
    }
    REQUIRE(ev.ok);
    CHECK(used == objective.num_samples());
    CHECK(ev.value == Approx(expected).epsilon(1e-13));
  }
}

TEST_CASE("optimisers by name: every registered one is valid, others are refused with the list", "[registry]") {
  for (const std::string name : {"lm", "bfgs", "newton", "nlopt:LN_BOBYQA", "nlopt:LD_MMA"}) {
    pk::FitOptions o;
    o.optimizer = name;
    std::string why;
    CHECK(o.IsValid(&why));
    CHECK(why.empty());
  }
  pk::FitOptions bad;
  std::string why;
  bad.optimizer = "simplex";
  CHECK_FALSE(bad.IsValid(&why));
  CHECK(why == "expected lm, bfgs, newton or nlopt:NAME, got 'simplex'");
  bad.optimizer = "nlopt:LN_NOSUCH";
  CHECK_FALSE(bad.IsValid(&why));
  CHECK_THAT(why, Catch::Contains("unknown NLopt algorithm 'LN_NOSUCH'"));
  bad.optimizer = "lm:LN_BOBYQA";  // lm takes no argument
  CHECK_FALSE(bad.IsValid(&why));
}

TEST_CASE("names of routes, propagators, weightings and population models parse back to themselves", "[registry]") {
  for (const pk::GradientRoute r : {pk::GradientRoute::kAuto, pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint,
                                    pk::GradientRoute::kFiniteDifference, pk::GradientRoute::kCompanion}) {
    CHECK(pk::ParseGradientRoute(pk::ToString(r)) == r);
  }
  for (const pk::Propagator p :
       {pk::Propagator::kAuto, pk::Propagator::kExact, pk::Propagator::kOde, pk::Propagator::kRungeKutta}) {
    CHECK(pk::ParsePropagator(pk::ToString(p)) == p);
  }
  for (const std::string w : {"uniform", "dv2", "dv", "column:W"}) {
    pk::ObjectiveOptions o;
    pk::ParseWeighting(w, &o);
    CHECK(std::string(pk::ToString(o.weighting)) == w.substr(0, w.find(':')));
  }
  CHECK(pk::ParseBetweenSubjectModel("lognormal") == pk::BetweenSubjectModel::kLogNormal);
  CHECK(pk::ParseBetweenSubjectModel("normal") == pk::BetweenSubjectModel::kNormal);
  CHECK_THROWS_AS(pk::ParseGradientRoute("backward"), pk::InputError);
  CHECK_THROWS_AS(pk::ParsePropagator("rk45"), pk::InputError);
  pk::ObjectiveOptions o;
  CHECK_THROWS_AS(pk::ParseWeighting("column:", &o), pk::InputError);
  CHECK_THROWS_AS(pk::ParseBetweenSubjectModel("uniform"), pk::InputError);
}

TEST_CASE("a regimen gets the reader's record checks", "[registry]") {
  const auto regimen = [](double amount, double ii, int addl, int ss) {
    pk::Regimen r;
    pk::Dose d;
    d.time = 2;
    d.amount = amount;
    d.ii = ii;
    d.addl = addl;
    d.ss = ss;
    r.doses = {d};
    r.times = {0, 1, 2};
    return r;
  };
  CHECK(pk::RegimenToDataset(regimen(100, 12, 2, 0)).subjects.at(0).records.size() == 4);
  CHECK_THROWS_WITH(pk::RegimenToDataset(regimen(-1, 0, 0, 0)), "the dose at TIME 2: AMT must not be negative");
  CHECK_THROWS_WITH(pk::RegimenToDataset(regimen(100, 0, 3, 0)), "the dose at TIME 2: ADDL>0 needs II>0");
  CHECK_THROWS_WITH(pk::RegimenToDataset(regimen(100, 12, 0, 3)), Catch::Contains("SS must be 0, 1 or 2, not 3"));
}
