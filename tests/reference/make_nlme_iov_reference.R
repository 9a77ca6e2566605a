# Reference population fit with inter-occasion variability (IOV) by R's nlme
# (method = "ML"), for comparison with libpk. Independent of libpk.
# Run from the repository root (needs nlme, Debian: r-cran-nlme):
#   Rscript tests/reference/make_nlme_iov_reference.R
# It writes
#   datasets/iov_synthetic.csv                ID,TIME,AMT,EVID,MDV,DV,OCC (simulated)
#   tests/reference/nlme_iov_reference.csv    quantity,value  (sprintf %.17g)
# Data: 40 subjects x 3 occasions; occasion k has a 100 mg dose at t0 = (k-1)*168
# (DV '.') and observations at t0 + 0.5, 1, 2, 4, 8, 12, 24: N = 840. Simulated
# with set.seed(20261127), drawn in this order: eta_CL[1:40], eta_V[1:40],
# kappa[40 x 3] (subject-major), then eps for the observation rows in file order.
# Model (one compartment, first-order absorption; each occasion starts from zero amounts, so the
# dataset's later occasions open with NONMEM's EVID 4, a reset and dose), t = time after the
# occasion's dose, D = 100:
#   C(t) = D ka / (V (ka - ke)) (exp(-ke t) - exp(-ka t)),  ke = CL/V
#   ka = exp(lKa), CL_ik = exp(lCl + eta_CL_i + kappa_ik), V_i = exp(lV + eta_V_i)
#   DV = C + eps, eps ~ N(0, sigma^2)   (additive)
#   truth: ka 1.5, CL 3, V 30, Var(eta_CL) 0.09, Var(eta_V) 0.04,
#          Var(kappa) 0.03, sigma 0.15
# Random effects: between-subject on CL and V (diagonal), between-occasion on CL
# with ONE variance shared by all occasions (NONMEM: $OMEGA BLOCK(1) / BLOCK(1)
# SAME per occasion). In nlme: groups = ~ID/OCC (OCC nested in ID),
#   random = list(ID = pdDiag(lCl + lV ~ 1), OCC = pdDiag(lCl ~ 1)).
# The fit uses the CSV as written (DV rounded to 6 significant digits); control
# below (tolerance 1e-8, pnlsTol 1e-7). Checked outside this script: nlme's
# -2 logLik equals the FOCE (linearised) -2 log L recomputed at its estimates to
# ~3e-8, as make_nlme_reference.R checks for theophylline.
# CSV quantities: KA, CL, V (exp of fixed effects); OMEGA_CL, OMEGA_V (ID-level
# variances); OMEGA_IOV (OCC-level variance of lCl); SIGMA_ADD (residual SD);
# ofv = -2 logLik - n log(2 pi) (as make_nlme_reference.R: NONMEM's convention,
# dropping the constant); loglik (nlme's ML logLik); n (observations).
suppressPackageStartupMessages(library(nlme))
cat(sprintf("%s, nlme %s\n", R.version.string, packageVersion("nlme")))

## Simulate ------------------------------------------------------------------
set.seed(20261127)
nid <- 40; nocc <- 3; D <- 100; tobs <- c(0.5, 1, 2, 4, 8, 12, 24)
eta_cl <- rnorm(nid, 0, sqrt(0.09)); eta_v <- rnorm(nid, 0, sqrt(0.04))
kappa <- matrix(rnorm(nid * nocc, 0, sqrt(0.03)), nid, nocc, byrow = TRUE)
conc <- function(tad, ka, cl, v) {
  ke <- cl / v; D * ka / (v * (ka - ke)) * (exp(-ke * tad) - exp(-ka * tad))
}
rows <- list()
for (i in 1:nid) for (k in 1:nocc) {
  t0 <- (k - 1) * 168
  cc <- conc(tobs, 1.5, 3 * exp(eta_cl[i] + kappa[i, k]), 30 * exp(eta_v[i]))
  rows[[length(rows) + 1]] <- data.frame(ID = i, TIME = c(t0, t0 + tobs),
    AMT = c(D, rep(0, 7)), EVID = c(if (k == 1) 1 else 4, rep(0, 7)), MDV = c(1, rep(0, 7)),
    C = c(NA, cc), OCC = k)
}
sim <- do.call(rbind, rows)
isobs <- sim$EVID == 0  # (a dose is EVID 1 or 4)
sim$C[isobs] <- sim$C[isobs] + rnorm(sum(isobs), 0, 0.15)
out <- data.frame(ID = sim$ID, TIME = as.character(sim$TIME), AMT = sim$AMT,
  EVID = sim$EVID, MDV = sim$MDV,
  DV = ifelse(isobs, as.character(signif(sim$C, 6)), "."), OCC = sim$OCC)
write.csv(out, "datasets/iov_synthetic.csv", row.names = FALSE, quote = FALSE)

## Fit -----------------------------------------------------------------------
raw <- read.csv("datasets/iov_synthetic.csv", na.strings = ".")
dose_t <- raw$TIME[raw$EVID != 0][match(paste(raw$ID, raw$OCC),
                                       paste(raw$ID, raw$OCC)[raw$EVID != 0])]
obs <- data.frame(ID = factor(raw$ID), OCC = factor(raw$OCC),
                  TAD = raw$TIME - dose_t, DV = raw$DV)[raw$EVID == 0, ]
n <- nrow(obs); stopifnot(n == nid * nocc * 7, !anyNA(obs$DV))
pk1 <- deriv(~ 100 * exp(lKa) / (exp(lV) * (exp(lKa) - exp(lCl - lV))) *
               (exp(-exp(lCl - lV) * TAD) - exp(-exp(lKa) * TAD)),
             c("lKa", "lCl", "lV"), function.arg = c("TAD", "lKa", "lCl", "lV"))
# pnlsTol = 1e-8 stops with "step halving factor reduced below minimum in PNLS
# step" (RSS already at rounding level); 1e-7 gives the same optimum as 3e-8.
ctrl <- nlmeControl(maxIter = 200, pnlsMaxIter = 50, msMaxIter = 200,
                    tolerance = 1e-8, pnlsTol = 1e-7, msTol = 1e-10)
fit <- nlme(DV ~ pk1(TAD, lKa, lCl, lV), data = obs,
            fixed = lKa + lCl + lV ~ 1,
            random = list(ID = pdDiag(lCl + lV ~ 1), OCC = pdDiag(lCl ~ 1)),
            groups = ~ ID/OCC, start = c(lKa = log(1.2), lCl = log(2.5), lV = log(35)),
            method = "ML", control = ctrl)   # nlme stops with an error if not converged
cat(sprintf("converged: %d outer iterations\n", fit$numIter))
print(VarCorr(fit))
s2 <- fit$sigma^2; re <- fit$modelStruct$reStruct
om_id <- diag(as.matrix(re$ID)) * s2; om_occ <- diag(as.matrix(re$OCC)) * s2
ll <- as.numeric(logLik(fit)); b <- fixef(fit)
q <- c(KA = exp(b[["lKa"]]), CL = exp(b[["lCl"]]), V = exp(b[["lV"]]),
       OMEGA_CL = om_id[["lCl"]], OMEGA_V = om_id[["lV"]], OMEGA_IOV = om_occ[["lCl"]],
       SIGMA_ADD = fit$sigma, ofv = -2 * ll - n * log(2 * pi), loglik = ll, n = n)
lines <- c("quantity,value", sprintf("%s,%s", names(q), sprintf("%.17g", q)))
writeLines(lines, "tests/reference/nlme_iov_reference.csv")
cat(lines, sep = "\n")
