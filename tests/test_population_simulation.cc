// Simulation from a population model and visual predictive checks: the drawn η against Ω, the
// residuals against the error models, IPRED and PRED against the closed form, reproducibility, and
// the VPC's statistics against R (tests/reference/make_vpc_reference.R).
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <map>
#include <numeric>
#include <sstream>

#include "pk/catalogue.h"
#include "pk/error.h"
#include "pk/output.h"
#include "pk/population.h"
#include "pk/population_estimates.h"
#include "pk/population_simulation.h"
#include "pk/residual_error.h"
#include "pk/vpc.h"
#include "simulation/normal_stream.h"
#include "test_util.h"

namespace {

// `subjects` subjects of 1cmt_iv: 100 at time 0 and samples at `times` (DV 1, a placeholder).
std::shared_ptr<pk::Dataset> Design(int subjects, const std::vector<double>& times, double dose_time = 0) {
  std::string text = "ID,TIME,AMT,EVID,MDV,DV\n";
  for (int id = 1; id <= subjects; ++id) {
    std::string samples;
    for (double t : times) samples += std::to_string(id) + "," + pk::FormatNumber(t) + ",0,0,0,1\n";
    const std::string dose = std::to_string(id) + "," + pk::FormatNumber(dose_time) + ",100,1,1,.\n";
    text += dose_time > 0 ? samples + dose : dose + samples;
  }
  return std::make_shared<pk::Dataset>(pk::ParseDataset(text, "design.csv"));
}

pk::PopulationParameters Truth(double sigma) {
  pk::PopulationParameters p;
  p.theta.resize(2);
  p.theta << 3, 30;  // CL, V
  p.omega.resize(2, 2);
  p.omega << 0.09, 0.03, 0.03, 0.04;
  p.sigma = Eigen::VectorXd::Constant(1, sigma);
  return p;
}

pk::PopulationProblem Problem(const std::shared_ptr<pk::Dataset>& data, const std::string& error) {
  pk::ObjectiveOptions o;
  o.error_model = pk::MakeResidualError(error);
  return pk::PopulationProblem(pk::MakeModel("1cmt_iv"), data, {"CL", "V"}, o);
}

std::vector<pk::SimulatedReplicate> Run(const pk::PopulationProblem& problem, const pk::PopulationParameters& p,
                                        const pk::PopulationSimulationOptions& o) {
  std::vector<pk::SimulatedReplicate> out;
  pk::SimulatePopulation(problem, p, o, [&](const pk::SimulatedReplicate& r) { out.push_back(r); });
  return out;
}

bool Same(const pk::SimulatedReplicate& a, const pk::SimulatedReplicate& b) {
  if (a.subjects.size() != b.subjects.size()) return false;
  for (size_t i = 0; i < a.subjects.size(); ++i) {
    const auto &x = a.subjects[i], &y = b.subjects[i];
    if (x.ok != y.ok || x.eta != y.eta || x.ipred != y.ipred || x.dv != y.dv) return false;
  }
  return true;
}

}  // namespace

TEST_CASE("population simulation draws η from Ω, and IPRED and PRED are the model's at η", "[population][simulation]") {
  const std::vector<double> times = {1, 4, 12};
  const auto data = Design(1000, times);
  const pk::PopulationProblem problem = Problem(data, "proportional");
  const pk::PopulationParameters p = Truth(0.1);
  pk::PopulationSimulationOptions o;
  o.seed = 42;
  o.threads = 2;
  o.replicates = 40;  // 40 000 draws: 5 SE of ω² is 3% of it
  const std::vector<pk::SimulatedReplicate> sims = Run(problem, p, o);
  REQUIRE(sims.size() == 40);
  const pk::SimulationDesign design = pk::MakeSimulationDesign(problem, p);
  const double n = 40.0 * 1000;
  Eigen::Matrix2d second = Eigen::Matrix2d::Zero();
  for (const pk::SimulatedReplicate& r : sims) {
  REQUIRE(r.failed == 0);
  for (size_t i = 0; i < r.subjects.size(); ++i) {
    const pk::SimulatedSubject& s = r.subjects[i];
    REQUIRE(s.ok);
    second += s.eta * s.eta.transpose() / n;
    const double cl = 3 * std::exp(s.eta(0)), v = 30 * std::exp(s.eta(1));
    for (size_t j = 0; j < times.size(); ++j) {
      const auto jj = static_cast<Eigen::Index>(j);
      CHECK(pk_test::RelDiff(s.ipred(jj), 100 / v * std::exp(-cl / v * times[j])) < 1e-12);
      CHECK(pk_test::RelDiff(design.subjects[i].pred(jj), 100 / 30.0 * std::exp(-0.1 * times[j])) < 1e-12);
      CHECK(design.subjects[i].time[j] == times[j]);
    }
  }
  }
  // E[ηηᵀ] = Ω, each entry within 5 standard errors: Var(η_a η_b) = Ω_aa Ω_bb + Ω_ab².
  for (int a = 0; a < 2; ++a) {
    for (int b = 0; b < 2; ++b) {
      const double se = std::sqrt((p.omega(a, a) * p.omega(b, b) + p.omega(a, b) * p.omega(a, b)) / n);
      INFO("Ω(" << a << "," << b << ") " << p.omega(a, b) << ", drawn " << second(a, b) << ", SE " << se);
      CHECK(std::fabs(second(a, b) - p.omega(a, b)) < 5 * se);
    }
  }
}

TEST_CASE("population simulation adds ε as each error model defines it", "[population][simulation]") {
  const std::vector<double> times = {1, 4, 12};
  const auto data = Design(1000, times);
  struct Case {
    std::string error;
    std::vector<double> sigma;
    std::function<double(double)> variance;  // of T(y) at ŷ
    bool log;
  };
  const std::vector<Case> cases = {
      {"additive", {0.2}, [](double) { return 0.04; }, false},
      {"proportional", {0.15}, [](double y) { return 0.0225 * y * y; }, false},
      {"combined", {0.1, 0.2}, [](double y) { return 0.01 + 0.04 * y * y; }, false},
      {"exponential", {0.25}, [](double) { return 0.0625; }, true}};
  for (const Case& c : cases) {
    INFO(c.error);
    const pk::PopulationProblem problem = Problem(data, c.error);
    pk::PopulationParameters p = Truth(0);
    p.sigma = Eigen::Map<const Eigen::VectorXd>(c.sigma.data(), static_cast<Eigen::Index>(c.sigma.size()));
    pk::PopulationSimulationOptions o;
    o.seed = 7;
    o.replicates = 40;  // 120 000 samples: 5 SE of the variance is 2% of it
    double sum = 0, squares = 0, count = 0;
    for (const pk::SimulatedReplicate& r : Run(problem, p, o))
    for (const pk::SimulatedSubject& s : r.subjects) {
      REQUIRE(s.ok);
      for (Eigen::Index j = 0; j < s.dv.size(); ++j) {
        const double z = c.log ? (std::log(s.dv(j)) - std::log(s.ipred(j))) / std::sqrt(c.variance(s.ipred(j)))
                               : (s.dv(j) - s.ipred(j)) / std::sqrt(c.variance(s.ipred(j)));
        sum += z;
        squares += z * z;
        ++count;
      }
    }
    const double mean = sum / count, variance = squares / count - mean * mean;
    INFO("standardised residuals: mean " << mean << ", variance " << variance << " over " << count);
    CHECK(std::fabs(mean) < 5 / std::sqrt(count));
    CHECK(std::fabs(variance - 1) < 5 * std::sqrt(2 / count));
  }
}

TEST_CASE("population simulation is reproducible: seed, threads, replicates, residual error",
          "[population][simulation]") {
  const auto data = Design(40, {0.5, 2, 8});
  const pk::PopulationProblem problem = Problem(data, "combined");
  pk::PopulationParameters p = Truth(0.1);
  p.sigma = Eigen::Vector2d(0.05, 0.1);
  pk::PopulationSimulationOptions o;
  o.seed = 123456789012345ULL;
  o.replicates = 3;
  const auto three = Run(problem, p, o);
  REQUIRE(three.size() == 3);
  for (int k = 0; k < 3; ++k) CHECK(three[static_cast<size_t>(k)].replicate == k);
  o.replicates = 1;
  const auto one = Run(problem, p, o);
  CHECK(Same(one[0], three[0]));            // a replicate does not depend on how many follow
  CHECK_FALSE(Same(three[0], three[1]));    // the replicates differ
  o.threads = 3;
  CHECK(Same(Run(problem, p, o)[0], one[0]));  // nor on the threads: a replicate's subjects on three
  o.replicates = 6;
  o.threads = 1;
  const auto serial = Run(problem, p, o);
  o.threads = 2;  // whole replicates on two threads, delivered in order
  const auto parallel = Run(problem, p, o);
  REQUIRE(parallel.size() == 6);
  for (size_t r = 0; r < 6; ++r) {
    CHECK(parallel[r].replicate == static_cast<int>(r));
    CHECK(Same(parallel[r], serial[r]));
  }
  o.replicates = 1;
  o.threads = 1;
  o.seed += 1;
  CHECK_FALSE(Same(Run(problem, p, o)[0], one[0]));
  o.seed -= 1;
  o.residual_error = false;  // the same η, and DV = IPRED
  const auto plain = Run(problem, p, o)[0];
  for (size_t i = 0; i < plain.subjects.size(); ++i) {
    CHECK(plain.subjects[i].eta == one[0].subjects[i].eta);
    CHECK(plain.subjects[i].dv == plain.subjects[i].ipred);
    CHECK(plain.subjects[i].ipred == one[0].subjects[i].ipred);
  }
}

TEST_CASE("a subject that cannot be simulated is reported, and the others are simulated", "[population][simulation]") {
  // Subject 2 has a sample before its dose: ŷ = 0 there, whose logarithm the exponential error takes.
  std::string text = "ID,TIME,AMT,EVID,MDV,DV\n1,0,100,1,1,.\n1,2,0,0,0,3\n2,0,0,0,0,1\n2,1,100,1,1,.\n2,2,0,0,0,3\n";
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(text, "bad.csv"));
  pk::ObjectiveOptions eo;
  eo.error_model = pk::MakeResidualError("exponential");
  // An individual fit would refuse subject 2's sample (log of 0); the population problem binds it.
  const pk::PopulationProblem problem(pk::MakeModel("1cmt_iv"), data, {"CL", "V"}, eo);
  pk::PopulationSimulationOptions o;
  const pk::SimulatedReplicate r = Run(problem, Truth(0.1), o)[0];
  REQUIRE(r.subjects.size() == 2);
  CHECK(r.subjects[0].ok);
  CHECK_FALSE(r.subjects[1].ok);
  CHECK(r.subjects[1].message.find("not positive") != std::string::npos);
  CHECK(r.failed == 1);
  o.replicates = 0;
  CHECK_THROWS_AS(Run(problem, Truth(0.1), o), pk::InputError);
  pk::PopulationParameters bad = Truth(0.1);
  bad.omega(0, 1) = bad.omega(1, 0) = 0.5;  // |ρ| > 1
  o.replicates = 1;
  CHECK_THROWS_WITH(Run(problem, bad, o), Catch::Contains("positive semi-definite"));
}

TEST_CASE("Ω's factor: Cholesky, or pivoted LDLᵀ for a singular Ω", "[simulation]") {
  Eigen::MatrixXd block(3, 3);  // a rank-1 block beside a variance fixed at 0
  block << 0.04, 0, 0.06, 0, 0, 0, 0.06, 0, 0.09;
  for (const Eigen::MatrixXd& omega : {Eigen::MatrixXd(Eigen::Vector2d(0.09, 0.04).asDiagonal()),
                                       Eigen::MatrixXd(Eigen::Vector2d(0, 0.09).asDiagonal()), block}) {
    INFO(omega);
    const Eigen::MatrixXd f = pk::internal::OmegaFactor(omega);
    CHECK((f * f.transpose() - omega).cwiseAbs().maxCoeff() < 1e-16);
  }
  Eigen::Matrix2d asymmetric;
  asymmetric << 0.09, 0.01, 0.02, 0.04;
  CHECK_THROWS_WITH(pk::internal::OmegaFactor(asymmetric), Catch::Contains("not symmetric"));
}

TEST_CASE("a singular Ω (a variance fixed at 0) draws that η as 0", "[population][simulation]") {
  const pk::PopulationProblem problem = Problem(Design(50, {1, 4}), "proportional");
  pk::PopulationParameters p = Truth(0.1);
  p.omega << 0.09, 0, 0, 0;
  const pk::SimulatedReplicate r = Run(problem, p, {})[0];
  double spread = 0;
  for (const auto& s : r.subjects) {
    REQUIRE(s.ok);
    CHECK(s.eta(1) == 0);
    spread += s.eta(0) * s.eta(0);
  }
  CHECK(spread > 0);
}

TEST_CASE("Percentile is R's quantile(type = 7)", "[vpc]") {
  // R: quantile(c(1, 2, 3, 4), c(.05, .5, .95), type = 7) = 1.15, 2.5, 3.85; quantile(c(10, 1, 7), .25) = 4.
  std::vector<double> v = {4, 2, 1, 3};
  CHECK(pk::Percentile(&v, 5) == Approx(1.15).epsilon(1e-15));
  CHECK(pk::Percentile(&v, 50) == Approx(2.5).epsilon(1e-15));
  CHECK(pk::Percentile(&v, 95) == Approx(3.85).epsilon(1e-15));
  v = {10, 1, 7};
  CHECK(pk::Percentile(&v, 25) == Approx(4).epsilon(1e-15));
  v = {5};
  CHECK(pk::Percentile(&v, 90) == 5);
  v.clear();
  CHECK(std::isnan(pk::Percentile(&v, 50)));
}

namespace {

// tests/reference/vpc_input.csv: replicate 0 (observed) as a design, the others as simulations.
struct VpcInput {
  pk::SimulationDesign design;
  std::vector<std::vector<std::vector<double>>> replicates;  // [replicate][subject][sample]
};

VpcInput ReadVpcInput() {
  std::ifstream in(std::string(PK_SOURCE_DIR) + "/tests/reference/vpc_input.csv");
  REQUIRE(in.good());
  std::string line;
  std::getline(in, line);
  REQUIRE(line == "REP,SUBJECT,SAMPLE,TIME,DVID,PRED,DV");
  std::vector<std::vector<double>> rows;
  while (std::getline(in, line)) {
    std::vector<double> row;
    std::stringstream ss(line);
    for (std::string f; std::getline(ss, f, ',');) row.push_back(std::strtod(f.c_str(), nullptr));
    REQUIRE(row.size() == 7);
    rows.push_back(row);
  }
  VpcInput out;
  for (const auto& r : rows) {
    const auto rep = static_cast<size_t>(r[0]), subject = static_cast<size_t>(r[1]), sample = static_cast<size_t>(r[2]);
    if (rep == 0) {
      if (out.design.subjects.size() <= subject) out.design.subjects.resize(subject + 1);
      auto& s = out.design.subjects[subject];
      REQUIRE(s.time.size() == sample);
      s.id = static_cast<double>(subject + 1);
      s.subject = static_cast<int>(subject);
      s.time.push_back(r[3]);
      s.dvid.push_back(static_cast<int>(r[4]));
      s.censored.push_back(0);
      s.pred.conservativeResize(static_cast<Eigen::Index>(sample + 1));
      s.pred(static_cast<Eigen::Index>(sample)) = r[5];
      s.dv.conservativeResize(static_cast<Eigen::Index>(sample + 1));
      s.dv(static_cast<Eigen::Index>(sample)) = r[6];
      continue;
    }
    if (out.replicates.size() < rep) out.replicates.resize(rep);
    auto& subjects = out.replicates[rep - 1];
    if (subjects.size() <= subject) subjects.resize(subject + 1);
    REQUIRE(subjects[subject].size() == sample);
    subjects[subject].push_back(r[6]);
  }
  return out;
}

}  // namespace

TEST_CASE("VPC statistics equal R's, plain, prediction-corrected and variability-corrected", "[vpc]") {
  const VpcInput input = ReadVpcInput();
  REQUIRE(input.replicates.size() == 30);
  const auto reference = [] {
    std::ifstream in(std::string(PK_SOURCE_DIR) + "/tests/reference/vpc_reference.csv");
    std::string line;
    std::getline(in, line);
    std::vector<std::vector<double>> rows;
    while (std::getline(in, line)) {
      std::vector<double> row;
      std::stringstream ss(line);
      for (std::string f; std::getline(ss, f, ',');) row.push_back(std::strtod(f.c_str(), nullptr));
      rows.push_back(row);
    }
    return rows;
  }();
  REQUIRE(reference.size() == 90);  // 5 corrections × 2 DVID × 3 bins × 3 percentiles
  for (int corrected = 0; corrected < 5; ++corrected) {  // none, lb = 0, lb = 0.5, pvcVPC with lb = 0 and 0.5
    pk::VpcOptions o;
    o.bin_edges = {0, 3, 8, 30};
    o.percentiles = {10, 50, 90};
    o.interval = 80;
    o.prediction_corrected = corrected > 0;
    o.variability_corrected = corrected >= 3;
    o.lower_bound = corrected == 2 || corrected == 4 ? 0.5 : 0;
    pk::VpcAccumulator vpc(input.design, o);
    if (o.variability_corrected) {
      for (const auto& r : input.replicates) vpc.AddVariability(r);
      vpc.EndVariability();
    }
    for (const auto& r : input.replicates) vpc.Add(r);
    const pk::VpcSummary s = vpc.Finish();
    CHECK(s.replicates == 30);
    REQUIRE(s.bins.size() == 6);
    size_t row = 0;
    for (const auto& ref : reference) {
      if (static_cast<int>(ref[0]) != corrected) continue;
      const int dvid = static_cast<int>(ref[1]), bin = static_cast<int>(ref[2]) - 1, k = static_cast<int>(row++ % 3);
      const pk::VpcBin& b = s.bins[static_cast<size_t>((dvid - 1) * 3 + bin)];
      INFO("corrected " << corrected << ", DVID " << dvid << ", bin " << bin + 1 << ", percentile " << ref[4]);
      REQUIRE(b.dvid == dvid);
      CHECK(b.observations == static_cast<int>(ref[3]));
      CHECK(s.percentiles[static_cast<size_t>(k)] == ref[4]);
      CHECK(pk_test::RelDiff(b.time, ref[5]) < 1e-14);
      CHECK(pk_test::RelDiff(b.observed[static_cast<size_t>(k)], ref[6]) < 1e-13);
      CHECK(pk_test::RelDiff(b.simulated_lower[static_cast<size_t>(k)], ref[7]) < 1e-13);
      CHECK(pk_test::RelDiff(b.simulated_median[static_cast<size_t>(k)], ref[8]) < 1e-13);
      CHECK(pk_test::RelDiff(b.simulated_upper[static_cast<size_t>(k)], ref[9]) < 1e-13);
    }
    CHECK(row == 18);
  }
}

namespace {

// Σ count·(t − group mean)² over the groups that `starts` (each group's first index) make.
double SplitCost(const std::vector<double>& t, const std::vector<int>& count, const std::vector<size_t>& starts) {
  double cost = 0;
  for (size_t g = 0; g < starts.size(); ++g) {
    const size_t a = starts[g], b = g + 1 < starts.size() ? starts[g + 1] : t.size();
    double n = 0, m = 0;
    for (size_t i = a; i < b; ++i) n += count[i], m += count[i] * t[i];
    m /= n;
    for (size_t i = a; i < b; ++i) cost += count[i] * (t[i] - m) * (t[i] - m);
  }
  return cost;
}

}  // namespace

namespace {

// The least SplitCost of every split of t into k consecutive groups (each non-empty).
double BestSplit(const std::vector<double>& t, const std::vector<int>& count, size_t k, std::vector<size_t> starts = {0}) {
  if (starts.size() == k) return SplitCost(t, count, starts);
  double best = HUGE_VAL;
  for (size_t a = starts.back() + 1; a + (k - starts.size()) <= t.size(); ++a) {
    std::vector<size_t> more = starts;
    more.push_back(a);
    best = std::min(best, BestSplit(t, count, k, more));
  }
  return best;
}

// One subject of DVID 1 with count[i] samples at time t[i], its DV and PRED 1, 2, 3, … in order.
pk::SimulationDesign RepeatedTimes(const std::vector<double>& t, const std::vector<int>& count) {
  pk::SimulationDesign design;
  design.subjects.resize(1);
  auto& s = design.subjects[0];
  for (size_t i = 0; i < t.size(); ++i) {
    for (int c = 0; c < count[i]; ++c) {
      s.time.push_back(t[i]);
      s.dvid.push_back(1);
      s.censored.push_back(0);
    }
  }
  const auto n = static_cast<Eigen::Index>(s.time.size());
  s.dv = Eigen::VectorXd::LinSpaced(n, 1, static_cast<double>(n));
  s.pred = s.dv;
  return design;
}

}  // namespace

TEST_CASE("automatic VPC bins are Jenks' natural breaks: the least squared deviation of all splits", "[vpc]") {
  // Designs of u distinct times (some repeated) binned into k: the bins' within-bin squared
  // deviation is the least of every split into k consecutive groups (enumerated here); u = k + 1
  // and u = k + 2 are the smallest cases that reach the dynamic programme.
  const std::pair<size_t, int> cases[] = {{5, 4}, {6, 4}, {11, 4}, {11, 4}, {11, 4}, {12, 6}, {13, 3}, {9, 2}};
  unsigned state = 12345u;
  const auto next = [&] { return (state = state * 1103515245u + 12345u) >> 16; };
  for (const auto& [u, k] : cases) {
    std::vector<double> t;
    std::vector<int> count;
    double time = 0;
    for (size_t i = 0; i < u; ++i) {
      time += 0.1 + static_cast<double>(next() % 1000) / 100;
      t.push_back(time);
      count.push_back(1 + static_cast<int>(next() % 4));
    }
    const pk::SimulationDesign design = RepeatedTimes(t, count);
    pk::VpcOptions o;
    o.max_bins = k;
    o.min_bin_count = 1;  // the dynamic programme's bins as they are
    const pk::VpcSummary vpc = pk::VpcAccumulator(design, o).Finish();
    INFO("u " << u << ", k " << k);
    REQUIRE(vpc.bins.size() == static_cast<size_t>(k));
    std::vector<size_t> found;
    for (const pk::VpcBin& b : vpc.bins) {
      found.push_back(static_cast<size_t>(std::lower_bound(t.begin(), t.end(), b.lower) - t.begin()));
      CHECK(b.observations > 0);
    }
    CHECK(SplitCost(t, count, found) == Approx(BestSplit(t, count, static_cast<size_t>(k))).epsilon(1e-12));
    int total = 0;
    for (const pk::VpcBin& b : vpc.bins) total += b.observations;
    CHECK(total == std::accumulate(count.begin(), count.end(), 0));
  }
}

TEST_CASE("automatic VPC bins of fewer than min_bin_count values join the neighbour across the smaller gap", "[vpc]") {
  // Times 1 (×10), 2 (×1), 10 (×8), 30 (×2), each a bin at first: 2 joins 1 (a gap of 1 against 8),
  // then 30 joins 10, the only neighbour; with min_bin_count 1 the four stay.
  const pk::SimulationDesign design = RepeatedTimes({1, 2, 10, 30}, {10, 1, 8, 2});
  pk::VpcOptions o;
  const pk::VpcSummary merged = pk::VpcAccumulator(design, o).Finish();
  REQUIRE(merged.bins.size() == 2);
  CHECK(merged.bins[0].lower == 1);
  CHECK(merged.bins[0].upper == 6);
  CHECK(merged.bins[0].observations == 11);
  CHECK(merged.bins[1].upper == 30);
  CHECK(merged.bins[1].observations == 10);
  o.min_bin_count = 1;
  CHECK(pk::VpcAccumulator(design, o).Finish().bins.size() == 4);
  o.min_bin_count = 100;  // more than there are: one bin
  CHECK(pk::VpcAccumulator(design, o).Finish().bins.size() == 1);
  o.bin_edges = {0, 5};  // given edges: the 10 values at 10 and 30 lie outside, and are counted
  const pk::VpcSummary given = pk::VpcAccumulator(design, o).Finish();
  REQUIRE(given.bins.size() == 1);
  CHECK(given.bins[0].observations == 11);
  CHECK(given.outside_edges == 10);
  CHECK(given.BriefReport().find("10 observations outside the bin edges are left out") != std::string::npos);
}

TEST_CASE("censored observations and simulated values below the limit count as −∞ in a VPC", "[vpc]") {
  // One time, ten subjects: three censored at the limit 1 (CENS = 1), seven values 2…8.
  pk::SimulationDesign design;
  design.subjects.resize(10);
  for (int i = 0; i < 10; ++i) {
    auto& s = design.subjects[static_cast<size_t>(i)];
    s.id = i + 1;
    s.time = {4};
    s.dvid = {1};
    s.censored = {i < 3 ? 1 : 0};
    s.dv = Eigen::VectorXd::Constant(1, i < 3 ? 1.0 : i - 1.0);
    s.pred = Eigen::VectorXd::Constant(1, 5.0);
  }
  pk::VpcOptions o;
  o.percentiles = {10, 50, 90};
  pk::VpcAccumulator vpc(design, o);
  std::vector<std::vector<double>> same(10), low(10, std::vector<double>{0.5}), high(10, std::vector<double>{3});
  for (int i = 0; i < 10; ++i) same[static_cast<size_t>(i)] = {i < 3 ? 0.9 : i - 1.0};
  vpc.Add(same);  // the data again: the same percentiles
  vpc.Add(low);   // everything below the limit
  vpc.Add(high);  // nothing below it
  const pk::VpcSummary v = vpc.Finish();
  REQUIRE(v.bins.size() == 1);
  const pk::VpcBin& b = v.bins[0];
  CHECK(v.limits);
  CHECK(v.censored == 3);
  // Type 7 over −∞ ×3, 2…8: the 10th percentile interpolates from −∞ (below the limit), the
  // median is 3.5, the 90th 7.1.
  CHECK(std::isinf(b.observed[0]));
  CHECK(b.observed[0] < 0);
  CHECK(b.observed[1] == Approx(3.5).epsilon(1e-15));
  CHECK(b.observed[2] == Approx(7.1).epsilon(1e-15));
  CHECK(b.censored_observed == Approx(0.3));
  // The replicates' censored fractions 0.3, 1, 0: interval 5%…95% by type 7 = 0.03, 0.93; median 0.3.
  CHECK(b.censored_lower == Approx(0.03));
  CHECK(b.censored_median == Approx(0.3));
  CHECK(b.censored_upper == Approx(0.93));
  // The median's replicates: 3.5, −∞, 3 → its interval runs from below the limit to 3.45.
  CHECK(std::isinf(b.simulated_lower[1]));
  CHECK(b.simulated_median[1] == Approx(3));
  CHECK(b.simulated_upper[1] == Approx(3.45));
  const std::string csv = pk::VpcCsv(v);
  INFO(csv);
  CHECK(csv.find("BLQ_OBSERVED") != std::string::npos);
  CHECK(csv.find("1,1,4,4,4,10,10,,") != std::string::npos);  // −∞ is an empty field
  CHECK(csv.find("nan") == std::string::npos);
  CHECK(csv.find("inf") == std::string::npos);
  // A limit for every DVID: the uncensored 2 and 3 fall below 3.5 too.
  o.lloq = 3.5;
  pk::VpcAccumulator with_lloq(design, o);
  CHECK(with_lloq.Finish().censored == 5);
}

TEST_CASE("pcVPC leaves out the samples whose PRED is not above the lower bound", "[vpc]") {
  pk::SimulationDesign design;
  design.subjects.resize(4);
  for (int i = 0; i < 4; ++i) {
    auto& s = design.subjects[static_cast<size_t>(i)];
    s.id = i + 1;
    s.time = {0, 2};
    s.dvid = {1, 1};
    s.censored = {0, 0};
    s.dv = Eigen::Vector2d(0.1, 2 + i);
    s.pred = Eigen::Vector2d(i == 3 ? std::nan("") : 0.0, 4);  // pre-dose PRED 0; one not evaluable
  }
  pk::VpcOptions o;
  o.prediction_corrected = true;
  const pk::VpcSummary v = pk::VpcAccumulator(design, o).Finish();
  CHECK(v.uncorrectable == 4);
  CHECK(v.observations.size() == 4);
  CHECK(v.BriefReport().find("4 observations whose PRED is not above the lower bound") != std::string::npos);
  for (auto& s : design.subjects) s.pred(1) = -1;
  CHECK_THROWS_WITH(pk::VpcAccumulator(design, o), Catch::Contains("no observation has a PRED above the lower bound"));
  design.subjects[0].dv.resize(1);
  CHECK_THROWS_WITH(pk::VpcAccumulator(design, o), Catch::Contains("unequal sizes"));
}

TEST_CASE("a VPC of the model's own data keeps the percentiles in their intervals, one with Ω too small does not",
          "[vpc][population][simulation]") {
  // Data simulated from the truth (seed 1), then VPCs at the truth and at an Ω a tenth of it (seed 2).
  const std::vector<double> times = {0.5, 1, 2, 4, 8, 12, 24};
  const auto design_data = Design(150, times);
  const pk::PopulationParameters truth = Truth(0.1);
  pk::PopulationSimulationOptions so;
  so.seed = 1;
  const pk::SimulatedReplicate data_sim = Run(Problem(design_data, "proportional"), truth, so)[0];
  std::string text = "ID,TIME,AMT,EVID,MDV,DV\n";
  for (size_t i = 0; i < data_sim.subjects.size(); ++i) {
    const std::string id = std::to_string(i + 1);
    text += id + ",0,100,1,1,.\n";
    for (size_t j = 0; j < times.size(); ++j) {
      text += id + "," + pk::FormatNumber(times[j]) + ",0,0,0," +
              pk::FormatNumber(data_sim.subjects[i].dv(static_cast<Eigen::Index>(j))) + "\n";
    }
  }
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(text, "observed.csv"));
  const pk::PopulationProblem problem = Problem(data, "proportional");
  pk::VpcOptions o;
  o.replicates = 100;
  o.seed = 2;
  o.threads = 2;
  const pk::VpcSummary good = pk::ComputeVpc(problem, truth, o);
  REQUIRE(good.bins.size() == times.size());  // each distinct time a bin
  pk::VpcOptions serial = o;
  serial.threads = 1;  // replicates summarised on two workers, appended in order: the same table
  CHECK(pk::VpcCsv(pk::ComputeVpc(problem, truth, serial)) == pk::VpcCsv(good));
  INFO(good.BriefReport());
  CHECK(good.compared == 21);
  // 10% of 21 expected by chance (2.1), with cells correlated; more than 5 has a chance of about 2%
  // under a right model. (These seeds give 2.)
  CHECK(good.outside <= 5);
  pk::PopulationParameters narrow = truth;
  narrow.omega *= 0.1;
  const pk::VpcSummary bad = pk::ComputeVpc(problem, narrow, o);
  INFO(bad.BriefReport());
  int tails_outside = 0;
  for (const pk::VpcBin& b : bad.bins) {
    for (size_t k : {size_t{0}, size_t{2}}) {  // the 5th and 95th percentiles
      tails_outside += b.observed[k] < b.simulated_lower[k] || b.observed[k] > b.simulated_upper[k];
    }
  }
  CHECK(tails_outside >= 10);  // of 14 (these seeds: every one); by chance, about 1.4
  // pcVPC of the same data: the correction changes the values, and the truth still passes.
  o.prediction_corrected = true;
  const pk::VpcSummary pc = pk::ComputeVpc(problem, truth, o);
  CHECK(pc.outside <= 5);
  CHECK(pc.observations.size() == good.observations.size());
  // pvcVPC: the truth passes, Ω a tenth of it fails in the tails, and two threads give the same table.
  o.variability_corrected = true;
  const pk::VpcSummary pvc = pk::ComputeVpc(problem, truth, o);
  INFO(pvc.BriefReport());
  CHECK(pvc.outside <= 5);
  CHECK(pk::VpcCsv(pvc) != pk::VpcCsv(pc));
  // Each table names its correction in its last column, on every row.
  for (const auto& [table, correction] : {std::pair<const pk::VpcSummary*, std::string>{&good, "none"},
                                          {&pc, "pc"}, {&pvc, "pvc"}}) {
    const std::string csv = pk::VpcCsv(*table);
    INFO(csv.substr(0, 400));
    std::istringstream lines(csv);
    std::string line;
    std::getline(lines, line);
    CHECK(line.size() > 11);
    CHECK(line.substr(line.size() - 11) == ",CORRECTION");
    int rows = 0;
    while (std::getline(lines, line)) {
      ++rows;
      CHECK(line.substr(line.rfind(',') + 1) == correction);
    }
    CHECK(rows > 0);
  }
  CHECK(pk::VpcCsv(pk::ComputeVpc(problem, truth, [&] {
          pk::VpcOptions one = o;
          one.threads = 1;
          return one;
        }())) == pk::VpcCsv(pvc));
  const pk::VpcSummary pvc_bad = pk::ComputeVpc(problem, narrow, o);
  int pvc_tails_outside = 0;
  for (const pk::VpcBin& b : pvc_bad.bins) {
    for (size_t k : {size_t{0}, size_t{2}}) {
      pvc_tails_outside += b.observed[k] < b.simulated_lower[k] || b.observed[k] > b.simulated_upper[k];
    }
  }
  CHECK(pvc_tails_outside >= 10);
}

// pvcVPC by its definition (Bergstrand et al. 2011), computed here from the values: pcY = Y·PRED_b/PRED
// (lb = 0), sd_ij the standard deviation of sample ij's pcY over the replicates, sd_b their median in
// the bin, pvcY = PRED_b + (pcY − PRED_b)·sd_b/sd_ij, for the observations and for every replicate.
TEST_CASE("pvcVPC scales each deviation from the bin's PRED by the bin's median spread over the sample's own",
          "[vpc]") {
  const std::vector<double> pred = {2, 4, 5, 8, 10}, dv = {2.5, 3, 6, 7, 13};
  pk::SimulationDesign design;
  design.subjects.resize(pred.size());
  for (size_t i = 0; i < pred.size(); ++i) {
    auto& s = design.subjects[i];
    s.id = static_cast<double>(i + 1);
    s.time = {4};
    s.dvid = {1};
    s.censored = {0};
    s.dv = Eigen::VectorXd::Constant(1, dv[i]);
    s.pred = Eigen::VectorXd::Constant(1, pred[i]);
  }
  // Six replicates; additive deviations of unequal size, so that the samples' spreads differ.
  const std::vector<double> shift = {-1, 0.5, 2, -0.3, 1.1, -2.2}, size = {0.2, 1, 3, 0.5, 2};
  std::vector<std::vector<std::vector<double>>> replicates;
  for (size_t r = 0; r < shift.size(); ++r) {
    std::vector<std::vector<double>> values(pred.size());
    for (size_t i = 0; i < pred.size(); ++i) values[i] = {pred[i] + shift[(r + i) % shift.size()] * size[i]};
    replicates.push_back(values);
  }
  const double pred_b = 5;  // the median PRED
  std::vector<double> sd(pred.size());
  for (size_t i = 0; i < pred.size(); ++i) {
    double sum = 0, squares = 0;
    for (const auto& values : replicates) sum += values[i][0] * pred_b / pred[i];
    const double mean = sum / static_cast<double>(replicates.size());
    for (const auto& values : replicates) squares += std::pow(values[i][0] * pred_b / pred[i] - mean, 2);
    sd[i] = std::sqrt(squares / static_cast<double>(replicates.size() - 1));
  }
  std::vector<double> sorted = sd;
  std::sort(sorted.begin(), sorted.end());
  const double sd_b = sorted[2];  // the median of five
  const auto corrected = [&](const std::vector<double>& y) {
    std::vector<double> out;
    for (size_t i = 0; i < y.size(); ++i) out.push_back(pred_b + (y[i] * pred_b / pred[i] - pred_b) * sd_b / sd[i]);
    return out;
  };
  pk::VpcOptions o;
  o.prediction_corrected = o.variability_corrected = true;
  o.replicates = static_cast<int>(replicates.size());
  pk::VpcAccumulator vpc(design, o);
  CHECK_THROWS_AS(vpc.Add(replicates[0]), std::logic_error);  // the spreads come first
  for (const auto& values : replicates) vpc.AddVariability(values);
  vpc.EndVariability();
  CHECK_THROWS_AS(vpc.AddVariability(replicates[0]), std::logic_error);
  for (const auto& values : replicates) vpc.Add(values);
  const pk::VpcSummary v = vpc.Finish();
  CHECK(v.variability_corrected);
  CHECK(v.Kind() == "Prediction- and variability-corrected VPC");
  REQUIRE(v.bins.size() == 1);
  const pk::VpcBin& b = v.bins[0];
  std::vector<double> observed = corrected(dv);
  for (size_t i = 0; i < dv.size(); ++i) CHECK(v.observations[i].value == Approx(observed[i]).epsilon(1e-13));
  std::vector<std::vector<double>> by_percentile(o.percentiles.size());
  for (const auto& values : replicates) {
    std::vector<double> y;
    for (const auto& subject : values) y.push_back(subject[0]);
    std::vector<double> c = corrected(y);
    for (size_t k = 0; k < o.percentiles.size(); ++k) by_percentile[k].push_back(pk::Percentile(&c, o.percentiles[k]));
  }
  for (size_t k = 0; k < o.percentiles.size(); ++k) {
    CHECK(b.observed[k] == Approx(pk::Percentile(&observed, o.percentiles[k])).epsilon(1e-13));
    CHECK(b.simulated_lower[k] == Approx(pk::Percentile(&by_percentile[k], 5)).epsilon(1e-13));
    CHECK(b.simulated_median[k] == Approx(pk::Percentile(&by_percentile[k], 50)).epsilon(1e-13));
    CHECK(b.simulated_upper[k] == Approx(pk::Percentile(&by_percentile[k], 95)).epsilon(1e-13));
  }
  // The correction moved the values: the spreads differ (sd from about 0.26 to 3.7 here).
  CHECK(*std::max_element(sd.begin(), sd.end()) > 5 * *std::min_element(sd.begin(), sd.end()));
  pk::VpcOptions pc = o;
  pc.variability_corrected = false;
  pk::VpcAccumulator plain(design, pc);
  for (const auto& values : replicates) plain.Add(values);
  CHECK(plain.Finish().bins[0].observed[2] != Approx(b.observed[2]));

  // Proportional deviations, the same in every sample: equal spreads of pcY, and pvcVPC is pcVPC.
  pk::VpcAccumulator same_spread(design, o), pc_only(design, pc);
  std::vector<std::vector<std::vector<double>>> proportional;
  for (double d : shift) {
    std::vector<std::vector<double>> values(pred.size());
    for (size_t i = 0; i < pred.size(); ++i) values[i] = {pred[i] * (1 + 0.1 * d)};
    proportional.push_back(values);
  }
  for (const auto& values : proportional) same_spread.AddVariability(values);
  same_spread.EndVariability();
  for (const auto& values : proportional) {
    same_spread.Add(values);
    pc_only.Add(values);
  }
  const pk::VpcSummary a = same_spread.Finish(), c = pc_only.Finish();
  for (size_t k = 0; k < o.percentiles.size(); ++k) {
    CHECK(a.bins[0].observed[k] == Approx(c.bins[0].observed[k]).epsilon(1e-12));
    CHECK(a.bins[0].simulated_median[k] == Approx(c.bins[0].simulated_median[k]).epsilon(1e-12));
  }
  // Subject 5 simulated in 2 of the 6 replicates (fewer than half): its spread is not estimated, it
  // keeps its pcY and is counted, and the bin's sd_b is the median of the other four.
  auto with_gaps = replicates;
  for (size_t r = 0; r < 4; ++r) with_gaps[r][4].clear();
  pk::VpcAccumulator sparse(design, o);
  for (const auto& values : with_gaps) sparse.AddVariability(values);
  sparse.EndVariability();
  for (const auto& values : with_gaps) sparse.Add(values);
  const pk::VpcSummary g = sparse.Finish();
  CHECK(g.unscaled == 1);
  CHECK(g.BriefReport().find("1 observations whose spread over the replicates cannot be estimated") != std::string::npos);
  CHECK(g.observations[4].value == Approx(dv[4] * pred_b / pred[4]).epsilon(1e-14));
  std::vector<double> four(sd.begin(), sd.begin() + 4);
  std::sort(four.begin(), four.end());
  const double sd_b4 = (four[1] + four[2]) / 2;
  for (size_t i = 0; i < 4; ++i) {
    CHECK(g.observations[i].value == Approx(pred_b + (dv[i] * pred_b / pred[i] - pred_b) * sd_b4 / sd[i]).epsilon(1e-13));
  }
  CHECK(v.unscaled == 0);
  // Not a pvcVPC: no first pass.
  pk::VpcAccumulator not_pvc(design, pc);
  CHECK_THROWS_AS(not_pvc.EndVariability(), std::logic_error);
}

TEST_CASE("VPC options are checked", "[vpc]") {
  std::string why;
  pk::VpcOptions o;
  CHECK(o.IsValid(&why));
  const std::vector<std::function<void(pk::VpcOptions*)>> bad = {
      [](pk::VpcOptions* x) { x->replicates = 0; },
      [](pk::VpcOptions* x) { x->percentiles = {50, 5}; },
      [](pk::VpcOptions* x) { x->percentiles = {0, 50}; },
      [](pk::VpcOptions* x) { x->percentiles.clear(); },
      [](pk::VpcOptions* x) { x->interval = 100; },
      [](pk::VpcOptions* x) { x->bin_edges = {1}; },
      [](pk::VpcOptions* x) { x->bin_edges = {0, 2, 2}; },
      [](pk::VpcOptions* x) { x->max_bins = 0; },
      [](pk::VpcOptions* x) { x->variability_corrected = true; },  // without the prediction correction
      [](pk::VpcOptions* x) {
        x->prediction_corrected = x->variability_corrected = true;
        x->replicates = 1;  // no spread from one replicate
      },
      [](pk::VpcOptions* x) { x->threads = 0; }};
  for (const auto& change : bad) {
    pk::VpcOptions x;
    change(&x);
    CHECK_FALSE(x.IsValid(&why));
    CHECK_FALSE(why.empty());
  }
}

TEST_CASE("population estimates are read back from pkpop's table", "[simulation][reader]") {
  const auto model = pk::MakeModel("1cmt_oral");
  const pk::PopulationEstimates p = pk::ParsePopulationEstimates(
      "PARAMETER,ESTIMATE,SE,RSE_PCT,FIXED,AT_BOUNDARY\nKA,1.5,,,0,0\ncl,3,0.1,3.3,0,0\nV,30,,,0,0\n"
      "OMEGA(CL),0.09,,,0,0\nOMEGA(V),0.04,,,0,0\n\"OMEGA(V,CL)\",0.02,,,0,0\nSIGMA_PROP,0.1,,,0,0\nOFV,100,,,,\n",
      "est.csv", *model);
  CHECK(p.theta.at("CL") == 3);
  CHECK(p.theta.at("KA") == 1.5);
  REQUIRE(p.etas == std::vector<std::string>{"CL", "V"});
  CHECK(p.eta_log_normal == std::vector<bool>{true, true});
  CHECK(p.omega(0, 0) == 0.09);
  CHECK(p.omega(1, 1) == 0.04);
  CHECK(p.omega(0, 1) == 0.02);
  CHECK(p.omega(1, 0) == 0.02);
  // As pkpop writes a block: Ω's lower triangle by rows, a covariance before the second variance.
  const pk::PopulationEstimates rows = pk::ParsePopulationEstimates(
      "PARAMETER,ESTIMATE\nCL,3\nV,30\nOMEGA(CL),0.09\n\"OMEGA(V,CL)\",0.02\nOMEGA(V),0.04\nSIGMA_PROP,0.1\n", "rows.csv",
      *model);
  CHECK(rows.omega == p.omega);
  CHECK(p.sigma_names == std::vector<std::string>{"SIGMA_PROP"});
  CHECK(p.sigma(0) == 0.1);
  const auto refused = [&](const std::string& body, const std::string& message) {
    INFO(body);
    CHECK_THROWS_WITH(pk::ParsePopulationEstimates("PARAMETER,ESTIMATE\n" + body, "est.csv", *model),
                      Catch::Contains(message));
  };
  refused("Q,1\nOMEGA(CL),0.1\n", "est.csv:2:1: 'Q' is not a parameter of model 1cmt_oral");
  refused("CL,3\nOMEGA(CL),-0.1\n", "est.csv:3:1: OMEGA(CL): a variance is not negative");
  refused("CL,3\n\"OMEGA(V,CL)\",0.01\nOMEGA(CL),0.1\n", "est.csv:3:1: OMEGA(V,CL): V has no variance");
  refused("CL,3\nOMEGA(CL),0.1\nSIGMA_ADD,-1\n", "est.csv:4:1: SIGMA_ADD: σ is a standard deviation");
  refused("CL,3\nCL,4\nOMEGA(CL),0.1\n", "est.csv:3:1: CL is given twice");
  refused("CL,3\n", "no OMEGA");
  refused("CL,x\nOMEGA(CL),0.1\n", "est.csv:2:2: ESTIMATE: 'x' is not a number");
  CHECK(pk::PopulationErrorModel(*model, p)->name() == std::string("proportional"));
  pk::PopulationEstimates both = p;
  both.sigma_names = {"SIGMA_PROP", "SIGMA_ADD"};
  CHECK(pk::PopulationErrorModel(*model, both)->name() == std::string("combined"));
  both.sigma_names = {"SIGMA_X"};
  CHECK_THROWS_WITH(pk::PopulationErrorModel(*model, both), Catch::Contains("no error model has the σ SIGMA_X"));
}

TEST_CASE("a dataset simulated with variability draws SimulatePopulation's η and ε", "[simulation]") {
  // The same design through both: pksim --population on the fitted data gives pkpop --simulate's numbers.
  const std::vector<double> times = {0.5, 2, 6, 12};
  const auto data = Design(30, times);
  const pk::PopulationProblem problem = Problem(data, "combined");
  pk::PopulationParameters p = Truth(0);
  p.sigma = Eigen::Vector2d(0.05, 0.15);  // SIGMA_ADD, SIGMA_PROP
  pk::PopulationSimulationOptions po;
  po.seed = 99;
  po.replicates = 2;
  const auto expected = Run(problem, p, po);
  pk::PopulationEstimates e;
  e.source = "truth";
  e.theta = {{"CL", 3}, {"V", 30}};
  e.etas = {"CL", "V"};
  e.eta_log_normal = {true, true};
  e.omega = p.omega;
  e.sigma_names = {"SIGMA_PROP", "SIGMA_ADD"};  // in another order than the error model's
  e.sigma = Eigen::Vector2d(0.15, 0.05);
  pk::VariabilityOptions vo;
  vo.seed = 99;
  vo.replicates = 2;
  pk::SimulationOptions so;
  so.jobs = 2;
  std::vector<pk::SubjectSimulation> got;
  pk::SimulationSink sink;
  sink.consume = [&](pk::SubjectSimulation&& s, std::string&&) { got.push_back(std::move(s)); };
  pk::SimulateEachWithVariability(*pk::MakeModel("1cmt_iv"), *data, e, {}, so, vo, sink);
  REQUIRE(got.size() == 60);
  for (size_t k = 0; k < got.size(); ++k) {
    const pk::SubjectSimulation& s = got[k];
    const pk::SimulatedSubject& x = expected[k / 30].subjects[k % 30];
    INFO("replicate " << k / 30 << ", subject " << k % 30);
    REQUIRE(s.ok);
    CHECK(s.replicate == static_cast<int>(k / 30));
    CHECK(s.eta == x.eta);
    REQUIRE(s.observations.cols() == static_cast<Eigen::Index>(times.size()));
    for (Eigen::Index j = 0; j < s.observations.cols(); ++j) {
      CHECK(pk_test::RelDiff(s.rows[static_cast<size_t>(j)].cp, x.ipred(j)) < 1e-13);
      CHECK(pk_test::RelDiff(s.observations(0, j), x.dv(j)) < 1e-12);
    }
  }
}

TEST_CASE("a regimen simulated for N subjects: each its own η, φ = θ·exp(η), ε on every row", "[simulation]") {
  const auto regimen = std::make_shared<pk::Dataset>(
      pk::ParseDataset("ID,TIME,AMT,EVID,MDV\n1,0,100,1,1\n1,1,0,2,1\n1,6,0,2,1\n1,24,0,2,1\n", "regimen.csv"));
  pk::PopulationEstimates e;
  e.source = "est";
  e.theta = {{"CL", 3}, {"V", 30}};
  e.etas = {"CL"};
  e.eta_log_normal = {true};
  e.omega = Eigen::MatrixXd::Constant(1, 1, 0.2);
  e.sigma_names = {"SIGMA_LOG"};
  e.sigma = Eigen::VectorXd::Constant(1, 0.3);
  pk::VariabilityOptions vo;
  vo.subjects = 400;
  std::vector<pk::SubjectSimulation> got;
  pk::SimulationSink sink;
  sink.consume = [&](pk::SubjectSimulation&& s, std::string&&) { got.push_back(std::move(s)); };
  pk::SimulateEachWithVariability(*pk::MakeModel("1cmt_iv"), *regimen, e, {{"V", 25}}, {}, vo, sink);
  REQUIRE(got.size() == 400);
  double eta2 = 0, z2 = 0, n = 0;
  for (size_t i = 0; i < got.size(); ++i) {
    const pk::SubjectSimulation& s = got[i];
    REQUIRE(s.ok);
    CHECK(s.id == static_cast<double>(i + 1));
    eta2 += s.eta(0) * s.eta(0);
    const double cl = 3 * std::exp(s.eta(0)), v = 25;  // --param V=25 overrides θ
    for (size_t j = 0; j < s.rows.size(); ++j) {
      const double t = s.rows[j].time, cp = 100 / v * std::exp(-cl / v * t);
      CHECK(pk_test::RelDiff(s.rows[j].cp, cp) < 1e-12);
      const double z = std::log(s.observations(0, static_cast<Eigen::Index>(j)) / cp) / 0.3;
      z2 += z * z;
      ++n;
    }
  }
  CHECK(got[0].eta(0) != got[1].eta(0));
  CHECK(std::fabs(eta2 / 400 - 0.2) < 5 * 0.2 * std::sqrt(2.0 / 400));
  CHECK(std::fabs(z2 / n - 1) < 5 * std::sqrt(2 / n));
  vo.residual_error = false;
  got.clear();
  vo.subjects = 2;
  pk::SimulateEachWithVariability(*pk::MakeModel("1cmt_iv"), *regimen, e, {}, {}, vo, sink);
  REQUIRE(got.size() == 2);
  CHECK(got[0].observations.size() == 0);
  vo.subjects = 0;
  e.sigma_names.clear();
  e.sigma.resize(0);
  vo.residual_error = true;
  CHECK_THROWS_WITH(pk::SimulateEachWithVariability(*pk::MakeModel("1cmt_iv"), *regimen, e, {}, {}, vo, sink),
                    Catch::Contains("no σ"));
}

TEST_CASE("a VPC stratified by a data column bins each of its values apart", "[vpc][simulation]") {
  // Two dose groups of 1cmt_iv (DOSE 100 and 300, the dose in AMT too), sampled at their own times.
  std::string text = "ID,TIME,AMT,EVID,MDV,DV,DOSE\n";
  for (int id = 1; id <= 40; ++id) {
    const int dose = id <= 20 ? 100 : 300;
    const std::string tail = "," + std::to_string(dose) + "\n";
    text += std::to_string(id) + ",0," + std::to_string(dose) + ",1,1,." + tail;
    for (double t : id <= 20 ? std::vector<double>{1, 4, 12} : std::vector<double>{2, 8}) {
      text += std::to_string(id) + "," + pk::FormatNumber(t) + ",0,0,0,1" + tail;
    }
  }
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(text, "groups.csv"));
  const pk::PopulationProblem problem = Problem(data, "proportional");
  pk::VpcOptions o;
  o.replicates = 20;
  o.stratify = "dose";
  const pk::VpcSummary v = pk::ComputeVpc(problem, Truth(0.1), o);
  CHECK(v.stratify == "DOSE");
  REQUIRE(v.bins.size() == 5);  // 3 times at DOSE 100, 2 at 300
  for (size_t b = 0; b < v.bins.size(); ++b) {
    CHECK(v.bins[b].stratum == (b < 3 ? 100 : 300));
    CHECK(v.bins[b].observations == 20);
    CHECK(v.bins[b].time == (b < 3 ? std::vector<double>{1, 4, 12}[b] : std::vector<double>{2, 8}[b - 3]));
  }
  for (const pk::VpcObservation& obs : v.observations) {
    CHECK(v.bins[static_cast<size_t>(obs.bin)].stratum == (obs.id <= 20 ? 100 : 300));
  }
  const std::string csv = pk::VpcCsv(v);
  CHECK(csv.rfind("DOSE,DVID,BIN,TIME,", 0) == 0);
  CHECK(csv.find("\n300,1,2,8,") != std::string::npos);
  o.stratify = "WT";
  CHECK_THROWS_WITH(pk::ComputeVpc(problem, Truth(0.1), o), Catch::Contains("has no such column (its covariate columns: DOSE)"));
}
