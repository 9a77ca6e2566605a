// A downstream program: simulate a one-compartment bolus and check it.
#include <cmath>
#include <cstdio>

#include <pk/catalogue.h>
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
  return std::fabs(sim.rows.at(0).cp - expected) < 1e-12 ? 0 : 1;
}
