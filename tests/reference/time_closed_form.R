# The R baseline of pksim's throughput (issue 28; docs/performance.md section 6): the vectorised closed
# form of 2cmt_oral (ADVAN4 TRANS4, first-order absorption, F = 1) for every subject and output time of a
# NONMEM-style dose dataset (AMT, ADDL, II; KA, CL, V2, Q, V3 as columns), by superposition of the doses,
# timed in-process (median of 5). With a pksim output it also reports the largest relative difference of
# pksim's CP from the closed form. Run by benchmarks/pksim_vs_r.sh:
#   Rscript tests/reference/time_closed_form.R DOSES.csv FIRST LAST STEP [PKSIM_OUTPUT.csv]
args <- commandArgs(trailingOnly = TRUE)
doses <- read.csv(args[1])
times <- seq(as.numeric(args[2]), as.numeric(args[4]), by = as.numeric(args[3]))

closed_form <- function() {
  k <- doses$CL / doses$V2; k12 <- doses$Q / doses$V2; k21 <- doses$Q / doses$V3; ka <- doses$KA
  s <- k + k12 + k21
  root <- sqrt(s^2 - 4 * k * k21)
  alpha <- (s + root) / 2; beta <- (s - root) / 2
  # Central amount per unit dose, tau after it (the three-exponential oral solution).
  ca <- ka * (k21 - alpha) / ((ka - alpha) * (beta - alpha))
  cb <- ka * (k21 - beta) / ((ka - beta) * (alpha - beta))
  ck <- ka * (k21 - ka) / ((alpha - ka) * (beta - ka))
  n <- nrow(doses); m <- length(times)
  conc <- matrix(0, n, m)
  for (j in 0:max(doses$ADDL)) {   # each dose of the ADDL train, for every subject at once
    tau <- outer(doses$TIME + j * doses$II, times, function(d, t) t - d)
    given <- j <= doses$ADDL & tau >= 0
    amount <- ca * exp(-alpha * tau) + cb * exp(-beta * tau) + ck * exp(-ka * tau)
    conc <- conc + ifelse(given, doses$AMT * amount, 0)
  }
  conc / doses$V2
}

conc <- closed_form()
elapsed <- replicate(5, system.time(closed_form())[["elapsed"]])
cat(sprintf("R closed form, %d subjects x %d times: %.1f ms (median of 5, in-process)\n",
            nrow(doses), length(times), 1000 * median(elapsed)))
if (length(args) >= 5) {
  sim <- read.csv(args[5])
  sim <- sim[sim$EVID == 2, ]
  ref <- as.vector(t(conc))   # subject by subject, times ascending: pksim's row order
  stopifnot(nrow(sim) == length(ref))
  cat(sprintf("pksim CP against the closed form: largest relative difference %.1e\n",
              max(abs(sim$CP - ref) / pmax(abs(ref), 1e-300))))
}
