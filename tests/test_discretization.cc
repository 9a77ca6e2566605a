// The two exact discretisation paths agree: eigendecomposition (Daleckii–Krein)
// and the seed's block-triangular exponentials, for sensitivities and adjoints.
#include <atomic>
#include <chrono>
#include <memory>
#include <thread>

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

TEST_CASE("a symmetrizing diagonal beyond double range is refused, not searched for forever", "[discretization]") {
  // Reversible exchange with rates 1e200 one way and 1e-200 the other: t_2 = sqrt(1e-400) underflows to 0, which
  // the graph search took for "not visited yet" (a fit of 3cmt_iv that drifted to such rates hung there).
  Eigen::Matrix2d a;
  a << -1e200, 1e200, 1e-200, -1e-200;
  auto done = std::make_shared<std::atomic<int>>(-1);
  std::thread([a, done] {
    Eigen::Vector2d t;
    done->store(pk::internal::SymmetrizingDiagonal(a, &t) ? 1 : 0);
  }).detach();
  for (int waited = 0; waited < 1000 && done->load() < 0; ++waited) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  REQUIRE(done->load() >= 0);  // returned within 10 s
  CHECK(done->load() == 0);
  // Within range the same exchange is symmetrized: t_2/t_1 = sqrt(a_21/a_12).
  a << -4, 4, 1, -1;
  Eigen::Vector2d t;
  REQUIRE(pk::internal::SymmetrizingDiagonal(a, &t));
  CHECK(t(1) / t(0) == Approx(0.5));
}
