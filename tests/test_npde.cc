// Normalised prediction distribution errors: the NPDE and PD of six subjects' given simulations against
// an independent R computation (tests/reference/make_npde_reference.R), their tests against R's
// (make_npde_tests_reference.R), and the NPDE of data simulated from the model against N(0, 1),
// independent within subjects, where a wrong Ω fails.
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>

#include "pk/catalogue.h"
#include "pk/error.h"
#include "pk/npde.h"
#include "pk/output.h"
#include "pk/population.h"
#include "pk/population_simulation.h"
#include "pk/residual_error.h"
#include "test_util.h"

namespace {

std::vector<std::vector<std::string>> ReadCsv(const std::string& name) {
  std::ifstream in(std::string(PK_SOURCE_DIR) + "/tests/reference/" + name);
  REQUIRE(in.good());
  std::vector<std::vector<std::string>> rows;
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    std::vector<std::string> fields;
    std::stringstream ss(line);
    for (std::string f; std::getline(ss, f, ',');) fields.push_back(f);
    if (!line.empty() && line.back() == ',') fields.push_back("");
    rows.push_back(fields);
  }
  return rows;
}

double Number(const std::string& text) {
  double v = 0;
  REQUIRE(pk::ParseNumber(text, &v));
  return v;
}

// `subjects` subjects of 1cmt_iv: 100 at time 0 and samples at `times` with the given DV (one a subject
// and time, subject-major), or 1.
std::shared_ptr<pk::Dataset> Data(int subjects, const std::vector<double>& times, const std::vector<double>& dv = {}) {
  std::string text = "ID,TIME,AMT,EVID,MDV,DV\n";
  for (int id = 1; id <= subjects; ++id) {
    text += std::to_string(id) + ",0,100,1,1,.\n";
    for (size_t j = 0; j < times.size(); ++j) {
      const size_t k = static_cast<size_t>(id - 1) * times.size() + j;
      text += std::to_string(id) + "," + pk::FormatNumber(times[j]) + ",0,0,0," +
              (dv.empty() ? std::string("1") : pk::FormatNumber(dv[k])) + "\n";
    }
  }
  return std::make_shared<pk::Dataset>(pk::ParseDataset(text, "npde.csv"));
}

pk::PopulationProblem Problem(const std::shared_ptr<pk::Dataset>& data) {
  pk::ObjectiveOptions o;
  o.error_model = pk::MakeResidualError("proportional");
  return pk::PopulationProblem(pk::MakeModel("1cmt_iv"), data, {"CL", "V"}, o);
}

pk::PopulationParameters Truth() {
  pk::PopulationParameters p;
  p.theta.resize(2);
  p.theta << 3, 30;  // CL, V
  p.omega.resize(2, 2);
  p.omega << 0.09, 0.03, 0.03, 0.04;
  p.sigma = Eigen::VectorXd::Constant(1, 0.1);
  return p;
}

// The correlation of the NPDE (or NPD) of consecutive samples of a subject.
double LagOneCorrelation(const pk::NpdeSummary& s, bool decorrelated) {
  std::vector<double> a, b;
  for (size_t r = 1; r < s.rows.size(); ++r) {
    if (s.rows[r].subject != s.rows[r - 1].subject) continue;
    a.push_back(decorrelated ? s.rows[r - 1].npde : s.rows[r - 1].npd);
    b.push_back(decorrelated ? s.rows[r].npde : s.rows[r].npd);
  }
  const Eigen::Map<const Eigen::ArrayXd> x(a.data(), static_cast<Eigen::Index>(a.size())),
      y(b.data(), static_cast<Eigen::Index>(b.size()));
  const Eigen::ArrayXd dx = x - x.mean(), dy = y - y.mean();
  return (dx * dy).sum() / std::sqrt(dx.square().sum() * dy.square().sum());
}

}  // namespace

TEST_CASE("NPDE and PD of given simulations equal an independent R computation", "[npde]") {
  // Subjects 0-4: n = 1, 2, 3, 5, 8 samples, K = 60; subject 5's simulations repeat a sample, so its
  // covariance has no Cholesky factor (no NPDE, PD given).
  std::map<int, std::map<int, std::map<int, double>>> input;  // subject → sample → simulation (0 observed)
  for (const auto& f : ReadCsv("npde_input.csv")) input[std::stoi(f[0])][std::stoi(f[1])][std::stoi(f[2])] = Number(f[3]);
  std::map<int, pk::SubjectNpde> computed;
  for (const auto& [subject, samples] : input) {
    const auto n = static_cast<Eigen::Index>(samples.size());
    const auto k = static_cast<Eigen::Index>(samples.begin()->second.size() - 1);
    Eigen::VectorXd observed(n);
    Eigen::MatrixXd simulated(n, k);
    for (const auto& [j, values] : samples) {
      for (const auto& [sim, v] : values) (sim == 0 ? observed(j) : simulated(j, sim - 1)) = v;
    }
    computed[subject] = pk::ComputeSubjectNpde(observed, simulated);
  }
  REQUIRE(computed.size() == 6);
  CHECK(computed[5].pde.size() == 0);
  CHECK(!computed[5].message.empty());
  std::vector<double> npde;
  int rows = 0;
  for (const auto& f : ReadCsv("npde_reference.csv")) {
    const int subject = std::stoi(f[0]);
    const auto j = static_cast<Eigen::Index>(std::stoi(f[1]));
    const pk::SubjectNpde& c = computed[subject];
    INFO("subject " << subject << " sample " << j);
    CHECK(c.epred(j) == Approx(Number(f[2])).epsilon(1e-14));
    CHECK(c.pd(j) == Number(f[3]));  // a count over K: exact
    CHECK(pk::NormalQuantile(c.pd(j)) == Approx(Number(f[4])).epsilon(1e-14));
    if (f[5].empty()) {
      CHECK(c.pde.size() == 0);
    } else {
      REQUIRE(c.pde.size() > j);
      CHECK(c.pde(j) == Number(f[5]));
      CHECK(pk::NormalQuantile(c.pde(j)) == Approx(Number(f[6])).epsilon(1e-14));
      npde.push_back(pk::NormalQuantile(c.pde(j)));
    }
    ++rows;
  }
  CHECK(rows == 22);
  // The npde package's moments of those NPDE (a NaN among them is skipped).
  npde.push_back(std::nan(""));
  const pk::NpdeMoments m = pk::ComputeNpdeMoments(npde);
  std::map<std::string, double> reference;
  for (const auto& f : ReadCsv("npde_moments_reference.csv")) reference[f[0]] = Number(f[1]);
  CHECK(m.count == reference["count"]);
  CHECK(m.mean == Approx(reference["mean"]).epsilon(1e-13));
  CHECK(m.variance == Approx(reference["variance"]).epsilon(1e-13));
  CHECK(m.skewness == Approx(reference["skewness"]).epsilon(1e-12));
  CHECK(m.kurtosis == Approx(reference["kurtosis"]).epsilon(1e-12));
  CHECK(m.mean_se == Approx(reference["mean_se"]).epsilon(1e-13));
  CHECK(m.variance_se == Approx(reference["variance_se"]).epsilon(1e-13));
}

TEST_CASE("NPDE of data simulated from the model are N(0, 1) and independent within subjects, with Ω too small not",
          "[npde][population][simulation]") {
  // Data: replicate 0 of the truth with seed 1; the NPDE's simulations with seed 2.
  const std::vector<double> times = {0.5, 1, 2, 4, 8, 12, 24};
  const int subjects = 100;
  pk::PopulationSimulationOptions so;
  so.seed = 1;
  const pk::SimulatedReplicate sim = pk::SimulateReplicate(Problem(Data(subjects, times)), Truth(), so, 0);
  std::vector<double> dv;
  for (const pk::SimulatedSubject& s : sim.subjects) dv.insert(dv.end(), s.dv.data(), s.dv.data() + s.dv.size());
  const pk::PopulationProblem problem = Problem(Data(subjects, times, dv));
  pk::NpdeOptions o;
  o.simulations = 300;
  o.seed = 2;
  o.threads = 2;
  const pk::NpdeSummary good = pk::ComputeNpde(problem, Truth(), o);
  INFO(good.FullReport());
  REQUIRE(good.rows.size() == 700);
  REQUIRE(good.npde.count == 700);
  REQUIRE(good.notes.empty());
  CHECK(std::abs(good.npde.mean) < 3 * good.npde.mean_se);
  CHECK(std::abs(good.npde.variance - 1) < 3 * good.npde.variance_se);
  CHECK(std::abs(good.npde.skewness) < 3 * std::sqrt(6.0 / 700));
  CHECK(std::abs(good.npde.kurtosis) < 3 * std::sqrt(24.0 / 700));
  // Decorrelated within a subject; the PD are not (each subject's η moves all its samples).
  CHECK(std::abs(LagOneCorrelation(good, true)) < 3 / std::sqrt(600.0));
  CHECK(LagOneCorrelation(good, false) > 0.3);
  // The same on one thread; simulation k of a subject is replicate k's.
  pk::NpdeOptions serial = o;
  serial.threads = 1;
  CHECK(pk::NpdeCsv(pk::ComputeNpde(problem, Truth(), serial)) == pk::NpdeCsv(good));
  pk::NpdeOptions two = o;
  two.simulations = 2;
  const pk::NpdeSummary pair = pk::ComputeNpde(problem, Truth(), two);
  pk::PopulationSimulationOptions replicate;
  replicate.seed = 2;
  const pk::SimulatedReplicate r0 = pk::SimulateReplicate(problem, Truth(), replicate, 0),
                               r1 = pk::SimulateReplicate(problem, Truth(), replicate, 1);
  CHECK(pair.rows[10].epred == Approx((r0.subjects[1].dv(3) + r1.subjects[1].dv(3)) / 2).epsilon(1e-15));
  // Ω a tenth of the truth: the data spread more than the simulations.
  pk::PopulationParameters narrow = Truth();
  narrow.omega *= 0.1;
  const pk::NpdeSummary bad = pk::ComputeNpde(problem, narrow, o);
  INFO(bad.BriefReport());
  CHECK(bad.npde.variance > 1.5);
}

TEST_CASE("NPDE leave out censored samples and report subjects without them", "[npde][population]") {
  std::string text = "ID,TIME,AMT,EVID,MDV,DV,CENS\n";
  for (int id = 1; id <= 3; ++id) {
    const std::string i = std::to_string(id);
    text += i + ",0,100,1,1,.,0\n" + i + ",1,0,0,0,2.9,0\n" + i + ",4,0,0,0,2.5,0\n" + i + ",24,0,0,0,0.4," +
            (id == 2 ? "1" : "0") + "\n";
  }
  const pk::PopulationProblem problem = Problem(std::make_shared<pk::Dataset>(pk::ParseDataset(text, "cens.csv")));
  pk::NpdeOptions o;
  o.simulations = 200;
  const pk::NpdeSummary s = pk::ComputeNpde(problem, Truth(), o);
  REQUIRE(s.rows.size() == 9);
  CHECK(s.censored == 1);
  CHECK(s.rows[5].censored);
  CHECK(std::isnan(s.rows[5].npde));
  CHECK(std::isnan(s.rows[5].pd));
  CHECK(std::isfinite(s.rows[3].npde));
  CHECK(std::isfinite(s.rows[4].npde));
  CHECK(s.npde.count == 8);
  // Three samples and two simulations: V_i has no Cholesky factor, so no NPDE; the PD stay.
  o.simulations = 2;
  const pk::NpdeSummary few = pk::ComputeNpde(problem, Truth(), o);
  CHECK(few.npde.count == 0);
  CHECK(few.npd.count == 8);
  CHECK(few.notes.size() == 3);  // subject 2's two uncensored samples have no factor from 2 simulations either
  CHECK(std::isnan(few.npde.mean));  // no values: every moment undefined, none 0
  CHECK(std::isnan(few.npde.variance));
  CHECK(few.BriefReport().find("mean –") != std::string::npos);
  o.simulations = 1;
  CHECK_THROWS_AS(pk::ComputeNpde(problem, Truth(), o), pk::InputError);
}

TEST_CASE("a subject whose simulations cannot be evaluated is left out of the NPDE, and reported", "[npde][population]") {
  // An exponential error takes log ŷ: subject 2's sample before its dose (ŷ = 0) cannot be simulated.
  std::string text = "ID,TIME,AMT,EVID,MDV,DV\n";
  for (int id = 1; id <= 3; ++id) {
    const std::string i = std::to_string(id);
    if (id == 2) text += i + ",0,0,0,0,0.5\n" + i + ",0.5,100,1,1,.\n";
    if (id != 2) text += i + ",0,100,1,1,.\n";
    text += i + ",1,0,0,0,2.9\n" + i + ",4,0,0,0,2.5\n";
  }
  pk::ObjectiveOptions oo;
  oo.error_model = pk::MakeResidualError("exponential");
  const pk::PopulationProblem problem(pk::MakeModel("1cmt_iv"), std::make_shared<pk::Dataset>(pk::ParseDataset(text, "x.csv")),
                                      {"CL", "V"}, oo);
  pk::NpdeOptions o;
  o.simulations = 50;
  const pk::NpdeSummary s = pk::ComputeNpde(problem, Truth(), o);
  REQUIRE(s.rows.size() == 7);
  REQUIRE(s.notes.size() == 1);
  CHECK(s.notes[0].find("ID 2 is left out") != std::string::npos);
  CHECK(s.npde.count == 4);
  CHECK(std::isnan(s.rows[2].npde));
  CHECK(std::isnan(s.rows[2].pd));
  CHECK(std::isfinite(s.rows[5].npde));
  // Given values that are not finite are an error, not a PD of 1/(2K).
  Eigen::MatrixXd sims = Eigen::MatrixXd::Ones(1, 5);
  sims(0, 1) = 2;
  CHECK_THROWS_AS(pk::ComputeSubjectNpde(Eigen::VectorXd::Constant(1, std::nan("")), sims), std::invalid_argument);
}

TEST_CASE("the NPDE's tests equal R's t.test, wilcox.test, shapiro.test and the npde package's variance and global tests",
          "[npde]") {
  std::map<int, std::vector<double>> sets;
  for (const auto& f : ReadCsv("npde_tests_input.csv")) sets[std::stoi(f[0])].push_back(Number(f[1]));
  const auto optional = [](const std::string& text) { return text.empty() ? std::nan("") : Number(text); };
  int checked = 0;
  for (const auto& f : ReadCsv("npde_tests_reference.csv")) {
    const std::vector<double>& x = sets[std::stoi(f[0])];
    INFO("set " << f[0] << ", n = " << x.size());
    REQUIRE(x.size() == static_cast<size_t>(std::stoi(f[1])));
    const pk::NpdeTests t = pk::TestNpde(x);
    CHECK(t.mean_wilcoxon_p == Approx(Number(f[2])).epsilon(1e-12));
    CHECK(t.mean_p == Approx(Number(f[6])).epsilon(1e-12));
    CHECK(t.global_p == Approx(Number(f[7])).epsilon(1e-10).margin(1e-13));  // set 15: R's variance p is 0
    CHECK(t.variance_p == Approx(Number(f[3])).epsilon(1e-12).margin(1e-14));  // R's 1 − pchisq is 0 below 1e-16
    const double w = optional(f[4]), p = optional(f[5]);
    if (std::isnan(w)) {
      CHECK(std::isnan(t.normality_w));
      CHECK(std::isnan(t.normality_p));
    } else {
      CHECK(t.normality_w == Approx(w).epsilon(1e-13));
      CHECK(t.normality_p == Approx(p).epsilon(1e-10).margin(1e-300));
    }
    ++checked;
  }
  CHECK(checked == 17);
}
