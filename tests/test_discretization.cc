// The two exact discretisation paths agree: eigendecomposition (Daleckii–Krein)
// and the seed's block-triangular exponentials, for sensitivities and adjoints.
#include <catch2/catch.hpp>

#include "exact/discretization.h"
#include "pk/catalogue.h"
#include "pk/linear_model.h"

TEST_CASE("eigen and block paths give the same sensitivities and adjoint contractions", "[discretization]") {
  const auto name = GENERATE(as<std::string>{}, "1cmt_oral", "2cmt_iv", "2cmt_oral", "3cmt_oral");
  const auto model = pk::MakeModel(name);
  const auto& lin = dynamic_cast<const pk::LinearModel&>(*model);
  Eigen::VectorXd theta = model->default_parameters();
  for (int i = 0; i < theta.size(); ++i) theta(i) *= 1 + 0.13 * i;
  const Eigen::MatrixXd a = lin.SystemMatrix<double>(theta);
  const int n = static_cast<int>(a.rows());
  std::vector<Eigen::MatrixXd> da;
  for (int j = 0; j < theta.size(); ++j) {
    // Central differences of A are exact here (A is linear in each rate): an independent ∂A/∂θ_j.
    Eigen::VectorXd tp = theta, tm = theta;
    tp(j) *= 1 + 1e-6;
    tm(j) *= 1 - 1e-6;
    da.push_back((lin.SystemMatrix<double>(tp) - lin.SystemMatrix<double>(tm)) / (2e-6 * theta(j)));
  }
  pk::internal::Discretization eig(a, n, true), blk(a, n, false);
  REQUIRE(eig.eigen_path());
  REQUIRE(!blk.eigen_path());
  for (double h : {0.1, 1.0, 7.5}) {
    const auto& se = eig.GetSensitivity(h, false, da);
    const auto& sb = blk.GetSensitivity(h, false, da);
    for (size_t j = 0; j < da.size(); ++j) {
      INFO(name << " h " << h << " j " << j);
      CHECK((se.dphi[j] - sb.dphi[j]).cwiseAbs().maxCoeff() < 1e-9 * (1 + sb.dphi[j].cwiseAbs().maxCoeff()));
    }
    CHECK((eig.Get(h, true).gamma - blk.Get(h, true).gamma).cwiseAbs().maxCoeff() < 1e-13);
    const Eigen::VectorXd lam = Eigen::VectorXd::LinSpaced(n, 1, 2), x = Eigen::VectorXd::LinSpaced(n, 3, -1);
    eig.AccumulateAdjoint(h, lam, x, Eigen::VectorXd());
    blk.AccumulateAdjoint(h, lam, x, Eigen::VectorXd());
  }
  const Eigen::MatrixXd ge = eig.FinishAdjoint(), gb = blk.FinishAdjoint();
  for (const Eigen::MatrixXd& d : da) {
    CHECK(ge.cwiseProduct(d).sum() == Approx(gb.cwiseProduct(d).sum()).epsilon(1e-9));
  }
}
