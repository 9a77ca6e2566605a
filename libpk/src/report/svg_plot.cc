#include <charconv>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "pk/plot.h"

namespace pk {
namespace {

// 20 colours that stay apart from each other (Tableau 20: the dark shades, then the light ones).
const char* const kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2",
                                "#7f7f7f", "#bcbd22", "#17becf", "#aec7e8", "#ff9896", "#98df8a", "#ffbb78",
                                "#c5b0d5", "#c49c94", "#f7b6d2", "#393b79", "#dbdb8d", "#9edae5"};
constexpr int kNumColours = sizeof kColours / sizeof kColours[0];

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
std::string Num(double v, int digits = 4) {
  char buf[32];
  return std::string(buf, std::to_chars(buf, buf + sizeof buf, v, std::chars_format::general, digits).ptr);
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

// Log ticks in [lo, hi]: 1, 2 and 5 times powers of ten over up to 3.5 decades, decades beyond.
std::vector<double> LogTicks(double lo, double hi) {
  if (!(lo > 0) || !(hi > lo) || !std::isfinite(hi)) return {};
  const int first = static_cast<int>(std::floor(std::log10(lo))), last = static_cast<int>(std::ceil(std::log10(hi)));
  const bool fine = std::log10(hi / lo) <= 3.5;
  std::vector<double> ticks;
  for (int e = first; e <= last; ++e) {
    for (double m : {1.0, 2.0, 5.0}) {
      if (!fine && m != 1.0) continue;
      const double t = m * std::pow(10.0, e);
      if (t >= lo * (1 - 1e-9) && t <= hi * (1 + 1e-9)) ticks.push_back(t);
    }
  }
  if (ticks.size() < 2) ticks = {lo, hi};  // under a factor of 2: the ends
  return ticks;
}

// A log axis spans at most this many decades below its largest value, and with markers reaches at
// most a factor kBelowMarkers below the smallest: a curve that rises from 0 or decays to 1e-300 would
// otherwise squeeze the data into a sliver. What lies below is not drawn.
constexpr double kMaxDecades = 6;
constexpr double kBelowMarkers = 4;

// One axis: its range from the data, padded so that markers at the extremes stay inside the frame.
struct Axis {
  bool log = false;
  double lo = std::numeric_limits<double>::infinity(), hi = -std::numeric_limits<double>::infinity();
  double floor = 0;  // log: the smallest value drawn, once the range is known
  double marker_lo = std::numeric_limits<double>::infinity();  // the smallest marker

  bool Usable(double v) const { return std::isfinite(v) && (!log || v > floor); }
  void Add(double v) {
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  void Finish(bool from_zero) {
    if (!std::isfinite(lo)) {
      lo = log ? 1 : 0;
      hi = log ? 10 : 1;
    }
    if (log) {
      double a = std::max(std::log10(lo), std::log10(hi) - kMaxDecades), b = std::log10(hi);
      if (std::isfinite(marker_lo)) a = std::max(a, std::log10(marker_lo / kBelowMarkers));
      if (b - a < 1e-9) {
        a -= 0.5;
        b += 0.5;
      }
      const double pad = 0.04 * (b - a);
      lo = std::pow(10.0, a - pad);
      hi = std::pow(10.0, b + pad);
      floor = std::pow(10.0, a) * (1 - 1e-12);
      return;
    }
    if (from_zero && lo > 0) lo = 0;
    if (hi - lo <= 1e-12 * std::max(std::fabs(lo), std::fabs(hi))) {
      const double half = lo == 0 ? 0.5 : 0.05 * std::fabs(lo);
      lo -= half;
      hi += half;
    }
    const double pad = 0.04 * (hi - lo);
    hi += pad;
    if (!(from_zero && lo == 0)) lo -= pad;
  }
  double Fraction(double v) const {
    return log ? (std::log10(v) - std::log10(lo)) / (std::log10(hi) - std::log10(lo)) : (v - lo) / (hi - lo);
  }
  std::vector<double> Ticks() const { return log ? LogTicks(lo, hi) : LinearTicks(lo, hi); }
};

// The fill of a series' markers and legend swatch: white, outlined in the colour, for a hollow series.
std::string Fill(const PlotSeries& s, const std::string& colour) {
  return s.hollow ? "fill=\"white\" stroke=\"" + colour + "\" stroke-width=\"1.5\"" : "fill=\"" + colour + "\"";
}

std::string ColourOf(const PlotSeries& s, int k) {
  if (!s.colour.empty()) return s.colour;
  return s.reference ? "#555555" : PaletteColour(k);
}

// Half the width of a band or a line with one point (a VPC of one bin), in pixels.
constexpr double kLoneHalfWidth = 12;

// A band's polygon: along upper, then back along y, over the points whose x and upper are drawn. A
// lower end of −∞ (a VPC's interval reaching below the limit of quantification) runs to the frame's
// bottom.
template <typename Px, typename Py, typename Usable>
std::string Band(const PlotSeries& s, const std::string& colour, const Px& px, const Py& py, const Usable& usable,
                 double bottom) {
  std::vector<size_t> drawn;
  for (size_t i = 0; i < std::min({s.x.size(), s.y.size(), s.upper.size()}); ++i) {
    if (usable(s.x[i], s.upper[i]) && (usable(s.x[i], s.y[i]) || s.y[i] == -HUGE_VAL)) drawn.push_back(i);
  }
  if (drawn.empty()) return "";
  if (drawn.size() == 1) {  // one x (a VPC of one bin): the interval as a box, where a polygon has no width
    const size_t i = drawn.front();
    const double top = py(s.upper[i]), low = s.y[i] == -HUGE_VAL ? bottom : py(s.y[i]);
    return "<rect fill=\"" + colour + "\" fill-opacity=\"0.3\" stroke=\"none\" x=\"" + Num(px(s.x[i]) - kLoneHalfWidth, 6) +
           "\" y=\"" + Num(std::min(top, low), 6) + "\" width=\"" + Num(2 * kLoneHalfWidth, 6) + "\" height=\"" +
           Num(std::fabs(low - top), 6) + "\"/>\n";
  }
  std::string points;
  for (size_t i : drawn) points += Num(px(s.x[i]), 6) + "," + Num(py(s.upper[i]), 6) + " ";
  for (auto it = drawn.rbegin(); it != drawn.rend(); ++it) {
    const double y = s.y[*it] == -HUGE_VAL ? bottom : py(s.y[*it]);
    points += Num(px(s.x[*it]), 6) + "," + Num(y, 6) + " ";
  }
  return "<polygon fill=\"" + colour + "\" fill-opacity=\"0.3\" stroke=\"none\" points=\"" + points + "\"/>\n";
}

}  // namespace

const char* PaletteColour(int k) { return kColours[((k % kNumColours) + kNumColours) % kNumColours]; }

std::string RenderSvg(const std::vector<PlotSeries>& series, const PlotOptions& options) {
  Axis ax, ay;
  ax.log = options.log_x;
  ay.log = options.log_y;
  for (const PlotSeries& s : series) {
    for (size_t i = 0; i < std::min(s.x.size(), s.y.size()); ++i) {
      if (!ax.Usable(s.x[i]) || !ay.Usable(s.y[i])) continue;
      ax.Add(s.x[i]);
      ay.Add(s.y[i]);
      if (i < s.upper.size() && ay.Usable(s.upper[i])) ay.Add(s.upper[i]);
      if (s.markers) {
        ax.marker_lo = std::min(ax.marker_lo, s.x[i]);
        ay.marker_lo = std::min(ay.marker_lo, s.y[i]);
      }
    }
  }
  ax.Finish(false);
  ay.Finish(!options.log_y);
  const bool small = options.width < 500;
  const double left = small ? 58 : 80, right = options.legend ? 170 : 14, top = options.title.empty() ? 12 : 32;
  const double bottom = small ? 44 : 60;
  const double w = options.width - left - right, h = options.height - top - bottom;
  auto px = [&](double x) { return left + ax.Fraction(x) * w; };
  auto py = [&](double y) { return top + (1 - ay.Fraction(y)) * h; };

  std::ostringstream svg;
  svg << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << options.width << "\" height=\"" << options.height
      << "\" viewBox=\"0 0 " << options.width << " " << options.height << "\" font-family=\"sans-serif\" font-size=\""
      << (small ? 11 : 12) << "\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  if (!options.title.empty()) {
    svg << "<text x=\"" << Num(left + w / 2) << "\" y=\"" << (small ? 20 : 24) << "\" text-anchor=\"middle\" font-size=\""
        << (small ? 13 : 15) << "\">" << Escape(options.title) << "</text>\n";
  }
  for (double t : ax.Ticks()) {
    svg << "<line x1=\"" << Num(px(t)) << "\" y1=\"" << top << "\" x2=\"" << Num(px(t)) << "\" y2=\"" << Num(top + h)
        << "\" stroke=\"#e5e5e5\"/>\n<text x=\"" << Num(px(t)) << "\" y=\"" << Num(top + h + 16)
        << "\" text-anchor=\"middle\">" << Num(t, 3) << "</text>\n";
  }
  for (double t : ay.Ticks()) {
    svg << "<line x1=\"" << left << "\" y1=\"" << Num(py(t)) << "\" x2=\"" << Num(left + w) << "\" y2=\"" << Num(py(t))
        << "\" stroke=\"#e5e5e5\"/>\n<text x=\"" << left - 6 << "\" y=\"" << Num(py(t) + 4)
        << "\" text-anchor=\"end\">" << Num(t, 3) << "</text>\n";
  }
  svg << "<rect x=\"" << left << "\" y=\"" << top << "\" width=\"" << Num(w) << "\" height=\"" << Num(h)
      << "\" fill=\"none\" stroke=\"black\"/>\n<text x=\"" << Num(left + w / 2) << "\" y=\"" << options.height - 10
      << "\" text-anchor=\"middle\">" << Escape(options.x_label) << (options.log_x ? " (log scale)" : "")
      << "</text>\n<text transform=\"translate(" << (small ? 14 : 20) << "," << Num(top + h / 2)
      << ") rotate(-90)\" text-anchor=\"middle\">" << Escape(options.y_label) << (options.log_y ? " (log scale)" : "")
      << "</text>\n";

  int legend_row = 0;
  for (size_t k = 0; k < series.size(); ++k) {
    const PlotSeries& s = series[k];
    const std::string colour = ColourOf(s, static_cast<int>(k));
    const auto shown = [&](size_t i) { return ax.Usable(s.x[i]) && ay.Usable(s.y[i]); };
    if (!s.upper.empty()) {
      svg << Band(s, colour, px, py, [&](double x, double y) { return ax.Usable(x) && ay.Usable(y); }, top + h);
    } else if (s.markers) {
      for (size_t i = 0; i < std::min(s.x.size(), s.y.size()); ++i) {
        if (!shown(i)) continue;
        svg << "<circle cx=\"" << Num(px(s.x[i])) << "\" cy=\"" << Num(py(s.y[i])) << "\" r=\"" << (small ? 3 : 3.5)
            << "\" " << Fill(s, colour) << "/>\n";
      }
    } else {
      std::vector<size_t> points;
      for (size_t i = 0; i < std::min(s.x.size(), s.y.size()); ++i) {
        if (shown(i)) points.push_back(i);
      }
      svg << "<polyline fill=\"none\" stroke=\"" << colour << "\" stroke-width=\"" << (s.reference ? 1.2 : 1.6) << "\""
          << ((s.reference && s.colour.empty()) || s.dashed ? " stroke-dasharray=\"5,4\"" : "") << " points=\"";
      if (points.size() == 1) {  // a line of one point has no length: a level across the point instead
        const double x = px(s.x[points.front()]), y = py(s.y[points.front()]);
        svg << Num(x - kLoneHalfWidth, 6) << "," << Num(y, 6) << " " << Num(x + kLoneHalfWidth, 6) << "," << Num(y, 6);
      } else {
        for (size_t i : points) svg << Num(px(s.x[i]), 6) << "," << Num(py(s.y[i]), 6) << " ";
      }
      svg << "\"/>\n";
    }
    if (options.legend && series.size() <= 24) {
      const double ly = top + 10 + 16 * static_cast<double>(legend_row++);
      if (s.markers || !s.upper.empty()) {  // a swatch
        svg << "<rect x=\"" << Num(left + w + 12) << "\" y=\"" << Num(ly - 8) << "\" width=\"12\" height=\"8\" "
            << Fill(s, colour) << (s.upper.empty() ? "" : " fill-opacity=\"0.3\"") << "/>";
      } else {  // a stretch of the line, dashed as it is
        svg << "<line x1=\"" << Num(left + w + 10) << "\" y1=\"" << Num(ly - 4) << "\" x2=\"" << Num(left + w + 26)
            << "\" y2=\"" << Num(ly - 4) << "\" stroke=\"" << colour << "\" stroke-width=\"2\""
            << ((s.reference && s.colour.empty()) || s.dashed ? " stroke-dasharray=\"4,3\"" : "") << "/>";
      }
      svg << "<text x=\"" << Num(left + w + 30) << "\" y=\"" << Num(ly) << "\">" << Escape(s.label)
          << "</text>\n";
    }
  }
  svg << "</svg>\n";
  return svg.str();
}

PlotSeries DecimateLine(const PlotSeries& line, int max_points) {
  const size_t n = std::min(line.x.size(), line.y.size());
  if (max_points < 4) throw std::invalid_argument("DecimateLine: at least 4 points");
  if (n <= static_cast<size_t>(max_points)) return line;
  PlotSeries out = line;
  out.x.clear();
  out.y.clear();
  // Consecutive runs of points, not ranges of x: a reset record may take time back.
  const size_t buckets = static_cast<size_t>(max_points) / 2;
  for (size_t b = 0; b < buckets; ++b) {
    const size_t begin = b * n / buckets, end = (b + 1) * n / buckets;
    size_t lo = begin, hi = begin;
    for (size_t i = begin; i < end; ++i) {
      if (line.y[i] < line.y[lo]) lo = i;
      if (line.y[i] > line.y[hi]) hi = i;
    }
    out.x.push_back(line.x[std::min(lo, hi)]);
    out.y.push_back(line.y[std::min(lo, hi)]);
    if (lo == hi) continue;
    out.x.push_back(line.x[std::max(lo, hi)]);
    out.y.push_back(line.y[std::max(lo, hi)]);
  }
  return out;
}

std::string RenderPanelsSvg(const std::vector<std::vector<PlotSeries>>& panels, const std::vector<PlotOptions>& options) {
  if (panels.size() != options.size()) throw std::invalid_argument("RenderPanelsSvg: one PlotOptions per panel");
  int width = 0, height = 0;
  for (const PlotOptions& o : options) {
    width = std::max(width, o.width);
    height += o.height;
  }
  std::ostringstream svg;
  svg << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << width << "\" height=\"" << height << "\" viewBox=\"0 0 "
      << width << " " << height << "\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  int y = 0;
  for (size_t k = 0; k < panels.size(); ++k) {
    // Each panel is a document of its own, nested at its place: "<svg " + y + the rest.
    const std::string panel = RenderSvg(panels[k], options[k]);
    svg << "<svg y=\"" << y << "\" " << panel.substr(5);
    y += options[k].height;
  }
  svg << "</svg>\n";
  return svg.str();
}

}  // namespace pk
