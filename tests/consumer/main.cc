// A downstream program: simulate a one-compartment bolus and check it, then fit
// noise-free data (which links the optimisers' libraries too).
#include <cmath>
#include <cstdio>
#include <memory>
#include <sstream>

#include <pk/catalogue.h>
#include <pk/dataset.h>
#include <pk/fit.h>
#include <pk/objective.h>
#include <pk/regimen.h>
#include <pk/simulate.h>

int main() {
  pk::Regimen regimen;
  pk::Dose dose;
  dose.amount = 100;
  regimen.doses.push_back(dose);
  regimen.times = {2.0};
  const auto sim = pk::SimulateSubject(*pk::MakeModel("1cmt_iv"), pk::RegimenToDataset(regimen), 0,
                                       {{"CL", 3}, {"V", 30}});
  const double expected = 100.0 / 30 * std::exp(-0.2);
  std::printf("CP(2) = %.12g (expected %.12g)\n", sim.rows.at(0).cp, expected);
  if (!(std::fabs(sim.rows.at(0).cp - expected) < 1e-12)) return 1;

  std::ostringstream csv;
  csv.precision(17);
  csv << "ID,TIME,AMT,EVID,CMT,DV\n1,0,100,1,1,.\n";
  for (double t : {0.5, 1.0, 2.0, 4.0, 8.0, 12.0}) csv << "1," << t << ",0,0,1," << 100.0 / 30 * std::exp(-0.1 * t) << "\n";
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(csv.str(), "consumer"));
  const pk::Objective objective(pk::MakeModel("1cmt_iv"), data, 0, pk::ObjectiveOptions());
  const pk::FitSummary fit = pk::Fit(objective, {{"CL", 1.0}, {"V", 10.0}}, pk::FitOptions());
  std::printf("%s\n", fit.BriefReport().c_str());
  return std::fabs(fit.values(0) - 3) < 1e-6 && std::fabs(fit.values(1) - 30) < 1e-5 ? 0 : 1;
}
