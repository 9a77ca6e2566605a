// Transfer-function coefficients -> exponents and compartmental parameters, with delta-method SEs.
#include <cmath>

#include <Eigen/Eigenvalues>
#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/conversion.h"
#include "pk/initial_estimates.h"
#include "pk/linear_model.h"

namespace {

pk::Exponentials IvResponse(const std::string& iv_model, const std::vector<double>& theta_values) {
  const auto model = pk::MakeModel(iv_model);
  const auto& lin = dynamic_cast<const pk::LinearModel&>(*model);
  const Eigen::VectorXd theta = Eigen::Map<const Eigen::VectorXd>(theta_values.data(), theta_values.size());
  Eigen::EigenSolver<Eigen::MatrixXd> es(lin.SystemMatrix<double>(theta));
  const Eigen::MatrixXd v = es.eigenvectors().real(), w = v.inverse();
  pk::Exponentials e;
  for (int i = 0; i < v.rows(); ++i) {
    e.rate.push_back(-es.eigenvalues()(i).real());
    e.amplitude.push_back(v(0, i) * w(i, 0) / theta(1));
  }
  return e;
}

const pk::TransferFunctionReading& Reading(const std::vector<pk::TransferFunctionReading>& r, const std::string& name) {
  for (const auto& x : r) {
    if (x.reading == name) return x;
  }
  FAIL("no reading " << name);
  return r.front();
}

}  // namespace

TEST_CASE("tf coefficients convert back to the IV and oral compartmental parameters", "[conversion]") {
  SECTION("IV: 2- and 3-compartment") {
    for (const auto& c : std::vector<std::pair<std::string, std::vector<double>>>{
             {"2cmt_iv", {4, 12, 7, 40}}, {"3cmt_iv", {3, 10, 8, 20, 1, 60}}}) {
      INFO(c.first);
      std::vector<double> coeffs;
      pk::ExponentialsToTransferFunction(IvResponse(c.first, c.second), &coeffs);
      const auto readings = pk::ConvertTransferFunction(
          Eigen::Map<const Eigen::VectorXd>(coeffs.data(), coeffs.size()), Eigen::MatrixXd());
      const auto& iv = Reading(readings, "iv");
      REQUIRE(iv.ok);
      for (size_t i = 0; i < c.second.size(); ++i) CHECK(iv.parameters[i].value == Approx(c.second[i]).epsilon(1e-8));
      const auto& ex = Reading(readings, "exponents");
      REQUIRE(ex.ok);
      CHECK(ex.parameters[0].value > ex.parameters[1].value);  // fastest first
      const int n = static_cast<int>(c.second.size()) / 2;
      CHECK(ex.parameters[n].value == Approx(std::log(2.0) / ex.parameters[0].value));  // t½
    }
  }
  SECTION("oral: 2cmt_oral read from its order-3 transfer function") {
    const double ka = 1.3;
    const pk::Exponentials iv = IvResponse("2cmt_iv", {4, 12, 7, 40});
    pk::Exponentials oral;
    double sum = 0;
    oral.rate.push_back(ka);
    oral.amplitude.push_back(0);
    for (size_t i = 0; i < iv.rate.size(); ++i) {
      const double c = iv.amplitude[i] * ka / (ka - iv.rate[i]);
      oral.rate.push_back(iv.rate[i]);
      oral.amplitude.push_back(c);
      sum += c;
    }
    oral.amplitude[0] = -sum;  // C(0) = 0
    std::vector<double> coeffs;
    pk::ExponentialsToTransferFunction(oral, &coeffs);
    const auto readings =
        pk::ConvertTransferFunction(Eigen::Map<const Eigen::VectorXd>(coeffs.data(), coeffs.size()), Eigen::MatrixXd());
    const auto& r = Reading(readings, "oral");
    REQUIRE(r.ok);
    const std::vector<double> truth{1.3, 4, 12, 7, 40};
    for (size_t i = 0; i < truth.size(); ++i) CHECK(r.parameters[i].value == Approx(truth[i]).epsilon(1e-8));
  }
}

TEST_CASE("compartmental -> exponentials -> tf -> compartmental round trips, micro-constants included", "[conversion]") {
  struct Case {
    std::string model;
    std::vector<double> theta;
    std::string reading;
  };
  for (const Case& c : std::vector<Case>{{"2cmt_iv", {4, 12, 7, 40}, "iv"},
                                         {"3cmt_iv", {3, 10, 8, 20, 1, 60}, "iv"},
                                         {"2cmt_oral", {1.3, 4, 12, 7, 40}, "oral"}}) {
    INFO(c.model);
    const Eigen::VectorXd theta = Eigen::Map<const Eigen::VectorXd>(c.theta.data(), c.theta.size());
    pk::Exponentials e;
    std::string why;
    REQUIRE(pk::ModelToExponentials(*pk::MakeModel(c.model), theta, &e, &why));
    std::vector<double> coeffs;
    pk::ExponentialsToTransferFunction(e, &coeffs);
    const auto readings =
        pk::ConvertTransferFunction(Eigen::Map<const Eigen::VectorXd>(coeffs.data(), coeffs.size()), Eigen::MatrixXd());
    const auto& r = Reading(readings, c.reading);
    REQUIRE(r.ok);
    for (size_t i = 0; i < c.theta.size(); ++i) CHECK(r.parameters[i].value == Approx(c.theta[i]).epsilon(1e-8));
    // Micro-constants follow the clearances and volumes: K10 = CL/V1, K12 = Q/V1, K21 = Q/V2.
    const size_t off = c.reading == "oral" ? 1 : 0;
    const double cl = c.theta[off], v1 = c.theta[off + 1], q = c.theta[off + 2], v2 = c.theta[off + 3];
    CHECK(r.parameters[c.theta.size()].name == "K10");
    CHECK(r.parameters[c.theta.size()].value == Approx(cl / v1));
    CHECK(r.parameters[c.theta.size() + 1].value == Approx(q / v1));
    CHECK(r.parameters[c.theta.size() + 2].value == Approx(q / v2));
  }
}

TEST_CASE("delta-method standard errors of derived parameters", "[conversion]") {
  // tf1: y = b1/(s + a1): V = 1/b1, CL = a1/b1.
  const double a1 = 0.2, b1 = 0.05, sa = 0.01, sb = 0.004;
  Eigen::VectorXd c(2);
  c << a1, b1;
  Eigen::MatrixXd cov = Eigen::MatrixXd::Zero(2, 2);
  cov(0, 0) = sa * sa;
  cov(1, 1) = sb * sb;
  const auto readings = pk::ConvertTransferFunction(c, cov);
  const auto& iv = Reading(readings, "iv");
  REQUIRE(iv.ok);
  CHECK(iv.parameters[0].name == "CL");
  CHECK(iv.parameters[0].value == Approx(a1 / b1));
  CHECK(iv.parameters[0].se == Approx(std::hypot(sa / b1, a1 * sb / (b1 * b1))).epsilon(1e-6));
  CHECK(iv.parameters[1].se == Approx(sb / (b1 * b1)).epsilon(1e-6));
  CHECK(iv.parameters[1].rse_pct == Approx(100 * sb / b1).epsilon(1e-6));
}

TEST_CASE("infeasible coefficients are reported with a reason", "[conversion]") {
  Eigen::VectorXd c(4);
  c << 0.2, 0.5, 0.1, 0.01;  // s² + 0.2 s + 0.5: complex roots
  const auto readings = pk::ConvertTransferFunction(c, Eigen::MatrixXd());
  CHECK(!Reading(readings, "iv").ok);
  CHECK_THAT(Reading(readings, "iv").message, Catch::Contains("complex roots"));
}
