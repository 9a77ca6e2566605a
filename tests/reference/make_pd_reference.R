# Reference predictions of the PD and other new model files (models/*.pkm) by R's deSolve
# (lsoda at rtol = atol = 1e-12), written from the models' equations, not from libpk's code.
# Regimen: a bolus of 100 into the dose compartment at t = 0, then an infusion of 50 at rate 25
# into it from t = 12 to 14. Run: Rscript tests/reference/make_pd_reference.R (from the root);
# writes tests/reference/pd_reference.csv (MODEL, TIME, DVID, VALUE).
library(deSolve)

times <- c(0.5, 1, 2, 4, 8, 12.5, 13, 14, 16, 24, 36)

hill <- function(c, emax, ec50, h) emax * max(c, 0)^h / (ec50^h + max(c, 0)^h)

models <- list(
  idr1 = list(p = c(CL = 3, V = 30, KOUT = 0.2, R0 = 100, IMAX = 0.8, IC50 = 2), n = 2, dose = 1,
    rhs = function(x, p) { c <- x[1] / p[["V"]]; r <- p[["R0"]] + x[2]; kin <- p[["KOUT"]] * p[["R0"]]
      i <- p[["IMAX"]] * c / (p[["IC50"]] + c)
      c(-p[["CL"]] * c, kin * (1 - i) - p[["KOUT"]] * r) },
    out = function(x, p) c(x[1] / p[["V"]], p[["R0"]] + x[2])),
  idr2 = list(p = c(CL = 3, V = 30, KOUT = 0.2, R0 = 100, IMAX = 0.8, IC50 = 2), n = 2, dose = 1,
    rhs = function(x, p) { c <- x[1] / p[["V"]]; r <- p[["R0"]] + x[2]; kin <- p[["KOUT"]] * p[["R0"]]
      i <- p[["IMAX"]] * c / (p[["IC50"]] + c)
      c(-p[["CL"]] * c, kin - p[["KOUT"]] * (1 - i) * r) },
    out = function(x, p) c(x[1] / p[["V"]], p[["R0"]] + x[2])),
  idr3 = list(p = c(CL = 3, V = 30, KOUT = 0.2, R0 = 100, EMAX = 2, EC50 = 2), n = 2, dose = 1,
    rhs = function(x, p) { c <- x[1] / p[["V"]]; r <- p[["R0"]] + x[2]; kin <- p[["KOUT"]] * p[["R0"]]
      s <- p[["EMAX"]] * c / (p[["EC50"]] + c)
      c(-p[["CL"]] * c, kin * (1 + s) - p[["KOUT"]] * r) },
    out = function(x, p) c(x[1] / p[["V"]], p[["R0"]] + x[2])),
  idr4 = list(p = c(CL = 3, V = 30, KOUT = 0.2, R0 = 100, EMAX = 2, EC50 = 2), n = 2, dose = 1,
    rhs = function(x, p) { c <- x[1] / p[["V"]]; r <- p[["R0"]] + x[2]; kin <- p[["KOUT"]] * p[["R0"]]
      s <- p[["EMAX"]] * c / (p[["EC50"]] + c)
      c(-p[["CL"]] * c, kin - p[["KOUT"]] * (1 + s) * r) },
    out = function(x, p) c(x[1] / p[["V"]], p[["R0"]] + x[2])),
  turnover = list(p = c(KIN = 10, KOUT = 0.5, V = 20), n = 1, dose = 1,
    rhs = function(x, p) -p[["KOUT"]] * x[1],
    out = function(x, p) (p[["KIN"]] / p[["KOUT"]] + x[1]) / p[["V"]]),
  parent_metabolite = list(p = c(KA = 1.5, CL = 3, V = 30, CLM = 6, VM = 50), n = 3, dose = 1,
    rhs = function(x, p) { c <- x[2] / p[["V"]]; cm <- x[3] / p[["VM"]]
      c(-p[["KA"]] * x[1], p[["KA"]] * x[1] - p[["CL"]] * c, p[["CL"]] * c - p[["CLM"]] * cm) },
    out = function(x, p) c(x[2] / p[["V"]], x[3] / p[["VM"]])),
  emax_baseline = list(p = c(CL = 3, V = 30, E0 = 10, EMAX = 50, EC50 = 1, HILL = 1.5), n = 1, dose = 1,
    rhs = function(x, p) -p[["CL"]] * x[1] / p[["V"]],
    out = function(x, p) { c <- x[1] / p[["V"]]; c(c, p[["E0"]] + hill(c, p[["EMAX"]], p[["EC50"]], p[["HILL"]])) }),
  effect_linear = list(p = c(CL = 3, V = 30, KE0 = 0.5, E0 = 10, SLOPE = 4), n = 2, dose = 1,
    rhs = function(x, p) { c <- x[1] / p[["V"]]; c(-p[["CL"]] * c, p[["KE0"]] * (c - x[2])) },
    out = function(x, p) c(x[1] / p[["V"]], p[["E0"]] + p[["SLOPE"]] * x[2])),
  `1cmt_iv_parallel` = list(p = c(CL = 1, VMAX = 20, KM = 2, V = 30), n = 1, dose = 1,
    rhs = function(x, p) { c <- x[1] / p[["V"]]; -p[["CL"]] * c - p[["VMAX"]] * c / (p[["KM"]] + c) },
    out = function(x, p) x[1] / p[["V"]])
)

# x at `times` from x0 at t0 under a constant input rate into the dose compartment.
advance <- function(m, x0, t0, t, rate) {
  u <- numeric(m$n)
  u[m$dose] <- rate
  f <- function(tt, x, parms) list(m$rhs(x, m$p) + u)
  out <- lsoda(x0, c(t0, t), f, NULL, rtol = 1e-12, atol = 1e-12)
  out[, -1, drop = FALSE]
}

rows <- list()
for (name in names(models)) {
  m <- models[[name]]
  bolus <- numeric(m$n); bolus[m$dose] <- 100
  # Piecewise: [0, 12) no input, [12, 14) rate 25, [14, 36] none; samples in each piece.
  pieces <- list(c(0, 12, 0), c(12, 14, 25), c(14, 36, 0))
  x <- bolus
  for (pc in pieces) {
    inside <- times[times > pc[1] & times <= pc[2]]
    sol <- advance(m, x, pc[1], c(inside, pc[2]), pc[3])
    for (k in seq_along(inside)) {
      y <- m$out(as.numeric(sol[k + 1, ]), m$p)
      for (j in seq_along(y)) rows[[length(rows) + 1]] <- data.frame(MODEL = name, TIME = inside[k], DVID = j, VALUE = y[j])
    }
    x <- as.numeric(sol[nrow(sol), ])
  }
}
out <- do.call(rbind, rows)
write.csv(out, "tests/reference/pd_reference.csv", row.names = FALSE, quote = FALSE)
cat(sprintf("%d rows\n", nrow(out)))
