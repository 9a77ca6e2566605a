// Exact propagation against closed-form solutions.
#include <cmath>

#include <Eigen/Eigenvalues>
#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/linear_model.h"
#include "test_util.h"

using pk_test::RelDiff;
using pk_test::SimulateText;

TEST_CASE("1cmt IV bolus matches D/V exp(-CL/V t), and its AUC is exact", "[closed-form]") {
  const double cl = 2.5, v = 40, dose = 100, k = cl / v;
  const auto sim = SimulateText("1cmt_iv",
                                "ID,TIME,AMT,EVID\n1,0,100,1\n1,0.5,0,0\n1,3,0,0\n1,10,0,0\n1,48,0,0\n",
                                {{"CL", cl}, {"V", v}});
  REQUIRE(sim.ok);
  REQUIRE(sim.rows.size() == 4);
  for (const auto& r : sim.rows) {
    CHECK(RelDiff(r.cp, dose / v * std::exp(-k * r.time)) < 1e-13);
    CHECK(RelDiff(r.auc, dose / cl * (1 - std::exp(-k * r.time))) < 1e-12);
  }
}

TEST_CASE("1cmt oral matches the Bateman function with F", "[closed-form]") {
  const double ka = 1.3, cl = 3, v = 30, f = 0.7, dose = 320, k = cl / v;
  const auto sim = SimulateText("1cmt_oral",
                                "ID,TIME,AMT,EVID,CMT\n1,0,320,1,1\n1,0.25,0,0,2\n1,1,0,0,2\n1,2.5,0,0,2\n1,12,0,0,2\n",
                                {{"KA", ka}, {"CL", cl}, {"V", v}, {"F1", f}});
  REQUIRE(sim.ok);
  REQUIRE(sim.amounts.cols() == static_cast<Eigen::Index>(sim.rows.size()));
  for (size_t i = 0; i < sim.rows.size(); ++i) {
    const auto& r = sim.rows[i];
    const double c = f * dose * ka / (v * (ka - k)) * (std::exp(-k * r.time) - std::exp(-ka * r.time));
    CHECK(RelDiff(r.cp, c) < 1e-12);
    CHECK(RelDiff(sim.amounts(0, static_cast<Eigen::Index>(i)), f * dose * std::exp(-ka * r.time)) < 1e-12);
  }
}

TEST_CASE("2cmt IV bolus matches the biexponential", "[closed-form]") {
  const double cl = 4, v1 = 15, q = 6, v2 = 45, dose = 500;
  const double k10 = cl / v1, k12 = q / v1, k21 = q / v2;
  const double s = k10 + k12 + k21, disc = std::sqrt(s * s - 4 * k10 * k21);
  const double alpha = (s + disc) / 2, beta = (s - disc) / 2;
  const auto sim = SimulateText("2cmt_iv", "ID,TIME,AMT,EVID\n1,0,500,1\n1,0.1,0,0\n1,1,0,0\n1,6,0,0\n1,30,0,0\n",
                                {{"CL", cl}, {"V1", v1}, {"Q", q}, {"V2", v2}});
  REQUIRE(sim.ok);
  for (const auto& r : sim.rows) {
    const double t = r.time;
    const double c = dose / v1 *
                     ((alpha - k21) / (alpha - beta) * std::exp(-alpha * t) +
                      (k21 - beta) / (alpha - beta) * std::exp(-beta * t));
    CHECK(RelDiff(r.cp, c) < 1e-12);
  }
}

TEST_CASE("1cmt zero-order infusion during and after the infusion", "[closed-form]") {
  const double cl = 3, v = 30, k = cl / v, rate = 50, dur = 4;  // AMT = 200
  const auto sim = SimulateText("1cmt_iv", "ID,TIME,AMT,RATE,EVID\n1,0,200,50,1\n1,1,0,0,0\n1,4,0,0,0\n1,9,0,0,0\n",
                                {{"CL", cl}, {"V", v}});
  REQUIRE(sim.ok);
  for (const auto& r : sim.rows) {
    const double t = r.time;
    const double c = t <= dur ? rate / cl * (1 - std::exp(-k * t))
                              : rate / cl * (1 - std::exp(-k * dur)) * std::exp(-k * (t - dur));
    CHECK(RelDiff(r.cp, c) < 1e-12);
  }
  // AUC to infinity of an infusion is AMT/CL; by t = 9 it is the integral of the above.
  const double c_end = rate / cl * (1 - std::exp(-k * dur));
  const double auc9 = rate / cl * (dur - (1 - std::exp(-k * dur)) / k) + c_end * (1 - std::exp(-k * 5)) / k;
  CHECK(RelDiff(sim.rows.back().auc, auc9) < 1e-11);
}

TEST_CASE("repeated doses are the superposition of single doses", "[closed-form]") {
  const double ka = 0.9, cl = 5, v2 = 20, q = 3, v3 = 50;
  const pk::ParameterValues p{{"KA", ka}, {"CL", cl}, {"V2", v2}, {"Q", q}, {"V3", v3}};
  const auto multi = SimulateText("2cmt_oral",
                                  "ID,TIME,AMT,II,ADDL,EVID\n1,0,100,8,4,1\n1,3,0,0,0,2\n1,17.5,0,0,0,2\n1,40,0,0,0,2\n"
                                  "1,55,0,0,0,2\n",
                                  p);
  REQUIRE(multi.ok);
  for (const auto& r : multi.rows) {
    double sum = 0;
    for (int d = 0; d < 5; ++d) {
      const double td = 8.0 * d;
      if (td > r.time) continue;
      const auto single = SimulateText(
          "2cmt_oral", "ID,TIME,AMT,EVID\n1,0,100,1\n1," + std::to_string(r.time - td) + ",0,2\n", p);
      sum += single.rows.back().cp;
    }
    CHECK(RelDiff(r.cp, sum) < 1e-9);
  }
}

TEST_CASE("3cmt IV bolus matches an independent eigendecomposition", "[closed-form]") {
  const auto model = pk::MakeModel("3cmt_iv");
  const auto& lin = dynamic_cast<const pk::LinearModel&>(*model);
  Eigen::VectorXd theta(6);
  theta << 2.0, 8.0, 10.0, 20.0, 1.5, 70.0;  // CL V1 Q2 V2 Q3 V3
  const Eigen::MatrixXd a = lin.SystemMatrix<double>(theta);
  Eigen::EigenSolver<Eigen::MatrixXd> es(a);
  const Eigen::MatrixXcd vecs = es.eigenvectors();
  const Eigen::VectorXcd vals = es.eigenvalues();
  Eigen::VectorXcd x0 = Eigen::VectorXcd::Zero(3);
  x0(0) = 250.0;
  const Eigen::VectorXcd coeff = vecs.fullPivLu().solve(x0);
  const auto sim = SimulateText("3cmt_iv", "ID,TIME,AMT,EVID\n1,0,250,1\n1,0.2,0,0\n1,2,0,0\n1,20,0,0\n1,200,0,0\n",
                                {{"CL", 2}, {"V1", 8}, {"Q2", 10}, {"V2", 20}, {"Q3", 1.5}, {"V3", 70}});
  REQUIRE(sim.ok);
  REQUIRE(sim.amounts.cols() == static_cast<Eigen::Index>(sim.rows.size()));
  for (size_t k = 0; k < sim.rows.size(); ++k) {
    Eigen::VectorXcd x = vecs * (coeff.array() * (vals.array() * sim.rows[k].time).exp()).matrix();
    for (int i = 0; i < 3; ++i) {
      CHECK(RelDiff(sim.amounts(i, static_cast<Eigen::Index>(k)), x(i).real(), 1e-9) < 1e-10);
    }
  }
}

TEST_CASE("step lengths a few ulps to 1e-10 apart share Φ and Γ through the first-order correction",
          "[closed-form]") {
  // Steps of 1 h, then of 1 ± 2e-10 h: within 2⁻³⁰/‖A‖ of the cached 1 h, so Φ(1) and Γ(1) are reused
  // with x + δ(Ax + Bu) (Discretization::GetNearby). Without the correction the concentration would
  // be off by about kδ = 2e-11 relative; with it, the closed form holds to rounding. An infusion
  // (Γ) runs to 4 h, then the decline (Φ alone).
  const double cl = 3, v = 30, k = cl / v, rate = 50, dur = 4;
  const auto sim = SimulateText("1cmt_iv",
                                "ID,TIME,AMT,RATE,EVID\n1,0,200,50,1\n1,1,0,0,0\n1,2,0,0,0\n1,3.0000000002,0,0,0\n"
                                "1,5,0,0,0\n1,6.0000000002,0,0,0\n1,7,0,0,0\n",
                                {{"CL", cl}, {"V", v}});
  REQUIRE(sim.ok);
  REQUIRE(sim.rows.size() == 6);
  for (const auto& r : sim.rows) {
    INFO("t = " << r.time);
    const double t = r.time;
    const double c = t <= dur ? rate / cl * (1 - std::exp(-k * t))
                              : rate / cl * (1 - std::exp(-k * dur)) * std::exp(-k * (t - dur));
    CHECK(RelDiff(r.cp, c) < 1e-13);
  }
}
