// Fits of the bundled real datasets against an independent implementation:
// R's nls (SSfol, SSbiexp), whose results tests/reference/make_reference.R
// wrote to tests/reference/nls_reference.csv. libpk must reach no higher
// objective on any subject, and the same estimates where the minimum is shared.
#include <fstream>
#include <map>
#include <sstream>

#include <catch2/catch.hpp>

#include "pk/catalogue.h"
#include "pk/fit_subjects.h"

namespace {

struct Reference {
  std::string dataset, model;
  double id, objective;
  std::map<std::string, double> estimates;
};

std::vector<Reference> ReadReference() {
  std::ifstream in(std::string(PK_SOURCE_DIR) + "/tests/reference/nls_reference.csv");
  REQUIRE(in);
  std::string line;
  std::getline(in, line);
  std::vector<Reference> out;
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) {
      if (cell.size() >= 2 && cell.front() == '"') cell = cell.substr(1, cell.size() - 2);
      f.push_back(cell);
    }
    Reference r{f[0], f[1], std::stod(f[2]), std::stod(f[3]), {}};
    for (int k = 0; k < 4; ++k) {
      if (!f[4 + 2 * k].empty()) r.estimates[f[4 + 2 * k]] = std::stod(f[5 + 2 * k]);
    }
    out.push_back(r);
  }
  return out;
}

}  // namespace

TEST_CASE("theophylline and indomethacin: no higher objective than R's nls, same estimates", "[reference]") {
  const std::vector<Reference> refs = ReadReference();
  REQUIRE(refs.size() == 18);
  // Once from starting values computed from the data (one start), once from the
  // catalogue defaults with four starts.
  const bool from_data = GENERATE(true, false);
  for (const std::string dataset : {"theophylline", "indomethacin"}) {
    pk::FitSubjectsRequest req;
    req.model = pk::MakeModel(dataset == "theophylline" ? "1cmt_oral" : "2cmt_iv");
    req.data = std::make_shared<pk::Dataset>(pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets/" + dataset + ".csv"));
    for (const std::string& p : req.model->parameter_names()) {
      pk::ParameterSpec s;
      s.name = p;
      s.initial = NAN;
      req.parameters.push_back(s);
    }
    req.initial_from_data = from_data;
    req.fit.starts = from_data ? 1 : 4;
    req.jobs = 2;
    const std::vector<pk::SubjectFit> fits = pk::FitSubjects(req);
    for (const Reference& ref : refs) {
      if (ref.dataset != dataset) continue;
      const pk::SubjectFit* fit = nullptr;
      for (const pk::SubjectFit& f : fits) {
        if (f.id == ref.id) fit = &f;
      }
      REQUIRE(fit != nullptr);
      INFO(dataset << " ID " << ref.id << " starting from " << fit->initial_method << "\n" << fit->summary.FullReport());
      if (from_data) CHECK(fit->initial_method.rfind("data", 0) == 0);
      REQUIRE(fit->ok);
      CHECK(fit->summary.converged());
      CHECK(fit->summary.objective <= ref.objective * (1 + 1e-9));
      CHECK(fit->summary.objective == Approx(ref.objective).epsilon(1e-7));
      for (const pk::ParameterEstimate& e : fit->summary.estimates) {
        CHECK(e.estimate == Approx(ref.estimates.at(e.name)).epsilon(1e-4));
      }
    }
  }
}

// Censored samples (Beal's M3) against R alone: tests/reference/make_m3_reference.R
// fitted datasets/theophylline_blq.csv (theophylline with a limit of 2 mg/L
// imposed; 27 of 132 samples censored) with the closed-form one-compartment
// oral model and an additive (dnorm, pnorm) or exponential (dlnorm, plnorm)
// error, by nlminb from 40 starts. Both optimisers that take a likelihood must
// reach its objective. The exponential error meets pre-dose samples censored
// below the limit at a prediction of 0 (log 0: certainly below).
TEST_CASE("theophylline below a limit of 2 mg/L (M3): R's optimum and estimates", "[reference][censoring]") {
  std::ifstream in(std::string(PK_SOURCE_DIR) + "/tests/reference/m3_reference.csv");
  REQUIRE(in);
  std::string line;
  std::getline(in, line);
  REQUIRE(line == "\"ID\",\"ERROR\",\"NCENS\",\"OBJECTIVE\",\"KA\",\"CL\",\"V\",\"SIGMA\"");
  struct Row {
    double id;
    std::string error;
    int censored;
    double objective;
    std::map<std::string, double> estimates;
  };
  std::vector<Row> refs;
  while (std::getline(in, line)) {
    std::stringstream ss(line);
    std::vector<std::string> f;
    for (std::string cell; std::getline(ss, cell, ',');) f.push_back(cell);
    REQUIRE(f.size() == 8);
    const std::string error = f[1].substr(1, f[1].size() - 2);
    refs.push_back({std::stod(f[0]), error, std::stoi(f[2]), std::stod(f[3]),
                    {{"KA", std::stod(f[4])}, {"CL", std::stod(f[5])}, {"V", std::stod(f[6])},
                     {error == "additive" ? "SIGMA_ADD" : "SIGMA_LOG", std::stod(f[7])}}});
  }
  REQUIRE(refs.size() == 24);
  const std::shared_ptr<const pk::ResidualErrorModel> error = GENERATE(pk::MakeResidualError("additive"), pk::MakeResidualError("exponential"));
  const std::string optimizer = GENERATE(as<std::string>{}, "newton", "bfgs");
  pk::FitSubjectsRequest req;
  req.model = pk::MakeModel("1cmt_oral");
  req.data = std::make_shared<pk::Dataset>(pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets/theophylline_blq.csv"));
  req.objective.error_model = error;
  req.fit.optimizer = optimizer;
  for (const char* p : {"KA", "CL", "V"}) req.parameters.push_back({p, NAN});
  req.parameters.push_back({std::string(error->name()) == "additive" ? "SIGMA_ADD" : "SIGMA_LOG", NAN});
  req.jobs = 2;
  const std::vector<pk::SubjectFit> fits = pk::FitSubjects(req);
  REQUIRE(fits.size() == 12);
  int compared = 0;
  for (const Row& ref : refs) {
    if (ref.error != error->name()) continue;
    const pk::SubjectFit& fit = fits[static_cast<size_t>(compared++)];
    INFO("ID " << ref.id << ", " << ref.error << " error, " << optimizer << "\n" << fit.summary.FullReport());
    REQUIRE(fit.id == ref.id);
    REQUIRE(fit.ok);
    CHECK(fit.censoring.cwiseAbs().sum() == ref.censored);
    CHECK(fit.summary.converged());
    CHECK(fit.summary.objective <= ref.objective + 1e-9 * std::max(1.0, std::fabs(ref.objective)));
    CHECK(fit.summary.objective == Approx(ref.objective).margin(1e-7 * std::max(1.0, std::fabs(ref.objective))));
    for (const pk::ParameterEstimate& e : fit.summary.estimates) {
      CHECK(e.estimate == Approx(ref.estimates.at(e.name)).epsilon(1e-4));
      CHECK(std::isfinite(e.rse_pct));
    }
  }
  CHECK(compared == 12);
}
