# Reference fits by R's nls, an independent implementation, for the bundled
# datasets. Run from the repository root:
#   Rscript tests/reference/make_reference.R
# It writes tests/reference/nls_reference.csv: per subject, R's objective
# (the seed's V = RSS/2) and its estimates in libpk's parameterisation.
# Also prints the wall time of the 12 theophylline fits (docs/performance.md).
theo <- read.csv("datasets/theophylline.csv")
# Self-start values at R's default settings, then a tight refit (falling back to
# R's default tolerance where the tight one does not converge).
tight_nls <- function(formula, d) {
  st <- getInitial(formula, data = d)
  tryCatch(nls(formula, data = d, start = st, control = nls.control(maxiter = 1000, tol = 1e-9, minFactor = 1e-12)),
           error = function(e) nls(formula, data = d, start = st))
}
indo <- read.csv("datasets/indomethacin.csv")
rows <- list()

# Theophylline, one compartment with first-order absorption: SSfol(Dose, t, lKe, lKa, lCl).
elapsed <- 0
for (id in unique(theo$ID)) {
  s <- theo[theo$ID == id, ]
  dose <- s$AMT[s$EVID == 1][1]
  obs <- s[s$EVID == 0, ]
  d <- data.frame(Time = obs$TIME, conc = obs$DV, Dose = dose)
  t0 <- proc.time()[["elapsed"]]
  fit <- tight_nls(conc ~ SSfol(Dose, Time, lKe, lKa, lCl), d)
  elapsed <- elapsed + proc.time()[["elapsed"]] - t0
  cf <- coef(fit)
  rows[[length(rows) + 1]] <- data.frame(
    DATASET = "theophylline", MODEL = "1cmt_oral", ID = id, OBJECTIVE = deviance(fit) / 2,
    P1 = "KA", V1 = exp(cf[["lKa"]]), P2 = "CL", V2 = exp(cf[["lCl"]]),
    P3 = "V", V3 = exp(cf[["lCl"]] - cf[["lKe"]]), P4 = "", V4 = NA)
}
cat(sprintf("R nls (SSfol), 12 theophylline fits: %.3f s\n", elapsed))

# Indomethacin, biexponential after an IV bolus of 25 mg: SSbiexp(t, A1, lrc1, A2, lrc2),
# converted to 2cmt_iv's CL, V1, Q, V2.
for (id in unique(indo$ID)) {
  s <- indo[indo$ID == id, ]
  dose <- s$AMT[s$EVID == 1][1]
  obs <- s[s$EVID == 0, ]
  d <- data.frame(time = obs$TIME, conc = obs$DV)
  fit <- tight_nls(conc ~ SSbiexp(time, A1, lrc1, A2, lrc2), d)
  cf <- coef(fit)
  A <- cf[["A1"]]; alpha <- exp(cf[["lrc1"]]); B <- cf[["A2"]]; beta <- exp(cf[["lrc2"]])
  v1 <- dose / (A + B)
  k21 <- (A * beta + B * alpha) / (A + B)
  k10 <- alpha * beta / k21
  k12 <- alpha + beta - k21 - k10
  rows[[length(rows) + 1]] <- data.frame(
    DATASET = "indomethacin", MODEL = "2cmt_iv", ID = id, OBJECTIVE = deviance(fit) / 2,
    P1 = "CL", V1 = k10 * v1, P2 = "V1", V2 = v1, P3 = "Q", V3 = k12 * v1, P4 = "V2", V4 = k12 * v1 / k21)
}
out <- do.call(rbind, rows)
write.csv(out, "tests/reference/nls_reference.csv", row.names = FALSE)
