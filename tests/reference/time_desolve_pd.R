# The R baseline of issue 27 for the other two ODE models of pkbench section 5: R's nls fitting
#   1cmt_oral_mm  (first-order absorption, Michaelis-Menten elimination) to datasets/theophylline.csv
#   1cmt_iv_emax  (one compartment, effect compartment, sigmoid Emax; both outputs, unweighted)
#                 to datasets/emax_synthetic.csv
# by least squares, as pkbench fits them, each model solved by deSolve's lsoda with its
# derivatives in compiled C (built here with R CMD SHLIB), integrated piecewise between dose
# events, rtol 1e-10 and atol 1e-12 (see time_desolve.R for why not 1e-8). Starting values are
# libpk's data-driven ones where the model declares them, otherwise the catalogue's defaults, all
# written below. Times are the median of 5 runs of all fits; compare with pkbench section 5 (one
# thread), and the objectives (RSS/2) with pkfit's. Run from the repository root:
#   Rscript tests/reference/time_desolve_pd.R
suppressMessages(library(deSolve))
work <- tempfile("pd_desolve")
dir.create(work)
c_file <- file.path(work, "pd.c")
writeLines(c(
  "#include <R.h>",
  "#include <math.h>",
  "static double parms[8];",
  "void oral_init(void (*odeparms)(int *, double *)) { int n = 4; odeparms(&n, parms); }",
  "/* KA, VMAX, KM, V; states DEPOT, CENTRAL */",
  "void oral_derivs(int *neq, double *t, double *y, double *ydot, double *yout, int *ip) {",
  "  double c = y[1] / parms[3];",
  "  ydot[0] = -parms[0] * y[0];",
  "  ydot[1] = parms[0] * y[0] - parms[1] * c / (parms[2] + c);",
  "}",
  "void emax_init(void (*odeparms)(int *, double *)) { int n = 4; odeparms(&n, parms); }",
  "/* CL, V, KE0, RATE; states CENTRAL, EFFECT */",
  "void emax_derivs(int *neq, double *t, double *y, double *ydot, double *yout, int *ip) {",
  "  double c = y[0] / parms[1];",
  "  ydot[0] = -parms[0] * c + parms[3];",
  "  ydot[1] = parms[2] * (c - y[1]);",
  "}"), c_file)
invisible(system2(file.path(R.home("bin"), "R"), c("CMD", "SHLIB", "-o", file.path(work, "pd.so"), c_file),
                  stdout = FALSE, stderr = FALSE))
dyn.load(file.path(work, "pd.so"))

# The amounts at `times` (sorted, with repeats) from doses (bolus, or infusion with RATE > 0).
amounts <- function(y0, doses, times, derivs, init, parms_at) {
  ends <- with(doses[doses$RATE > 0, ], TIME + AMT / RATE)
  grid <- sort(unique(c(doses$TIME, ends, times)))
  y <- y0; t <- min(grid); out <- matrix(NA_real_, length(times), length(y0))
  for (tk in grid) {
    if (tk > t) {
      sol <- ode(y = y, times = c(t, tk), func = derivs, initfunc = init, dllname = "pd",
                 parms = parms_at(t), method = "lsoda", rtol = 1e-10, atol = 1e-12)
      y <- unname(sol[2, -1]); t <- tk
    }
    b <- doses[doses$TIME == tk & doses$RATE == 0, ]
    if (nrow(b)) y[b$CMT] <- y[b$CMT] + b$AMT
    out[times == tk, ] <- rep(y, each = sum(times == tk))
  }
  out
}

oral_mm <- function(KA, VMAX, KM, V, doses, times) {
  a <- amounts(c(0, 0), doses, times, "oral_derivs", "oral_init", function(t) c(KA, VMAX, KM, V))
  a[, 2] / V
}
rate_at <- function(doses, t) {
  inf <- doses[doses$RATE > 0, ]
  sum(inf$RATE[t >= inf$TIME & t < inf$TIME + inf$AMT / inf$RATE])
}
iv_emax <- function(CL, V, KE0, E0, EMAX, EC50, HILL, doses, times, dvid) {
  a <- amounts(c(0, 0), doses, times, "emax_derivs", "emax_init", function(t) c(CL, V, KE0, rate_at(doses, t)))
  ce <- pmax(a[, 2], 0)
  ifelse(dvid == 1, a[, 1] / V, E0 + EMAX * ce^HILL / (EC50^HILL + ce^HILL))
}

theo <- read.csv("datasets/theophylline.csv", na.strings = ".")
emax <- read.csv("datasets/emax_synthetic.csv", na.strings = ".")
emax$CMT <- 1

fit_oral <- function() {
  lapply(unique(theo$ID), function(id) {
    s <- theo[theo$ID == id, ]; doses <- s[s$EVID == 1, ]; obs <- s[s$EVID == 0 & s$MDV == 0, ]
    tryCatch(nls(DV ~ oral_mm(KA, VMAX, KM, V, doses, TIME), data = obs,
                 start = list(KA = 1.5, VMAX = 20, KM = 2, V = 30),
                 control = nls.control(maxiter = 200, warnOnly = TRUE)), error = function(e) NULL)
  })
}
fit_emax <- function() {
  lapply(unique(emax$ID), function(id) {
    s <- emax[emax$ID == id, ]; doses <- s[s$EVID == 1, ]; obs <- s[s$EVID == 0, ]
    tryCatch(nls(DV ~ iv_emax(CL, V, KE0, E0, EMAX, EC50, HILL, doses, TIME, DVID), data = obs,
                 start = list(CL = 3, V = 30, KE0 = 0.5, E0 = 10, EMAX = 50, EC50 = 1, HILL = 1.5),
                 control = nls.control(maxiter = 200, warnOnly = TRUE)), error = function(e) NULL)
  })
}

report <- function(name, data_name, fit_all) {
  fits <- fit_all()
  elapsed <- replicate(5, system.time(fit_all())[["elapsed"]])
  ok <- sum(vapply(fits, function(f) !is.null(f) && f$convInfo$isConv, logical(1)))
  objective <- vapply(fits, function(f) if (is.null(f)) NA_real_ else deviance(f) / 2, numeric(1))
  cat(sprintf("R nls + deSolve (lsoda, compiled C), %s on %s: %.1f ms for %d fits (%.2f ms a fit), %d converged\n",
              name, data_name, 1000 * median(elapsed), length(fits), 1000 * median(elapsed) / length(fits), ok))
  cat("  objectives (RSS/2):", paste(sprintf("%.6g", objective), collapse = " "), "\n")
}
report("1cmt_oral_mm", "theophylline.csv", fit_oral)
report("1cmt_iv_emax", "emax_synthetic.csv", fit_emax)
