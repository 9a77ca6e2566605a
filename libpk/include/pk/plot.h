// libpk report library (target pk::report): SVG plots of concentration against time and the
// goodness-of-fit plots, and the LOWESS smoother they draw. Presentation only: the core library
// (pk::pk) does not depend on it.
#ifndef PK_PLOT_H_
#define PK_PLOT_H_

#include <string>
#include <utility>
#include <vector>

namespace pk {

struct PlotSeries {
  PlotSeries() = default;
  PlotSeries(std::string label_, std::vector<double> x_, std::vector<double> y_, bool markers_ = false)
      : label(std::move(label_)), x(std::move(x_)), y(std::move(y_)), markers(markers_) {}

  std::string label;
  std::vector<double> x;
  std::vector<double> y;
  bool markers = false;  ///< draw points (observations) instead of a line
  bool hollow = false;   ///< with markers: open circles (e.g. censored samples, drawn at their limit)
  /// A reference line (identity, zero) or a smoother: grey and dashed, or the colour below.
  bool reference = false;
  /// An explicit colour ("#rrggbb"); empty: the series' place in the palette.
  std::string colour;
  /// A band (a VPC's simulated interval): the region between y and upper at each x, filled
  /// translucent in the series' colour, without markers or outline. Empty: not a band.
  std::vector<double> upper;
  /// A line drawn dashed in its own colour (a VPC's observed outer percentiles).
  bool dashed = false;
};

struct PlotOptions {
  std::string title;
  std::string x_label = "time";
  std::string y_label = "concentration";
  bool log_x = false;  ///< logarithmic x axis; non-positive values are left out
  bool log_y = false;  ///< logarithmic y axis; non-positive values are left out
  bool legend = true;  ///< a legend at the right (panels in a grid leave it out)
  int width = 820;
  int height = 520;
};

/// An SVG document with one line or point series per entry. Axes are padded so that no marker
/// is cut at the frame; logarithmic axes have ticks at 1, 2 and 5 times powers of ten (decades
/// only beyond three decades).
std::string RenderSvg(const std::vector<PlotSeries>& series, const PlotOptions& options);

/// Panels stacked from top to bottom in one SVG document, panel k being RenderSvg(panels[k],
/// options[k]): the outputs of one simulation on a shared time axis (pksim's --plot of a model with
/// several outputs). Throws std::invalid_argument unless there is one PlotOptions per panel.
std::string RenderPanelsSvg(const std::vector<std::vector<PlotSeries>>& panels, const std::vector<PlotOptions>& options);

/// A line of at most `max_points` points (at least 4) that draws as the original does at widths
/// below max_points/2 pixels: the points split into max_points/2 consecutive runs, each run's
/// lowest and highest y kept in their order, so a peak (Cmax) and a trough stay exact. A line with
/// no more points than that is returned as it is.
PlotSeries DecimateLine(const PlotSeries& line, int max_points);

/// The colour of palette entry k: 20 distinct colours, then they repeat.
const char* PaletteColour(int k);

/// Cleveland's LOWESS smoother (R's lowess(x, y, f, iter)): a local linear fit with tricube
/// weights over the fraction `f` of the points nearest each x, then `iterations` robustness
/// passes with bisquare weights. Returns the points sorted by x with the smoothed y; non-finite
/// points are left out. Empty (x and y) for fewer than 3 points or a single x.
PlotSeries Lowess(const std::vector<double>& x, const std::vector<double>& y, double f = 2.0 / 3.0,
                  int iterations = 3);

/// A goodness-of-fit plot: `points` (observations, drawn as markers in `points.colour`), a
/// `reference` line (identity or zero), any `extra` marker series (e.g. censored samples), and
/// R's lowess() of the points as the axes show them (on log axes, of the logarithms), in red.
std::string RenderGofSvg(const PlotSeries& points, const PlotSeries& reference, const PlotOptions& options,
                         const std::vector<PlotSeries>& extra = {});

}  // namespace pk

#endif  // PK_PLOT_H_
