# Synthetic datasets for the nonlinear models, simulated by libpk's own pksim
# (CVODES, rtol 1e-12) and given measurement noise here with a fixed seed.
# Run from the repository root after building (build/apps/pksim):
#
#   Rscript datasets/make_synthetic.R
#
# mm_synthetic.csv    1cmt_iv_mm: 200 mg IV bolus at 0 h, then 300 mg infused
#                     over 6 h from 8 h; 16 samples to 32 h; 6 subjects; 5 %
#                     proportional noise. Truth per subject in mm_synthetic_truth.csv.
# emax_synthetic.csv  1cmt_iv_emax: 50, 100, 200 and 400 mg infused over 0.5 h
#                     at 0, 12, 24 and 36 h; 4 subjects; concentrations (DVID 1,
#                     8 % proportional noise) and effects (DVID 2, additive SD 2);
#                     W = 1/noise variance for weighted least squares.
# effect_linear_pop.csv  effect_linear.pkm: 100 mg IV bolus; 40 subjects with
#                     log-normal CL (ω² 0.09) and normal E0 (ω² 1); CP (DVID 1,
#                     10 % proportional noise) and E (DVID 2, additive SD 0.5) at
#                     0.5–24 h. Fit with models/effect_linear_pop.pkm (pkpop).
set.seed(20261121)
pksim <- "build/apps/pksim"

simulate <- function(model, data, params) {
  infile <- tempfile(fileext = ".csv")
  outfile <- tempfile(fileext = ".csv")
  write.csv(data, infile, row.names = FALSE, quote = FALSE, na = ".")
  args <- c("--model", model, "--data", infile, "--propagator", "ode", "--rtol", "1e-12", "--atol", "1e-14",
            "--out", outfile, as.vector(rbind("--param", paste0(names(params), "=", params))))
  status <- system2(pksim, args)
  if (status != 0) stop("pksim failed")
  read.csv(outfile)
}

## Michaelis-Menten
times <- c(0.25, 0.5, 1, 2, 3, 4, 6, 8.5, 9, 10, 12, 14, 16, 20, 26, 32)
mm <- NULL
truth <- NULL
for (id in 1:6) {
  p <- c(VMAX = 30 * exp(0.2 * rnorm(1)), KM = 1.8 * exp(0.25 * rnorm(1)), V = 20 * exp(0.15 * rnorm(1)))
  rows <- rbind(data.frame(ID = id, TIME = 0, AMT = 200, RATE = 0, EVID = 1),
                data.frame(ID = id, TIME = times[times < 8], AMT = 0, RATE = 0, EVID = 0),
                data.frame(ID = id, TIME = 8, AMT = 300, RATE = 50, EVID = 1),
                data.frame(ID = id, TIME = times[times > 8], AMT = 0, RATE = 0, EVID = 0))
  sim <- simulate("1cmt_iv_mm", rows, p)
  rows$DV <- NA
  obs <- rows$EVID == 0
  rows$DV[obs] <- signif(sim$CP * exp(0.05 * rnorm(nrow(sim))), 5)
  mm <- rbind(mm, rows)
  truth <- rbind(truth, data.frame(ID = id, VMAX = p[["VMAX"]], KM = p[["KM"]], V = p[["V"]]))
}
write.csv(mm, "datasets/mm_synthetic.csv", row.names = FALSE, quote = FALSE, na = ".")
write.csv(signif(truth, 6), "datasets/mm_synthetic_truth.csv", row.names = FALSE, quote = FALSE)

## Effect compartment, sigmoid Emax
# Each subject gets escalating doses, so that its concentrations span the whole
# concentration-effect curve; W = 1/variance of the noise (use --weighting column:W).
doses <- data.frame(TIME = c(0, 12, 24, 36), AMT = c(50, 100, 200, 400))
cp_times <- c(0.25, 0.5, 1, 2, 4, 8)
e_times <- c(0.25, 0.5, 1, 1.5, 2, 3, 4, 6, 8, 11.9)
emax <- NULL
for (id in 1:4) {
  p <- c(CL = 4 * exp(0.15 * rnorm(1)), V = 25 * exp(0.1 * rnorm(1)), KE0 = 0.7 * exp(0.2 * rnorm(1)), E0 = 8,
         EMAX = 60 * exp(0.1 * rnorm(1)), EC50 = 1.2 * exp(0.2 * rnorm(1)), HILL = 2.2)
  obs <- NULL
  for (k in seq_len(nrow(doses))) {
    obs <- rbind(obs, data.frame(TIME = doses$TIME[k] + cp_times, DVID = 1),
                 data.frame(TIME = doses$TIME[k] + e_times, DVID = 2))
  }
  obs <- obs[order(obs$TIME, obs$DVID), ]
  rows <- rbind(data.frame(ID = id, TIME = doses$TIME, AMT = doses$AMT, RATE = 2 * doses$AMT, EVID = 1, DVID = NA),
                data.frame(ID = id, TIME = obs$TIME, AMT = 0, RATE = 0, EVID = 0, DVID = obs$DVID))
  rows <- rows[order(rows$TIME, -rows$EVID), ]
  sim <- simulate("1cmt_iv_emax", rows, p)
  rows$DV <- NA
  rows$W <- NA
  o <- rows$EVID == 0
  conc <- rows$DVID[o] == 1
  y <- ifelse(conc, sim$CP * exp(0.08 * rnorm(sum(o))), sim$EFFECT + 2 * rnorm(sum(o)))
  rows$DV[o] <- signif(y, 5)
  rows$W[o] <- signif(ifelse(conc, 1 / (0.08 * sim$CP)^2, 1 / 2^2), 5)
  emax <- rbind(emax, rows)
}
write.csv(emax, "datasets/emax_synthetic.csv", row.names = FALSE, quote = FALSE, na = ".")

## Effect compartment, linear response with a baseline: a population
# 40 subjects, 100 mg IV bolus; CP (DVID 1, 10 % proportional noise) and E = E0 + SLOPE·Ce (DVID 2,
# additive SD 0.5) at each time. Between subjects: CL log-normal (ω² = 0.09), E0 normal (ω² = 1).
# Fit with models/effect_linear_pop.pkm. Its own seed: the section does not depend on those above.
set.seed(20261127)
times <- c(0.5, 1, 2, 4, 8, 12, 24)
effect <- NULL
for (id in 1:40) {
  p <- c(CL = 3 * exp(0.3 * rnorm(1)), V = 30, KE0 = 0.5, E0 = 10 + rnorm(1), SLOPE = 4)
  obs <- data.frame(TIME = rep(times, each = 2), DVID = rep(1:2, length(times)))
  rows <- rbind(data.frame(ID = id, TIME = 0, AMT = 100, EVID = 1, DVID = NA),
                data.frame(ID = id, TIME = obs$TIME, AMT = 0, EVID = 0, DVID = obs$DVID))
  sim <- simulate("models/effect_linear.pkm", rows, p)
  rows$DV <- NA
  o <- rows$EVID == 0
  conc <- rows$DVID[o] == 1
  y <- ifelse(conc, sim$CP * (1 + 0.1 * rnorm(sum(o))), sim$E + 0.5 * rnorm(sum(o)))
  rows$DV[o] <- signif(y, 5)
  effect <- rbind(effect, rows)
}
write.csv(effect, "datasets/effect_linear_pop.csv", row.names = FALSE, quote = FALSE, na = ".")
