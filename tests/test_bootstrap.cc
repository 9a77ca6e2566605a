// The nonparametric bootstrap of a population fit: the draws of subjects (reproducible, uniform), and
// on data simulated from a known population, bootstrap SEs against the covariance step's, whatever the
// threads.
#include <algorithm>
#include <cmath>
#include <sstream>

#include "pk/bootstrap.h"
#include "pk/catalogue.h"
#include "pk/error.h"
#include "pk/output.h"
#include "pk/population.h"
#include "pk/population_simulation.h"
#include "pk/residual_error.h"
#include "simulation/normal_stream.h"
#include "test_util.h"

namespace {

// 40 subjects of 1cmt_iv (100 at 0 h, samples at 0.5 … 24 h) simulated at CL 3, V 30, ω² 0.09 and 0.04,
// proportional σ 0.1 (seed 3), as a problem with η on CL and V.
pk::PopulationProblem SimulatedProblem() {
  const std::vector<double> times = {0.5, 1, 2, 4, 8, 24};
  const auto design = [&](const std::vector<double>& dv) {
    std::string text = "ID,TIME,AMT,EVID,MDV,DV\n";
    for (int id = 1; id <= 40; ++id) {
      text += std::to_string(id) + ",0,100,1,1,.\n";
      for (size_t j = 0; j < times.size(); ++j) {
        const size_t k = static_cast<size_t>(id - 1) * times.size() + j;
        text += std::to_string(id) + "," + pk::FormatNumber(times[j]) + ",0,0,0," +
                (dv.empty() ? std::string("1") : pk::FormatNumber(dv[k])) + "\n";
      }
    }
    return std::make_shared<pk::Dataset>(pk::ParseDataset(text, "bootstrap.csv"));
  };
  pk::ObjectiveOptions o;
  o.error_model = pk::MakeResidualError("proportional");
  pk::PopulationParameters truth;
  truth.theta.resize(2);
  truth.theta << 3, 30;
  truth.omega = Eigen::Vector2d(0.09, 0.04).asDiagonal();
  truth.sigma = Eigen::VectorXd::Constant(1, 0.1);
  pk::PopulationSimulationOptions so;
  so.seed = 3;
  const pk::PopulationProblem placeholder(pk::MakeModel("1cmt_iv"), design({}), {"CL", "V"}, o);
  const pk::SimulatedReplicate sim = pk::SimulateReplicate(placeholder, truth, so, 0);
  std::vector<double> dv;
  for (const auto& s : sim.subjects) dv.insert(dv.end(), s.dv.data(), s.dv.data() + s.dv.size());
  return pk::PopulationProblem(pk::MakeModel("1cmt_iv"), design(dv), {"CL", "V"}, o);
}

}  // namespace

TEST_CASE("bootstrap draws: reproducible, one stream a replicate, uniform over the subjects", "[bootstrap]") {
  CHECK(pk::BootstrapSample(7, 3, 25) == pk::BootstrapSample(7, 3, 25));
  CHECK(pk::BootstrapSample(7, 3, 25) != pk::BootstrapSample(7, 4, 25));
  CHECK(pk::BootstrapSample(7, 3, 25) != pk::BootstrapSample(8, 3, 25));
  std::vector<int> count(10, 0);
  for (int r = 0; r < 2000; ++r) {
    for (int k : pk::BootstrapSample(1, r, 10)) {
      REQUIRE(k >= 0);
      REQUIRE(k < 10);
      ++count[static_cast<size_t>(k)];
    }
  }
  for (int c : count) CHECK(std::abs(c - 2000) < 5 * std::sqrt(2000 * 0.9));  // binomial SD √(Np(1 − p))
}

TEST_CASE("stratified bootstrap draws keep each stratum's size and draw within it", "[bootstrap]") {
  // 3 strata of 5, 2 and 8 subjects, interleaved.
  std::vector<double> strata;
  for (int i = 0; i < 15; ++i) strata.push_back(i % 3 == 0 ? 1.0 : i % 7 == 1 ? 2.0 : 3.5);
  std::vector<int> count(15, 0);
  for (int r = 0; r < 3000; ++r) {
    const std::vector<int> drawn = pk::BootstrapSample(5, r, strata);
    REQUIRE(drawn.size() == strata.size());
    for (size_t i = 0; i < drawn.size(); ++i) {
      REQUIRE(drawn[i] >= 0);
      REQUIRE(drawn[i] < 15);
      CHECK(strata[static_cast<size_t>(drawn[i])] == strata[i]);  // within the position's stratum
      ++count[static_cast<size_t>(drawn[i])];
    }
  }
  // Each subject drawn as often as its stratum's size over the replicates: 3000 (binomial spread).
  for (int i = 0; i < 15; ++i) {
    const double n = static_cast<double>(std::count(strata.begin(), strata.end(), strata[static_cast<size_t>(i)]));
    CHECK(std::abs(count[static_cast<size_t>(i)] - 3000) < 5 * std::sqrt(3000 * n * (1 - 1 / n)));
  }
  // One stratum: the unstratified draws.
  CHECK(pk::BootstrapSample(9, 4, std::vector<double>(12, 2.0)) == pk::BootstrapSample(9, 4, 12));
  // Strata from a column: each subject's first record; an unknown column is named.
  const pk::Dataset data = pk::ParseDataset("ID,TIME,AMT,DV,EVID,MDV,STUDY\n1,0,10,.,1,1,1\n1,1,0,5,0,0,1\n"
                                            "2,0,10,.,1,1,2\n2,1,0,4,0,0,2\n",
                                            "strata.csv");
  CHECK(pk::BootstrapStrata(data, "STUDY") == std::vector<double>{1, 2});
  CHECK_THROWS_WITH(pk::BootstrapStrata(data, "ARM"), Catch::Contains("'ARM'") && Catch::Contains("STUDY"));
  CHECK_THROWS_WITH(pk::BootstrapStrata(data, "EVID"), Catch::Contains("a PREDPP column"));
  // A stratum is one value a subject (PsN refuses a column that changes within one): the line is named.
  const pk::Dataset changing = pk::ParseDataset("ID,TIME,AMT,DV,EVID,MDV,STUDY\n1,0,10,.,1,1,1\n1,1,0,5,0,0,2\n",
                                                "changing.csv");
  CHECK_THROWS_WITH(pk::BootstrapStrata(changing, "STUDY"),
                    Catch::Contains("changing.csv:3:7") && Catch::Contains("ID 1 has 2 here and 1 on its first record"));
}

TEST_CASE("a bootstrap's replicates and table do not depend on the threads", "[bootstrap][population]") {
  const pk::PopulationProblem problem = SimulatedProblem();
  pk::PopulationOptions fo;
  fo.covariance = false;
  fo.structure.omega_blocks = {2};  // a block: its covariance's name has a comma
  const pk::PopulationSummary fit = pk::FitPopulation(problem, problem.DefaultParameters(), fo);
  REQUIRE(fit.converged);
  pk::BootstrapOptions o;
  o.replicates = 6;
  o.seed = 11;
  o.fit = fo;
  o.threads = 2;
  const pk::BootstrapSummary two = pk::BootstrapPopulation(problem, fit, o);
  o.threads = 1;
  const pk::BootstrapSummary one = pk::BootstrapPopulation(problem, fit, o);
  CHECK(pk::BootstrapCsv(one) == pk::BootstrapCsv(two));
  CHECK(one.FullReport() == two.FullReport());
  REQUIRE(one.runs.size() == 6);
  CHECK(one.converged == 6);
  CHECK(one.used == 6);
  // CL's statistics from the replicates' rows: the median, R's type 7 at 2.5 and 97.5, the SD (R − 1).
  std::vector<double> cl;
  for (const auto& r : one.runs) cl.push_back(r.estimates(0));
  std::sort(cl.begin(), cl.end());
  double mean = 0, ss = 0;
  for (double v : cl) mean += v / 6;
  for (double v : cl) ss += (v - mean) * (v - mean);
  CHECK(one.parameters[0].median == Approx((cl[2] + cl[3]) / 2).epsilon(1e-15));
  CHECK(one.parameters[0].lower == Approx(cl[0] + 0.125 * (cl[1] - cl[0])).epsilon(1e-15));  // h = 1 + 5·0.025
  CHECK(one.parameters[0].upper == Approx(cl[4] + 0.875 * (cl[5] - cl[4])).epsilon(1e-15));
  CHECK(one.parameters[0].se == Approx(std::sqrt(ss / 5)).epsilon(1e-13));
  CHECK(one.parameters[0].mean == Approx(mean).epsilon(1e-15));
  CHECK(one.parameters[0].bias == Approx(mean - fit.estimates[0].estimate).margin(1e-12 * mean));
  CHECK_THAT(one.FullReport(), Catch::Contains("median        mean        bias    bootstrap SE"));
  // The names of a block's covariance hold a comma: quoted in the header.
  CHECK(pk::BootstrapCsv(one).substr(0, pk::BootstrapCsv(one).find('\n')) ==
        "REPLICATE,CONVERGED,BOUNDARY,USED,OFV,CL,V,OMEGA(CL),\"OMEGA(V,CL)\",OMEGA(V),SIGMA_PROP");
  o.stratify = "HALF";  // a column SimulatedProblem does not have
  CHECK_THROWS_AS(pk::BootstrapPopulation(problem, fit, o), pk::InputError);
  o.stratify.clear();
  o.replicates = 0;
  CHECK_THROWS_AS(pk::BootstrapPopulation(problem, fit, o), pk::InputError);
  o.replicates = 2;
  o.fit.max_iterations = 0;  // every replicate would stay at the estimates
  CHECK_THROWS_AS(pk::BootstrapPopulation(problem, fit, o), pk::InputError);
}

TEST_CASE("a fit without its tables (a bootstrap replicate's) has the estimates, OFV and SEs of one with them",
          "[bootstrap][population]") {
  const pk::PopulationProblem problem = SimulatedProblem();
  for (pk::PopulationMethod method : {pk::PopulationMethod::kFo, pk::PopulationMethod::kFocei}) {
    INFO(pk::ToString(method));
    pk::PopulationOptions o;
    o.method = method;
    o.max_iterations = 30;
    const pk::PopulationSummary with = pk::FitPopulation(problem, problem.DefaultParameters(), o);
    o.tables = false;
    const pk::PopulationSummary without = pk::FitPopulation(problem, problem.DefaultParameters(), o);
    REQUIRE(with.estimates.size() == without.estimates.size());
    CHECK(with.ofv == without.ofv);
    CHECK(with.evaluations == without.evaluations);
    for (size_t k = 0; k < with.estimates.size(); ++k) {
      INFO(with.estimates[k].name);
      CHECK(with.estimates[k].estimate == without.estimates[k].estimate);
      CHECK(with.estimates[k].se == without.estimates[k].se);
      CHECK(with.estimates[k].se > 0);
    }
    CHECK(with.subjects.size() == 40);
    CHECK(with.rows.size() == 240);
    CHECK(with.eta_shrinkage_sd.size() == 2);
    CHECK_THAT(with.FullReport(), Catch::Contains("shrinkage (SD form"));
    CHECK(without.subjects.empty());
    CHECK(without.rows.empty());
    CHECK(without.eta_shrinkage_sd.size() == 0);
    CHECK_THAT(without.FullReport(), Catch::Contains("no tables: η̂, residuals and shrinkage not formed") &&
                                         !Catch::Contains("shrinkage (SD form"));
  }
}

TEST_CASE("the bootstrap's draws are a stream apart from every subject's η and ε", "[bootstrap][simulation]") {
  for (int replicate : {0, 5}) {
    pk::internal::NormalStream draws(9, replicate, 0, pk::internal::kBootstrapStream);
    for (int subject = 0; subject < 3; ++subject) {
      for (int kind : {pk::internal::kEtaStream, pk::internal::kEpsilonStream}) {
        pk::internal::NormalStream other(9, replicate, subject, kind), again(9, replicate, 0, pk::internal::kBootstrapStream);
        CHECK(other.NextUniform() != again.NextUniform());
      }
    }
    CHECK(draws.NextUniform() > 0);
  }
}

TEST_CASE("bootstrap SEs of data simulated from a known population agree with the covariance step's",
          "[bootstrap][population][release-only]") {
  const pk::PopulationProblem problem = SimulatedProblem();
  const pk::PopulationSummary fit = pk::FitPopulation(problem, problem.DefaultParameters(), pk::PopulationOptions());
  REQUIRE(fit.converged);
  REQUIRE(std::isfinite(fit.estimates[0].se));
  pk::BootstrapOptions o;
  o.replicates = 100;
  o.threads = 2;
  const pk::BootstrapSummary b = pk::BootstrapPopulation(problem, fit, o);
  INFO(b.FullReport() << fit.FullReport());
  CHECK(b.converged >= 95);
  // θ, ω² and σ: the bootstrap SE within 0.7 to 1.4 times the sandwich's (an SE from 100 replicates
  // has a sampling error of about 7%; the sandwich's own is larger), and the interval around the
  // estimate.
  for (size_t k = 0; k < fit.estimates.size(); ++k) {
    const pk::PopulationEstimate& e = fit.estimates[k];
    const pk::BootstrapParameter& p = b.parameters[k];
    INFO(e.name);
    CHECK(p.name == e.name);
    CHECK(p.se / e.se > 0.7);
    CHECK(p.se / e.se < 1.4);
    CHECK(p.lower < e.estimate);
    CHECK(p.upper > e.estimate);
    CHECK(std::abs(p.median - e.estimate) < 0.5 * p.se);
  }
}
