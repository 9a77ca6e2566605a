#include "pk/exposure.h"

#include <algorithm>
#include <limits>

namespace pk {

Exposure ComputeExposure(const SubjectSimulation& sim) {
  Exposure e;
  e.id = sim.id;
  if (sim.rows.empty()) return e;
  e.auc = sim.rows.back().auc;
  const double first_dose = sim.doses.empty() ? sim.rows.front().time : sim.doses.front().time;
  e.cmax = -std::numeric_limits<double>::infinity();
  e.cmin = std::numeric_limits<double>::infinity();
  for (const SimulatedRecord& r : sim.rows) {
    if (r.time < first_dose) continue;
    if (r.cp > e.cmax) {
      e.cmax = r.cp;
      e.tmax = r.time;
    }
    e.cmin = std::min(e.cmin, r.cp);
  }
  if (e.cmin == std::numeric_limits<double>::infinity()) e.cmax = e.cmin = e.tmax = 0;

  // Dosing intervals: from each dose entry to the next one at a later time.
  std::vector<size_t> starts;
  for (size_t i = 0; i < sim.doses.size(); ++i) {
    if (starts.empty() || sim.doses[i].time > sim.doses[starts.back()].time) starts.push_back(i);
  }
  const double last_time = sim.rows.back().time;
  for (size_t k = 0; k < starts.size(); ++k) {
    const DoseEntry& d = sim.doses[starts[k]];
    const bool has_next = k + 1 < starts.size();
    IntervalExposure iv;
    iv.index = static_cast<int>(k) + 1;
    iv.start = d.time;
    iv.end = has_next ? sim.doses[starts[k + 1]].time : last_time;
    if (iv.end <= iv.start) continue;
    iv.cmax = -std::numeric_limits<double>::infinity();
    iv.cmin = std::numeric_limits<double>::infinity();
    auto visit = [&](double t, double c) {
      if (c > iv.cmax) {
        iv.cmax = c;
        iv.tmax = t;
      }
      iv.cmin = std::min(iv.cmin, c);
    };
    double end_auc = 0;
    double end_c = 0;
    // Rows strictly inside the interval, and the last row at its end (the
    // pre-dose state of the next dose is DoseEntry::cp_before).
    for (const SimulatedRecord& r : sim.rows) {
      if (r.time > iv.start && r.time < iv.end) visit(r.time, r.cp);
      if (!has_next && r.time == iv.end) {
        end_auc = r.auc;
        end_c = r.cp;
      }
      if (r.time == iv.start) visit(r.time, r.cp);
    }
    if (has_next) {
      end_auc = sim.doses[starts[k + 1]].auc_before;
      end_c = sim.doses[starts[k + 1]].cp_before;
    }
    visit(iv.end, end_c);
    iv.ctrough = end_c;
    iv.auc = end_auc - d.auc_before;
    e.intervals.push_back(iv);
  }
  return e;
}

}  // namespace pk
