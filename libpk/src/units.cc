#include "pk/units.h"

#include <cctype>
#include <sstream>

#include "internal_text.h"
#include "pk/error.h"

namespace pk {
namespace {

using internal::ToUpper;

bool StartsWith(const std::string& s, const char* prefix) { return s.rfind(prefix, 0) == 0; }

// A name that is a prefix followed by digits only (or nothing): "V", "V2", "Q3", "K10".
bool Numbered(const std::string& name, const char* prefix) {
  if (!StartsWith(name, prefix)) return false;
  for (size_t i = std::string(prefix).size(); i < name.size(); ++i) {
    if (!std::isdigit(static_cast<unsigned char>(name[i]))) return false;
  }
  return true;
}

std::string Per(const std::string& numerator, const std::string& denominator) {
  if (numerator.empty() || denominator.empty()) return "";
  return numerator + "/" + denominator;
}

}  // namespace

Units ParseUnits(const std::string& text) {
  Units u;
  std::stringstream list(text);
  std::string item;
  while (std::getline(list, item, ',')) {
    const size_t eq = item.find('=');
    if (eq == std::string::npos) throw InputError("--units: expected KEY=UNIT, got '" + item + "'");
    const std::string key = internal::ToLower(internal::Trim(item.substr(0, eq)));
    const std::string unit = internal::Trim(item.substr(eq + 1));
    if (key == "time") {
      u.time = unit;
    } else if (key == "amt" || key == "amount") {
      u.amount = unit;
    } else if (key == "conc" || key == "dv") {
      u.concentration = unit;
    } else {
      throw InputError("--units: unknown key '" + key + "' (time, amt or conc)");
    }
  }
  return u;
}

Units DatasetUnits(const Dataset& data) {
  Units u;
  const auto find = [&](const char* column) {
    const auto it = data.column_units.find(column);
    return it == data.column_units.end() ? std::string() : it->second;
  };
  u.time = find("TIME");
  u.amount = find("AMT");
  u.concentration = find("DV");
  return u;
}

Units MergeUnits(const Units& given, const Units& fallback) {
  Units u = given;
  if (u.time.empty()) u.time = fallback.time;
  if (u.amount.empty()) u.amount = fallback.amount;
  if (u.concentration.empty()) u.concentration = fallback.concentration;
  return u;
}

std::string VolumeUnit(const Units& units) {
  if (units.amount.empty() || units.concentration.empty()) return "";
  const size_t slash = units.concentration.find('/');
  if (slash != std::string::npos && units.concentration.substr(0, slash) == units.amount) {
    return units.concentration.substr(slash + 1);
  }
  return units.amount + "/(" + units.concentration + ")";
}

std::string ParameterUnit(const std::string& raw, const Units& units) {
  const std::string name = ToUpper(raw);
  const auto declared = units.parameters.find(name);
  if (declared != units.parameters.end()) return declared->second;
  const std::string volume = VolumeUnit(units), per_time = units.time.empty() ? "" : "1/" + units.time;
  if (name == "VMAX") return Per(units.amount, units.time);
  // Exposure: AUC is concentration × time; CMAX, CMIN and CTROUGH a concentration, TMAX a time.
  if (name == "AUC") return units.concentration.empty() || units.time.empty() ? "" : units.concentration + "·" + units.time;
  if (name == "CMAX" || name == "CMIN" || name == "CTROUGH") return units.concentration;
  if (name == "TMAX") return units.time;
  if (name == "KM" || name == "EC50" || name == "SIGMA_ADD") return units.concentration;
  if (name == "SIGMA_PROP" || name == "SIGMA_LOG" || name == "HILL" || Numbered(name, "F")) return "1";
  if (Numbered(name, "V")) return volume;
  if (Numbered(name, "CL") || Numbered(name, "Q")) return Per(volume, units.time);
  if (name == "KA" || name == "KE0" || Numbered(name, "K") || StartsWith(name, "LAMBDA")) return per_time;
  if (Numbered(name, "ALAG") || Numbered(name, "D") || name == "MTT" || StartsWith(name, "THALF")) return units.time;
  if (Numbered(name, "R") || Numbered(name, "K0_")) return Per(units.amount, units.time);
  if (Numbered(name, "X0_")) return units.amount;
  return "";
}

Units ModelUnits(const Units& units, const Model& model) {
  Units out = units;
  const ModelDeclarations& d = model.declarations();
  for (const auto* list : {&d.parameters, &d.modifiers}) {
    for (const DeclaredParameter& p : *list) {
      if (!p.unit.empty()) out.parameters[ToUpper(p.name)] = p.unit;
    }
  }
  return out;
}

std::string WithUnit(const std::string& name, const std::string& unit) {
  return unit.empty() || unit == "1" ? name : name + " (" + unit + ")";
}

}  // namespace pk
