#include "pk/regimen.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "pk/error.h"
#include "pk/output.h"

namespace pk {

Dataset RegimenToDataset(const Regimen& regimen) {
  Dataset data;
  data.source = "regimen";
  data.columns = {"ID", "TIME", "AMT", "RATE", "II", "ADDL", "SS", "EVID", "CMT", "MDV", "DV"};
  Subject s;
  s.id = regimen.id;
  std::vector<Dose> doses = regimen.doses;
  std::stable_sort(doses.begin(), doses.end(), [](const Dose& a, const Dose& b) { return a.time < b.time; });
  for (const Dose& d : doses) {
    Record r;
    r.id = regimen.id;
    r.time = d.time;
    r.amt = d.amount;
    r.rate = d.duration > 0 ? d.amount / d.duration : d.rate;
    r.ii = d.ii;
    r.addl = d.addl;
    r.ss = d.ss;
    r.evid = Evid::kDose;
    r.cmt = d.cmt;
    r.mdv = 1;
    const RecordProblem problem = CheckRecord(r);
    if (!problem.message.empty()) {
      throw InputError("the dose at TIME " + FormatNumber(d.time) + ": " + problem.message);
    }
    s.records.push_back(r);
  }
  Dataset with_doses = data;
  with_doses.subjects.push_back(s);
  Dataset out = AddOutputTimes(with_doses, regimen.times);
  // Numbered as the lines of the same records in a file with a header, so messages can point at them.
  int line = 1;
  for (Record& r : out.subjects.front().records) r.line = ++line;
  return out;
}

Dataset AddOutputTimes(const Dataset& data, const std::vector<double>& times) {
  std::vector<double> sorted = times;
  std::sort(sorted.begin(), sorted.end());
  Dataset out = data;
  const size_t n_extra = data.extra_columns.size();
  for (Subject& subject : out.subjects) {
    std::vector<Record> merged;
    const std::vector<Record>& old = subject.records;
    merged.reserve(old.size() + sorted.size());
    size_t k = 0;
    auto make = [&](double t, const Record* next) {
      Record r;
      r.id = subject.id;
      r.time = t;
      r.evid = Evid::kOther;
      r.mdv = 1;
      r.line = -1;  // marks an added output record
      r.extra = next ? next->extra : std::vector<double>(n_extra, std::numeric_limits<double>::quiet_NaN());
      return r;
    };
    // A reset whose TIME goes back (EVID 3/4) starts a new time axis, for example the next period of a
    // crossover. The first axis takes every output time (those past its last record follow it, before the
    // reset); each later axis takes those at or after its first record, so every period gets the grid.
    size_t begin = 0;
    while (begin < old.size()) {
      size_t end = begin + 1;
      while (end < old.size() && old[end].time >= old[end - 1].time) ++end;
      if (begin > 0) {
        k = static_cast<size_t>(std::lower_bound(sorted.begin(), sorted.end(), old[begin].time) - sorted.begin());
      }
      for (size_t i = begin; i < end; ++i) {
        // Output times before this record (strictly) come first; those at the
        // same time follow it (they see the post-record state).
        while (k < sorted.size() && sorted[k] < old[i].time) merged.push_back(make(sorted[k++], &old[i]));
        merged.push_back(old[i]);
      }
      // Past the axis's last record its columns stay in force, as past a subject's last record.
      while (k < sorted.size()) merged.push_back(make(sorted[k++], &old[end - 1]));
      begin = end;
    }
    if (old.empty()) {
      while (k < sorted.size()) merged.push_back(make(sorted[k++], nullptr));
    }
    subject.records = std::move(merged);
  }
  return out;
}

Dataset SubjectWithOutputTimes(const Dataset& data, int subject, const std::vector<double>& times,
                               const std::vector<std::string>& columns) {
  Dataset one;
  one.source = data.source;
  one.columns = data.columns;
  one.relative_times = data.relative_times;
  // Only the columns asked for: an added record copies its neighbour's, and a dataset may have
  // thousands of columns that no simulation reads.
  std::vector<int> kept;
  for (const std::string& name : columns) {
    const int c = data.ExtraColumn(name);
    if (c < 0 || std::find(kept.begin(), kept.end(), c) != kept.end()) continue;
    kept.push_back(c);
    one.extra_columns.push_back(data.extra_columns[static_cast<size_t>(c)]);
  }
  Subject s = data.subjects[static_cast<size_t>(subject)];
  for (Record& r : s.records) {
    std::vector<double> extra;
    extra.reserve(kept.size());
    for (int c : kept) extra.push_back(r.extra[static_cast<size_t>(c)]);
    r.extra = std::move(extra);
  }
  one.subjects = {std::move(s)};
  return AddOutputTimes(one, times);
}

}  // namespace pk
