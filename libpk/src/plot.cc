#include "pk/plot.h"

#include <charconv>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

namespace pk {
namespace {

const char* const kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b",
                                "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"};

std::string Escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '&': out += "&amp;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

// SVG coordinates and labels in the same form whatever the C locale (std::to_chars, not printf).
std::string Num(double v) {
  char buf[32];
  return std::string(buf, std::to_chars(buf, buf + sizeof buf, v, std::chars_format::general, 4).ptr);
}

// "Nice" linear tick positions covering [lo, hi].
std::vector<double> LinearTicks(double lo, double hi) {
  const double span = hi - lo;
  // A range that is one value to the last digits (predictions of a fit to constant data) gets one
  // tick: steps of its width would not advance t, and the loop below would never end.
  if (!(span > 1e-9 * std::max(std::fabs(lo), std::fabs(hi))) || !std::isfinite(span)) return {lo};
  const double raw = span / 6;
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  double step = mag;
  for (double m : {1.0, 2.0, 2.5, 5.0, 10.0}) {
    if (m * mag >= raw) {
      step = m * mag;
      break;
    }
  }
  std::vector<double> ticks;
  for (double t = std::ceil(lo / step) * step; t <= hi + 1e-9 * span; t += step) {
    ticks.push_back(std::fabs(t) < 1e-12 * span ? 0.0 : t);
  }
  return ticks;
}

// The fill of a series' markers and legend swatch: white, outlined in the colour, for a hollow series.
std::string Fill(const PlotSeries& s, const char* colour) {
  return s.hollow ? std::string("fill=\"white\" stroke=\"") + colour + "\" stroke-width=\"1.5\""
                  : std::string("fill=\"") + colour + "\"";
}

}  // namespace

std::string RenderSvg(const std::vector<PlotSeries>& series, const PlotOptions& options) {
  double x_lo = std::numeric_limits<double>::infinity(), x_hi = -x_lo;
  double y_lo = x_lo, y_hi = -x_lo;
  auto usable = [&](double y) { return std::isfinite(y) && (!options.log_y || y > 0); };
  for (const PlotSeries& s : series) {
    for (size_t i = 0; i < std::min(s.x.size(), s.y.size()); ++i) {
      if (!usable(s.y[i]) || !std::isfinite(s.x[i])) continue;
      x_lo = std::min(x_lo, s.x[i]);
      x_hi = std::max(x_hi, s.x[i]);
      y_lo = std::min(y_lo, s.y[i]);
      y_hi = std::max(y_hi, s.y[i]);
    }
  }
  if (!std::isfinite(x_lo)) {
    x_lo = 0;
    x_hi = 1;
    y_lo = options.log_y ? 1 : 0;
    y_hi = options.log_y ? 10 : 1;
  }
  if (x_hi <= x_lo) x_hi = x_lo + 1;
  if (options.log_y) {
    y_lo = std::pow(10.0, std::floor(std::log10(y_lo)));
    y_hi = std::pow(10.0, std::ceil(std::log10(y_hi)));
    if (y_hi <= y_lo) y_hi = y_lo * 10;
  } else {
    y_lo = std::min(0.0, y_lo);
    if (y_hi <= y_lo) y_hi = y_lo + 1;
    y_hi += 0.05 * (y_hi - y_lo);
  }

  const double left = 80, right = 170, top = 40, bottom = 60;
  const double w = options.width - left - right, h = options.height - top - bottom;
  auto px = [&](double x) { return left + (x - x_lo) / (x_hi - x_lo) * w; };
  auto py = [&](double y) {
    const double f = options.log_y ? (std::log10(y) - std::log10(y_lo)) / (std::log10(y_hi) - std::log10(y_lo))
                                   : (y - y_lo) / (y_hi - y_lo);
    return top + (1 - f) * h;
  };

  std::ostringstream svg;
  svg << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << options.width << "\" height=\"" << options.height
      << "\" font-family=\"sans-serif\" font-size=\"12\">\n"
      << "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  if (!options.title.empty()) {
    svg << "<text x=\"" << left + w / 2 << "\" y=\"24\" text-anchor=\"middle\" font-size=\"15\">"
        << Escape(options.title) << "</text>\n";
  }
  // Grid and ticks.
  for (double t : LinearTicks(x_lo, x_hi)) {
    svg << "<line x1=\"" << px(t) << "\" y1=\"" << top << "\" x2=\"" << px(t) << "\" y2=\"" << top + h
        << "\" stroke=\"#e5e5e5\"/>\n<text x=\"" << px(t) << "\" y=\"" << top + h + 18
        << "\" text-anchor=\"middle\">" << Num(t) << "</text>\n";
  }
  std::vector<double> y_ticks;
  if (options.log_y) {
    for (double t = y_lo; t <= y_hi * 1.0001; t *= 10) y_ticks.push_back(t);
  } else {
    y_ticks = LinearTicks(y_lo, y_hi);
  }
  for (double t : y_ticks) {
    svg << "<line x1=\"" << left << "\" y1=\"" << py(t) << "\" x2=\"" << left + w << "\" y2=\"" << py(t)
        << "\" stroke=\"#e5e5e5\"/>\n<text x=\"" << left - 8 << "\" y=\"" << py(t) + 4
        << "\" text-anchor=\"end\">" << Num(t) << "</text>\n";
  }
  svg << "<rect x=\"" << left << "\" y=\"" << top << "\" width=\"" << w << "\" height=\"" << h
      << "\" fill=\"none\" stroke=\"black\"/>\n"
      << "<text x=\"" << left + w / 2 << "\" y=\"" << options.height - 15 << "\" text-anchor=\"middle\">"
      << Escape(options.x_label) << "</text>\n"
      << "<text transform=\"translate(20," << top + h / 2 << ") rotate(-90)\" text-anchor=\"middle\">"
      << Escape(options.y_label) << (options.log_y ? " (log scale)" : "") << "</text>\n";

  for (size_t k = 0; k < series.size(); ++k) {
    const PlotSeries& s = series[k];
    const char* colour = kColours[k % (sizeof kColours / sizeof kColours[0])];
    if (s.markers) {
      for (size_t i = 0; i < std::min(s.x.size(), s.y.size()); ++i) {
        if (!usable(s.y[i])) continue;
        svg << "<circle cx=\"" << px(s.x[i]) << "\" cy=\"" << py(s.y[i]) << "\" r=\"3.5\" " << Fill(s, colour) << "/>\n";
      }
    } else {
      svg << "<polyline fill=\"none\" stroke=\"" << colour << "\" stroke-width=\"1.6\" points=\"";
      for (size_t i = 0; i < std::min(s.x.size(), s.y.size()); ++i) {
        if (usable(s.y[i])) svg << px(s.x[i]) << "," << py(s.y[i]) << " ";
      }
      svg << "\"/>\n";
    }
    if (series.size() <= 24) {
      const double ly = top + 10 + 16 * static_cast<double>(k);
      svg << "<rect x=\"" << left + w + 12 << "\" y=\"" << ly - 8 << "\" width=\"12\" height=\"8\" " << Fill(s, colour)
          << "/><text x=\"" << left + w + 30 << "\" y=\"" << ly << "\">" << Escape(s.label) << "</text>\n";
    }
  }
  svg << "</svg>\n";
  return svg.str();
}

}  // namespace pk
