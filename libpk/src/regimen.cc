#include "pk/regimen.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "output_times.h"
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

namespace {

// The next record of *out to write, its storage reused: assigning into a record keeps its column
// vector's capacity, so simulating many subjects through one workspace allocates nothing per row.
Record& NextSlot(std::vector<Record>* out, size_t* used) {
  if (*used == out->size()) out->emplace_back();
  return (*out)[(*used)++];
}

// An output record at t for subject `id`: the columns of `next` (the record it precedes, or the
// last one), or NaN throughout without one.
void WriteOutputRecord(double id, double t, const Record* next, size_t n_extra, Record* r) {
  std::vector<double> extra = std::move(r->extra);
  *r = Record();
  r->id = id;
  r->time = t;
  r->evid = Evid::kOther;
  r->mdv = 1;
  r->line = -1;  // marks an added output record
  if (next) {
    extra.assign(next->extra.begin(), next->extra.end());
  } else {
    extra.assign(n_extra, std::numeric_limits<double>::quiet_NaN());
  }
  r->extra = std::move(extra);
}

// `old` with output records at `sorted` merged in, as AddOutputTimes describes, into *merged.
void MergeOutputTimes(const std::vector<Record>& old, double id, const std::vector<double>& sorted, size_t n_extra,
                      std::vector<Record>* merged) {
  size_t used = 0, k = 0;
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
      while (k < sorted.size() && sorted[k] < old[i].time) {
        WriteOutputRecord(id, sorted[k++], &old[i], n_extra, &NextSlot(merged, &used));
      }
      NextSlot(merged, &used) = old[i];
    }
    // Past the axis's last record its columns stay in force, as past a subject's last record.
    while (k < sorted.size()) WriteOutputRecord(id, sorted[k++], &old[end - 1], n_extra, &NextSlot(merged, &used));
    begin = end;
  }
  if (old.empty()) {
    while (k < sorted.size()) WriteOutputRecord(id, sorted[k++], nullptr, n_extra, &NextSlot(merged, &used));
  }
  merged->resize(used);
}

void SortedTimes(const std::vector<double>& times, std::vector<double>* sorted) {
  sorted->assign(times.begin(), times.end());
  if (!std::is_sorted(sorted->begin(), sorted->end())) std::sort(sorted->begin(), sorted->end());
}

}  // namespace

Dataset AddOutputTimes(const Dataset& data, const std::vector<double>& times) {
  std::vector<double> sorted;
  SortedTimes(times, &sorted);
  Dataset out = data;
  for (Subject& subject : out.subjects) {
    std::vector<Record> merged;
    merged.reserve(subject.records.size() + sorted.size());
    MergeOutputTimes(subject.records, subject.id, sorted, data.extra_columns.size(), &merged);
    subject.records = std::move(merged);
  }
  return out;
}

namespace internal {

void SubjectWithOutputTimes(const Dataset& data, int subject, const std::vector<double>& times,
                            const std::vector<std::string>& columns, OutputTimesWorkspace* w) {
  Dataset& one = w->one;
  one.source = data.source;
  one.columns = data.columns;
  one.relative_times = data.relative_times;
  // Only the columns asked for: an added record copies its neighbour's, and a dataset may have
  // thousands of columns that no simulation reads.
  w->kept.clear();
  one.extra_columns.clear();
  for (const std::string& name : columns) {
    const int c = data.ExtraColumn(name);
    if (c < 0 || std::find(w->kept.begin(), w->kept.end(), c) != w->kept.end()) continue;
    w->kept.push_back(c);
    one.extra_columns.push_back(data.extra_columns[static_cast<size_t>(c)]);
  }
  const Subject& from = data.subjects[static_cast<size_t>(subject)];
  size_t used = 0;
  for (const Record& r : from.records) {
    Record& copy = NextSlot(&w->reduced, &used);
    copy = r;
    w->scratch.clear();
    for (int c : w->kept) w->scratch.push_back(r.extra[static_cast<size_t>(c)]);
    copy.extra.assign(w->scratch.begin(), w->scratch.end());
  }
  w->reduced.resize(used);
  SortedTimes(times, &w->sorted);
  one.subjects.resize(1);
  one.subjects[0].id = from.id;
  one.subjects[0].occurrence = from.occurrence;
  MergeOutputTimes(w->reduced, from.id, w->sorted, w->kept.size(), &one.subjects[0].records);
}

}  // namespace internal

Dataset SubjectWithOutputTimes(const Dataset& data, int subject, const std::vector<double>& times,
                               const std::vector<std::string>& columns) {
  internal::OutputTimesWorkspace w;
  internal::SubjectWithOutputTimes(data, subject, times, columns, &w);
  return std::move(w.one);
}

}  // namespace pk
