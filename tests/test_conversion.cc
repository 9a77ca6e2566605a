// Transfer-function coefficients -> exponents and compartmental parameters, with delta-method SEs.
#include <cmath>
#include <functional>

#include <Eigen/Eigenvalues>
#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/conversion.h"
#include "pk/initial_estimates.h"
#include "pk/linear_model.h"

namespace {

// ModelExponents of a two-exponential model against `closed` (θ ↦ λ1, λ2, t½1,
// t½2, AMP1, AMP2, fastest first), its SEs against the delta method on
// `closed` differentiated by central differences.
void CheckTwoExponentials(const pk::Model& model, const Eigen::VectorXd& theta, const Eigen::MatrixXd& cov,
                          const std::function<Eigen::VectorXd(const Eigen::VectorXd&)>& closed) {
  const Eigen::Index m = theta.size();
  Eigen::MatrixXd jac(6, m);
  for (Eigen::Index j = 0; j < m; ++j) {
    const double h = 1e-5 * theta(j);
    Eigen::VectorXd up = theta, down = theta;
    up(j) += h;
    down(j) -= h;
    jac.col(j) = (closed(up) - closed(down)) / (2 * h);
  }
  const Eigen::VectorXd se = (jac * cov * jac.transpose()).diagonal().cwiseSqrt();
  const Eigen::VectorXd value = closed(theta);
  const auto r = pk::ModelExponents(model, theta, cov);
  REQUIRE(r.ok);
  REQUIRE(r.parameters.size() == 6);
  // Behind a depot the absorption rate (here the faster one) is labelled _ABS.
  const bool oral = model.initial_structure().depot;
  const char* names[] = {oral ? "LAMBDA_ABS" : "LAMBDA1", oral ? "LAMBDA1" : "LAMBDA2",
                         oral ? "THALF_ABS" : "THALF1",   oral ? "THALF1" : "THALF2",
                         oral ? "AMP_ABS" : "AMP1",       oral ? "AMP1" : "AMP2"};
  for (int i = 0; i < 6; ++i) {
    INFO(names[i]);
    CHECK(r.parameters[i].name == names[i]);
    CHECK(r.parameters[i].value == Approx(value(i)).epsilon(1e-12));
    CHECK(r.parameters[i].se == Approx(se(i)).epsilon(1e-6));
    CHECK(r.parameters[i].rse_pct == Approx(100 * se(i) / std::fabs(value(i))).epsilon(1e-6));
  }
}

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
    // The reading names its values as the model does (NONMEM's TRANS4: V2, V3 behind a depot).
    const auto model = pk::MakeModel(c.model);
    for (size_t i = 0; i < c.theta.size(); ++i) CHECK(r.parameters[i].name == model->parameter_names()[i]);
    // Micro-constants follow the clearances and volumes: K10 = CL/V1, K12 = Q/V1, K21 = Q/V2 (behind a
    // depot K20, K23, K32 of CL/V2, Q/V2, Q/V3).
    const size_t off = c.reading == "oral" ? 1 : 0;
    const double cl = c.theta[off], v1 = c.theta[off + 1], q = c.theta[off + 2], v2 = c.theta[off + 3];
    CHECK(r.parameters[c.theta.size()].name == (off ? "K20" : "K10"));
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

TEST_CASE("exponents and half-lives of a fitted compartment model, with delta-method SEs", "[conversion]") {
  {  // 1cmt_iv: λ = CL/V, Var λ = λ²(Var CL/CL² + Var V/V² − 2 Cov/(CL V)).
    const auto model = pk::MakeModel("1cmt_iv");
    const double cl = 4, v = 30;
    Eigen::VectorXd theta(2);
    theta << cl, v;
    Eigen::MatrixXd cov(2, 2);
    cov << 0.09, 0.5, 0.5, 16;
    const auto r = pk::ModelExponents(*model, theta, cov);
    REQUIRE(r.ok);
    REQUIRE(r.parameters.size() == 3);
    CHECK(r.parameters[0].name == "LAMBDA1");
    CHECK(r.parameters[0].value == Approx(cl / v));
    const double var = (cl / v) * (cl / v) * (cov(0, 0) / (cl * cl) + cov(1, 1) / (v * v) - 2 * cov(0, 1) / (cl * v));
    CHECK(r.parameters[0].se == Approx(std::sqrt(var)).epsilon(1e-6));
    CHECK(r.parameters[1].name == "THALF1");
    CHECK(r.parameters[1].value == Approx(std::log(2.0) * v / cl));
    CHECK(r.parameters[1].rse_pct == Approx(r.parameters[0].rse_pct).epsilon(1e-6));  // same relative error
    CHECK(r.parameters[2].name == "AMP1");
    CHECK(r.parameters[2].value == Approx(1 / v));
    CHECK(r.message.empty());
    // No covariance: values without SEs.
    const auto bare = pk::ModelExponents(*model, theta, Eigen::MatrixXd());
    REQUIRE(bare.ok);
    CHECK(std::isnan(bare.parameters[0].se));
  }
  {  // 2cmt_iv: λ1 + λ2 = k10 + k12 + k21 and λ1 λ2 = k10 k21, fastest first.
    const auto model = pk::MakeModel("2cmt_iv");
    Eigen::VectorXd theta(4);
    theta << 5, 20, 8, 60;  // CL, V1, Q, V2
    const double k10 = 5.0 / 20, k12 = 8.0 / 20, k21 = 8.0 / 60;
    const auto r = pk::ModelExponents(*model, theta, Eigen::MatrixXd::Identity(4, 4) * 0.01);
    REQUIRE(r.ok);
    REQUIRE(r.parameters.size() == 6);
    const double l1 = r.parameters[0].value, l2 = r.parameters[1].value;
    CHECK(l1 > l2);
    CHECK(l1 + l2 == Approx(k10 + k12 + k21));
    CHECK(l1 * l2 == Approx(k10 * k21));
    CHECK(r.parameters[3].value == Approx(std::log(2.0) / l2));
    CHECK(r.message.empty());
  }
  {  // 2cmt_iv SEs against the closed form C(t) = A e^{−αt} + B e^{−βt} (unit dose), differentiated here,
     // with a covariance that correlates all four parameters.
    const auto model = pk::MakeModel("2cmt_iv");
    auto closed = [](const Eigen::VectorXd& p) {  // α, β, t½α, t½β, A, B
      const double k10 = p(0) / p(1), k12 = p(2) / p(1), k21 = p(2) / p(3);
      const double s = k10 + k12 + k21, disc = std::sqrt(s * s - 4 * k10 * k21);
      const double a = (s + disc) / 2, b = (s - disc) / 2;
      Eigen::VectorXd out(6);
      out << a, b, std::log(2.0) / a, std::log(2.0) / b, (a - k21) / (p(1) * (a - b)), (k21 - b) / (p(1) * (a - b));
      return out;
    };
    Eigen::VectorXd theta(4);
    theta << 5, 20, 8, 60;  // CL, V1, Q, V2
    Eigen::MatrixXd l(4, 4);
    l << 0.3, 0, 0, 0, 0.8, 2, 0, 0, -0.2, 0.5, 1, 0, 1.5, -2, 3, 6;
    CheckTwoExponentials(*model, theta, l * l.transpose(), closed);
  }
  {  // 1cmt_oral SEs against the closed form C(t) = KA/(V(KA − k)) (e^{−kt} − e^{−KA t}), k = CL/V (unit
     // dose into the depot), differentiated here, with a covariance that correlates all three parameters.
    const auto model = pk::MakeModel("1cmt_oral");
    auto closed = [](const Eigen::VectorXd& p) {  // KA, k, t½(KA), t½(k), amplitudes of e^{−KA t} and e^{−kt}
      const double ka = p(0), k = p(1) / p(2), c = ka / (p(2) * (ka - k));
      Eigen::VectorXd out(6);
      out << ka, k, std::log(2.0) / ka, std::log(2.0) / k, -c, c;
      return out;
    };
    Eigen::VectorXd theta(3);
    theta << 1.2, 3, 30;  // KA, CL, V
    Eigen::MatrixXd l(3, 3);
    l << 0.2, 0, 0, 0.05, 0.3, 0, -0.1, 1.5, 4;
    CheckTwoExponentials(*model, theta, l * l.transpose(), closed);
  }
  {  // KA within 1e-5 of CL/V: still a sum of exponentials, with a caveat; 1e-2 apart: none.
    const auto model = pk::MakeModel("1cmt_oral");
    Eigen::VectorXd theta(3);
    theta << 0.1 * (1 + 1e-5), 3, 30;  // KA, CL, V
    const auto r = pk::ModelExponents(*model, theta, Eigen::MatrixXd());
    REQUIRE(r.ok);
    CHECK_THAT(r.message, Catch::StartsWith("LAMBDA_ABS and LAMBDA1 nearly coincide (1.0e-05 apart, relative)"));
    theta(0) = 0.1 * 1.01;
    CHECK(pk::ModelExponents(*model, theta, Eigen::MatrixXd()).message.empty());
    // Flip-flop: absorption slower than elimination keeps its label, in second place (fastest first).
    theta(0) = 0.02;
    const auto flip = pk::ModelExponents(*model, theta, Eigen::MatrixXd());
    REQUIRE(flip.ok);
    CHECK(flip.parameters[0].name == "LAMBDA1");
    CHECK(flip.parameters[0].value == Approx(0.1));
    CHECK(flip.parameters[1].name == "LAMBDA_ABS");
    CHECK(flip.parameters[1].value == Approx(0.02));
  }
  {  // Coincident rates (KA = CL/V) have no exponential form: said, not thrown.
    const auto model = pk::MakeModel("1cmt_oral");
    Eigen::VectorXd theta(3);
    theta << 0.1, 3, 30;  // KA, CL, V
    const auto r = pk::ModelExponents(*model, theta, Eigen::MatrixXd());
    CHECK_FALSE(r.ok);
    CHECK(r.message == "A(θ) is defective (coincident rates)");
  }
}

TEST_CASE("infeasible coefficients are reported with a reason", "[conversion]") {
  Eigen::VectorXd c(4);
  c << 0.2, 0.5, 0.1, 0.01;  // s² + 0.2 s + 0.5: complex roots
  const auto readings = pk::ConvertTransferFunction(c, Eigen::MatrixXd());
  CHECK(!Reading(readings, "iv").ok);
  CHECK_THAT(Reading(readings, "iv").message, Catch::Contains("complex roots"));
}
