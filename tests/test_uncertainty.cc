// Parameter uncertainty for simulations (pk/uncertainty.h): draws from the covariance step's normal,
// truncated to the parameter space, and a bootstrap's parameter sets, and their use by replicate.
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "pk/catalogue.h"
#include "pk/dataset.h"
#include "pk/error.h"
#include "pk/model_file.h"
#include "pk/population_simulation.h"
#include "pk/uncertainty.h"
#include "test_util.h"

namespace {

// 1cmt_iv's estimates: CL 3, V 30, Ω over CL and V with a covariance, proportional σ 0.1.
pk::PopulationEstimates Estimates() {
  pk::PopulationEstimates e;
  e.source = "est";
  e.theta = {{"CL", 3}, {"V", 30}};
  e.etas = {"CL", "V"};
  e.eta_log_normal = {true, true};
  e.omega.resize(2, 2);
  e.omega << 0.09, 0.02, 0.02, 0.04;
  e.sigma_names = {"SIGMA_PROP"};
  e.sigma = Eigen::VectorXd::Constant(1, 0.1);
  return e;
}

// A file under the build tree, unique to this process (ctest runs tests in parallel).
std::string WriteTemporary(const std::string& name, const std::string& text) {
  const std::string dir = std::string(PK_BINARY_DIR) + "/uncertainty_test_" + std::to_string(::getpid());
  std::filesystem::create_directories(dir);
  const std::string path = dir + "/" + name;
  std::ofstream(path) << text;
  return path;
}

}  // namespace

TEST_CASE("uncertainty draws are N(estimates, covariance): mean, covariance, reproducibility", "[uncertainty]") {
  const auto model = pk::MakeModel("1cmt_iv");
  const pk::PopulationEstimates e = Estimates();
  pk::EstimatesCovariance c;
  c.names = {"CL", "V", "OMEGA(CL)", "OMEGA(V,CL)", "SIGMA_PROP"};
  const Eigen::VectorXd sd = (Eigen::VectorXd(5) << 0.1, 1.5, 0.01, 0.004, 0.005).finished();
  Eigen::MatrixXd corr = Eigen::MatrixXd::Identity(5, 5);
  corr(0, 1) = corr(1, 0) = 0.4;  // CL with V
  corr(2, 3) = corr(3, 2) = -0.3;
  c.covariance = sd.asDiagonal() * corr * sd.asDiagonal();
  const int n = 4000;
  int redrawn = -1;
  const std::vector<pk::PopulationEstimates> sets = pk::DrawFromCovariance(e, c, *model, n, 7, &redrawn);
  REQUIRE(sets.size() == static_cast<size_t>(n));
  CHECK(redrawn == 0);  // every SD is small beside its value: no draw leaves the parameter space
  Eigen::MatrixXd x(n, 5);
  for (int r = 0; r < n; ++r) {
    const pk::PopulationEstimates& s = sets[static_cast<size_t>(r)];
    x.row(r) << s.theta.at("CL"), s.theta.at("V"), s.omega(0, 0), s.omega(1, 0), s.sigma(0);
    CHECK(s.omega(0, 1) == s.omega(1, 0));
    CHECK(s.omega(1, 1) == 0.04);  // not in the covariance: held
  }
  const Eigen::VectorXd centre = (Eigen::VectorXd(5) << 3, 30, 0.09, 0.02, 0.1).finished();
  const Eigen::RowVectorXd mean = x.colwise().mean();
  const Eigen::MatrixXd d = x.rowwise() - mean;
  const Eigen::MatrixXd cov = d.transpose() * d / (n - 1);
  for (int k = 0; k < 5; ++k) {
    INFO("parameter " << k);
    CHECK(std::abs(mean(k) - centre(k)) < 4 * sd(k) / std::sqrt(n));
    CHECK(std::abs(std::sqrt(cov(k, k)) / sd(k) - 1) < 4 / std::sqrt(2.0 * n));
  }
  // Correlations within 4 of their SEs ((1 − ρ²)/√n).
  CHECK(std::abs(cov(0, 1) / std::sqrt(cov(0, 0) * cov(1, 1)) - 0.4) < 4 * (1 - 0.16) / std::sqrt(n));
  CHECK(std::abs(cov(2, 3) / std::sqrt(cov(2, 2) * cov(3, 3)) + 0.3) < 4 * (1 - 0.09) / std::sqrt(n));
  CHECK(std::abs(cov(0, 4) / std::sqrt(cov(0, 0) * cov(4, 4))) < 4 / std::sqrt(n));
  // Set r comes from a stream of its own: the first sets do not depend on how many are drawn.
  const auto few = pk::DrawFromCovariance(e, c, *model, 3, 7);
  CHECK(few[2].theta == sets[2].theta);
  CHECK(few[2].omega == sets[2].omega);
  CHECK(pk::DrawFromCovariance(e, c, *model, 3, 8)[2].theta != sets[2].theta);
  // Names the estimates do not hold; a covariance that is not positive semi-definite.
  pk::EstimatesCovariance bad = c;
  bad.names[1] = "KA";
  CHECK_THROWS_WITH(pk::DrawFromCovariance(e, bad, *model, 1, 1), Catch::Contains("no typical value KA"));
  bad = c;
  bad.names[2] = "OMEGA(KA)";
  CHECK_THROWS_WITH(pk::DrawFromCovariance(e, bad, *model, 1, 1), Catch::Contains("no η for OMEGA(KA)"));
  bad = c;
  bad.covariance(0, 0) = -1;
  CHECK_THROWS_WITH(pk::DrawFromCovariance(e, bad, *model, 1, 1), Catch::Contains("not symmetric positive"));
}

TEST_CASE("uncertainty draws stay in the parameter space, and SAME blocks follow their source", "[uncertainty]") {
  // A variance whose SE is as large as it, and a θ near 0: draws outside are drawn again.
  const auto model = pk::MakeModel("1cmt_iv");
  pk::PopulationEstimates e = Estimates();
  e.theta["CL"] = 0.05;
  pk::EstimatesCovariance c;
  c.names = {"CL", "OMEGA(CL)", "SIGMA_PROP"};
  c.covariance = Eigen::Vector3d(0.05 * 0.05, 0.09 * 0.09, 0.08 * 0.08).asDiagonal();
  int redrawn = 0;
  const auto sets = pk::DrawFromCovariance(e, c, *model, 500, 3, &redrawn);
  CHECK(redrawn > 100);  // about a sixth of each parameter's draws fall below 0
  for (const auto& s : sets) {
    CHECK(s.theta.at("CL") > 0);
    CHECK(s.sigma(0) > 0);
    CHECK(s.omega(0, 0) * s.omega(1, 1) > s.omega(0, 1) * s.omega(0, 1));
  }
  // models/iov_pop.pkm: IOV2 and IOV3 ~ SAME as IOV1 take its drawn variance.
  const auto iov = pk::LoadModelFile(std::string(PK_SOURCE_DIR) + "/models/iov_pop.pkm", pk::RandomEffects::kParameters);
  pk::PopulationEstimates p;
  p.source = "iov";
  p.theta = {{"TVKA", 1.5}, {"TVCL", 3}, {"TVV", 30}};
  p.etas = {"ETA_CL", "ETA_V", "IOV1", "IOV2", "IOV3"};
  p.eta_log_normal = std::vector<bool>(5, false);
  p.omega = Eigen::VectorXd((Eigen::VectorXd(5) << 0.09, 0.04, 0.03, 0.03, 0.03).finished()).asDiagonal();
  p.sigma_names = {"SIGMA_ADD"};
  p.sigma = Eigen::VectorXd::Constant(1, 0.15);
  pk::EstimatesCovariance ci;
  ci.names = {"TVCL", "OMEGA(IOV1)"};
  ci.covariance = Eigen::Vector2d(0.01, 1e-4).asDiagonal();
  for (const auto& s : pk::DrawFromCovariance(p, ci, *iov, 20, 5)) {
    CHECK(s.omega(2, 2) != 0.03);
    CHECK(s.omega(3, 3) == s.omega(2, 2));
    CHECK(s.omega(4, 4) == s.omega(2, 2));
  }
  // A run whose --block regrouped IOV2 estimated it on its own: its covariance names it, and the tie
  // is not imposed on it (IOV3, still SAME as IOV2 in the file and not named, follows IOV2).
  ci.names = {"TVCL", "OMEGA(IOV1)", "OMEGA(IOV2)"};
  ci.covariance = Eigen::Vector3d(0.01, 1e-4, 1e-4).asDiagonal();
  for (const auto& s : pk::DrawFromCovariance(p, ci, *iov, 20, 5)) {
    CHECK(s.omega(3, 3) != s.omega(2, 2));
    CHECK(s.omega(4, 4) == s.omega(3, 3));
  }
}

TEST_CASE("the estimates' covariance and a bootstrap's parameter sets are read from pkpop's files", "[uncertainty][reader]") {
  const auto model = pk::MakeModel("1cmt_iv");
  const pk::PopulationEstimates e = Estimates();
  const std::string cov = WriteTemporary("cov.csv",
                                         "PARAMETER,CL,\"OMEGA(V,CL)\"\nCL,0.01,0.001\n\"OMEGA(V,CL)\",0.001,0.0004\n");
  const pk::EstimatesCovariance c = pk::ReadEstimatesCovariance(cov);
  CHECK(c.names == std::vector<std::string>{"CL", "OMEGA(V,CL)"});
  CHECK(c.covariance(0, 1) == 0.001);
  CHECK(c.covariance(1, 1) == 0.0004);
  CHECK_THROWS_WITH(pk::ReadEstimatesCovariance(WriteTemporary("cov2.csv", "PARAMETER,CL,V\nV,1,0\nCL,0,1\n")),
                    Catch::Contains("cov2.csv:2:1: expected the row of CL, found V"));
  CHECK_THROWS_WITH(pk::ReadEstimatesCovariance(WriteTemporary("cov3.csv", "PARAMETER,CL,V\nCL,1,0.5\nV,0,1\n")),
                    Catch::Contains("cov3.csv:3:2: the covariance is not symmetric: V with CL"));
  CHECK_THROWS_WITH(pk::ReadEstimatesCovariance(WriteTemporary("cov4.csv", "PARAMETER,CL\nCL,x\n")),
                    Catch::Contains("cov4.csv:2:2: 'x' is not a number"));
  const std::string boot = WriteTemporary(
      "boot.csv",
      "REPLICATE,CONVERGED,BOUNDARY,USED,OFV,CL,V,OMEGA(CL),\"OMEGA(V,CL)\",OMEGA(V),SIGMA_PROP\n"
      "1,1,0,1,100,3.1,29,0.08,0.01,0.05,0.11\n2,0,0,0,,,,,,,\n3,1,0,1,99,2.9,31,0.1,0.03,0.03,0.09\n");
  const auto sets = pk::ReadParameterSets(boot, e, *model);
  REQUIRE(sets.size() == 2);  // the unused replicate 2 is left out
  CHECK(sets[0].theta.at("CL") == 3.1);
  CHECK(sets[1].theta.at("V") == 31);
  CHECK(sets[1].omega(0, 1) == 0.03);
  CHECK(sets[1].omega(1, 0) == 0.03);
  CHECK(sets[0].sigma(0) == 0.11);
  const std::string all = "REPLICATE,USED,CL,V,OMEGA(CL),\"OMEGA(V,CL)\",OMEGA(V),SIGMA_PROP";
  CHECK_THROWS_WITH(
      pk::ReadParameterSets(WriteTemporary("boot2.csv", all + ",KA\n1,1,3,30,0.1,0.01,0.04,0.1,2\n"), e, *model),
      Catch::Contains("boot2.csv:1:9: est has no typical value KA"));
  CHECK_THROWS_WITH(pk::ReadParameterSets(WriteTemporary("boot3.csv", all + "\n1,0,3,30,0.1,0.01,0.04,0.1\n"), e, *model),
                    Catch::Contains("no parameter set"));
  // A bootstrap of another run: a parameter of the estimates missing, or a covariance they do not have.
  CHECK_THROWS_WITH(pk::ReadParameterSets(WriteTemporary("boot4.csv", "REPLICATE,USED,CL,V,OMEGA(CL),SIGMA_PROP\n"
                                                                      "1,1,3,30,0.1,0.1\n"),
                                          e, *model),
                    Catch::Contains("boot4.csv:1: no column OMEGA(V)"));
  pk::PopulationEstimates diagonal = e;
  diagonal.omega(0, 1) = diagonal.omega(1, 0) = 0;
  CHECK_THROWS_WITH(pk::ReadParameterSets(boot, diagonal, *model),
                    Catch::Contains("boot.csv:1:9: OMEGA(V,CL): a covariance est does not have"));
  // A used replicate outside the parameter space is named by its line.
  CHECK_THROWS_WITH(pk::ReadParameterSets(WriteTemporary("boot5.csv", all + "\n1,1,3,30,0.1,0.01,0.04,0.1\n"
                                                                            "2,1,-3,30,0.1,0.01,0.04,0.1\n"),
                                          e, *model),
                    Catch::Contains("boot5.csv:3: a used replicate outside the parameter space: CL = -3 is not positive"));
}

TEST_CASE("a simulation with uncertainty takes replicate r's θ, Ω and σ from set r mod n, its η streams unchanged",
          "[uncertainty][simulation]") {
  const auto regimen = std::make_shared<pk::Dataset>(
      pk::ParseDataset("ID,TIME,AMT,EVID,MDV\n1,0,100,1,1\n1,2,0,2,1\n1,8,0,2,1\n", "regimen.csv"));
  const auto model = pk::MakeModel("1cmt_iv");
  const pk::PopulationEstimates e = Estimates();
  pk::PopulationEstimates slow = e, fast = e;
  slow.theta["CL"] = 1;
  fast.theta["CL"] = 10;
  fast.omega *= 4;  // η = L z with L doubled
  pk::VariabilityOptions vo;
  vo.replicates = 3;
  vo.subjects = 4;
  vo.residual_error = false;
  const auto run = [&](const pk::VariabilityOptions& o) {
    std::vector<pk::SubjectSimulation> got;
    pk::SimulationSink sink;
    sink.consume = [&](pk::SubjectSimulation&& s, std::string&&) { got.push_back(std::move(s)); };
    pk::SimulateEachWithVariability(*model, *regimen, e, {}, {}, o, sink);
    return got;
  };
  const auto plain = run(vo);
  vo.parameter_sets = {slow, fast};
  const auto uncertain = run(vo);
  REQUIRE(uncertain.size() == 12);
  for (size_t k = 0; k < uncertain.size(); ++k) {
    const int r = uncertain[k].replicate;
    const bool is_fast = r % 2 == 1;  // sets slow, fast, slow
    INFO("replicate " << r << ", subject " << k % 4);
    CHECK(uncertain[k].eta == (is_fast ? 2.0 : 1.0) * plain[k].eta);
    const double cl = (is_fast ? 10.0 : 1.0) * std::exp(uncertain[k].eta(0)), v = 30 * std::exp(uncertain[k].eta(1));
    for (const auto& row : uncertain[k].rows) CHECK(pk_test::RelDiff(row.cp, 100 / v * std::exp(-cl / v * row.time)) < 1e-12);
  }
}
