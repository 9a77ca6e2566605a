#include "pk/simulation_csv.h"

#include <algorithm>
#include <array>
#include <cstring>
#include <stdexcept>
#include <vector>

#include "../internal_text.h"
#include "pk/error.h"
#include "pk/output.h"

namespace pk {

namespace {

// Each row's TIME text, kept from one subject to the next on this thread: subjects share their
// output grid, and a number's shortest digits cost several times their copy. A row whose time has
// the cached bits takes the cached text; any other is written and cached.
class TimeTexts {
 public:
  char* Write(size_t row, double time, char* p) {
    if (row < rows_.size() && std::memcmp(&rows_[row].time, &time, sizeof time) == 0) {
      return std::copy_n(rows_[row].text.data(), rows_[row].size, p);
    }
    char* end = internal::WriteNumber(time, p);
    if (end - p > 24) return end;  // never: a number's text has at most 24 characters
    if (row >= rows_.size()) rows_.resize(row + 1);
    Text& cached = rows_[row];
    cached.time = time;
    cached.size = static_cast<unsigned char>(end - p);
    std::copy(p, end, cached.text.data());
    return end;
  }
  static TimeTexts& ForThisThread() {
    thread_local TimeTexts texts;
    return texts;
  }

 private:
  struct Text {
    double time = 0;
    unsigned char size = 0;
    std::array<char, 24> text;
  };
  std::vector<Text> rows_;
};

// Whether `s` has rows to write; throws when its amounts and outputs lack a column per row.
bool HasRows(const SubjectSimulation& s, const char* who) {
  if (!s.ok || s.rows.empty()) return false;
  if (s.amounts.cols() != static_cast<Eigen::Index>(s.rows.size()) ||
      (s.outputs.size() && s.outputs.cols() != s.amounts.cols())) {
    throw std::invalid_argument(std::string(who) + ": the amounts and outputs need a column per row");
  }
  return true;
}

}  // namespace

std::string SimulationCsvHeader(const Model& model) {
  std::string csv = "ID,TIME,EVID,CP";
  for (int k = 1; k < model.num_outputs(); ++k) csv += "," + model.output_names()[static_cast<size_t>(k)];
  for (int c = 1; c <= model.num_compartments(); ++c) csv += ",A" + std::to_string(c);
  return csv + "\n";
}

void AppendSimulationCsv(const SubjectSimulation& s, std::string* out) {
  if (!HasRows(s, "AppendSimulationCsv")) return;
  char id[48];
  const size_t id_size = static_cast<size_t>(internal::WriteNumber(s.id, id) - id);
  const Eigen::Index outputs = std::max<Eigen::Index>(s.outputs.rows() - 1, 0), amounts = s.amounts.rows();
  // Room for the longest row (a number is at most 24 characters and its comma), written through a
  // pointer, then cut to what was written.
  const size_t longest = id_size + 3 + static_cast<size_t>(3 + outputs + amounts) * 25 + 1;
  const size_t start = out->size();
  out->resize(start + s.rows.size() * longest + 48);  // WriteNumber's room past the last number
  char* p = &(*out)[start];
  TimeTexts& times = TimeTexts::ForThisThread();
  for (size_t i = 0; i < s.rows.size(); ++i) {
    const SimulatedRecord& r = s.rows[i];
    const auto col = static_cast<Eigen::Index>(i);
    p = std::copy(id, id + id_size, p);
    *p++ = ',';
    p = times.Write(i, r.time, p);
    p = std::copy_n(r.evid == Evid::kObservation ? ",0," : ",2,", 3, p);
    p = internal::WriteNumber(r.cp, p);
    for (Eigen::Index k = 1; k <= outputs; ++k) {
      *p++ = ',';
      p = internal::WriteNumber(s.outputs(k, col), p);
    }
    for (Eigen::Index c = 0; c < amounts; ++c) {
      *p++ = ',';
      p = internal::WriteNumber(s.amounts(c, col), p);
    }
    *p++ = '\n';
  }
  out->resize(static_cast<size_t>(p - out->data()));
}

namespace {

std::vector<std::string> Split(const std::string& list) {
  std::vector<std::string> out;
  std::string item;
  for (char c : list + ",") {
    if (c != ',') {
      if (c != ' ') item += c;
      continue;
    }
    out.push_back(internal::ToUpper(item));
    item.clear();
  }
  return out;
}

}  // namespace

namespace {

// The name of output k's simulated observation: DV for the first, DV_<NAME> for the others.
std::string ObservationName(const Model& model, int k) {
  return k == 0 ? "DV" : "DV_" + internal::ToUpper(model.output_names()[static_cast<size_t>(k)]);
}

}  // namespace

SimulationColumns::SimulationColumns(const Model& model, const std::string& list)
    : SimulationColumns(model, list, {}, false) {}

std::string SimulationColumns::DefaultList(const Model& model, const std::vector<std::string>& etas, bool observations,
                                           bool replicates) {
  std::string list = std::string(replicates ? "REP," : "") + "ID,TIME,EVID,CP";
  for (int k = 1; k < model.num_outputs(); ++k) list += "," + model.output_names()[static_cast<size_t>(k)];
  for (int k = 0; observations && k < std::max(model.num_outputs(), 1); ++k) list += "," + ObservationName(model, k);
  for (int c = 1; c <= model.num_compartments(); ++c) list += ",A" + std::to_string(c);
  for (const std::string& e : etas) list += "," + e;
  return list;
}

SimulationColumns::SimulationColumns(const Model& model, const std::string& list, const std::vector<std::string>& etas,
                                     bool observations) {
  std::vector<Column> all = {{Kind::kId, 0, "ID"}, {Kind::kTime, 0, "TIME"}, {Kind::kEvid, 0, "EVID"},
                             {Kind::kCp, 0, "CP"}};
  for (int k = 1; k < model.num_outputs(); ++k) {
    all.push_back({Kind::kOutput, k, internal::ToUpper(model.output_names()[static_cast<size_t>(k)])});
  }
  for (int c = 0; c < model.num_compartments(); ++c) all.push_back({Kind::kAmount, c, "A" + std::to_string(c + 1)});
  if (!etas.empty()) all.push_back({Kind::kReplicate, 0, "REP"});
  for (size_t k = 0; k < etas.size(); ++k) all.push_back({Kind::kEta, static_cast<int>(k), internal::ToUpper(etas[k])});
  for (int k = 0; observations && k < std::max(model.num_outputs(), 1); ++k) {
    all.push_back({Kind::kObservation, k, ObservationName(model, k)});
  }
  std::vector<std::string> names;
  for (const Column& c : all) names.push_back(c.name);
  for (const std::string& name : Split(list)) {
    const auto it = std::find_if(all.begin(), all.end(), [&](const Column& c) { return c.name == name; });
    if (it == all.end()) {
      const std::string closest = ClosestName(name, names);
      throw InputError("--columns: " + (name.empty() ? std::string("an empty name") : "no column " + name) +
                       (closest.empty() ? "" : " (did you mean " + closest + "?)") + "; model " + model.name() +
                       " has " + internal::Join(names, ","));
    }
    for (const Column& c : columns_) {
      if (c.name == name) throw InputError("--columns: " + name + " is named twice");
    }
    columns_.push_back(*it);
  }
}

std::string SimulationColumns::Header() const {
  std::string out;
  for (const Column& c : columns_) out += (out.empty() ? "" : ",") + c.name;
  return out + "\n";
}

void SimulationColumns::Append(const SubjectSimulation& s, std::string* out) const {
  if (!HasRows(s, "SimulationColumns::Append")) return;
  for (const Column& c : columns_) {
    if ((c.kind == Kind::kEta && c.index >= s.eta.size()) ||
        (c.kind == Kind::kObservation && (c.index >= s.observations.rows() ||
                                          s.observations.cols() != static_cast<Eigen::Index>(s.rows.size())))) {
      throw std::invalid_argument("SimulationColumns::Append: " + c.name + " needs a simulation with variability");
    }
  }
  char id[48];
  const size_t id_size = static_cast<size_t>(internal::WriteNumber(s.id, id) - id);
  const size_t longest = (id_size + 25) * columns_.size() + 1;
  const size_t start = out->size();
  out->resize(start + s.rows.size() * longest + 48);  // WriteNumber's room past the last number
  char* p = &(*out)[start];
  TimeTexts& times = TimeTexts::ForThisThread();
  for (size_t i = 0; i < s.rows.size(); ++i) {
    const SimulatedRecord& r = s.rows[i];
    const auto col = static_cast<Eigen::Index>(i);
    for (size_t k = 0; k < columns_.size(); ++k) {
      if (k > 0) *p++ = ',';
      const Column& c = columns_[k];
      switch (c.kind) {
        case Kind::kId: p = std::copy(id, id + id_size, p); break;
        case Kind::kTime: p = times.Write(i, r.time, p); break;
        case Kind::kEvid: *p++ = r.evid == Evid::kObservation ? '0' : '2'; break;
        case Kind::kCp: p = internal::WriteNumber(r.cp, p); break;
        case Kind::kOutput: p = internal::WriteNumber(s.outputs(c.index, col), p); break;
        case Kind::kAmount: p = internal::WriteNumber(s.amounts(c.index, col), p); break;
        case Kind::kReplicate: p = internal::WriteNumber(s.replicate + 1, p); break;
        case Kind::kEta: p = internal::WriteNumber(s.eta(c.index), p); break;
        case Kind::kObservation: p = internal::WriteNumber(s.observations(c.index, col), p); break;
      }
    }
    *p++ = '\n';
  }
  out->resize(static_cast<size_t>(p - out->data()));
}

}  // namespace pk
