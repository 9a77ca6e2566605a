// The minimisers by name: adding one is a file in this folder and a line here.
#include "estimation/minimizer.h"

#include <vector>

namespace pk {
namespace internal {

// One line each here and in Registry(), for the minimiser in its own file of this folder.
std::unique_ptr<Minimizer> MakeLevenbergMarquardt(const std::string& argument, std::string* why);
std::unique_ptr<Minimizer> MakeBfgs(const std::string& argument, std::string* why);
std::unique_ptr<Minimizer> MakeNewton(const std::string& argument, std::string* why);
std::unique_ptr<Minimizer> MakeNloptMinimizer(const std::string& argument, std::string* why);

namespace {

struct Entry {
  const char* name;  // the whole name, or its prefix up to ':' for a minimiser that takes an argument
  bool takes_argument;
  std::unique_ptr<Minimizer> (*make)(const std::string& argument, std::string* why);
};

const std::vector<Entry>& Registry() {
  static const std::vector<Entry> registry = {
      {"lm", false, MakeLevenbergMarquardt},
      {"bfgs", false, MakeBfgs},
      {"newton", false, MakeNewton},
      {"nlopt", true, MakeNloptMinimizer},
  };
  return registry;
}

}  // namespace

std::unique_ptr<Minimizer> MakeMinimizer(const std::string& name, std::string* why) {
  const size_t colon = name.find(':');
  const std::string head = name.substr(0, colon);
  for (const Entry& e : Registry()) {
    if (head != e.name || (colon != std::string::npos) != e.takes_argument) continue;
    return e.make(colon == std::string::npos ? "" : name.substr(colon + 1), why);
  }
  std::string names;
  for (size_t k = 0; k < Registry().size(); ++k) {
    const Entry& e = Registry()[k];
    names += std::string(k == 0 ? "" : k + 1 == Registry().size() ? " or " : ", ") + e.name +
             (e.takes_argument ? ":NAME" : "");
  }
  *why = "expected " + names + ", got '" + name + "'";
  return nullptr;
}

}  // namespace internal
}  // namespace pk
