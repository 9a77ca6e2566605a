# Reference Laplace objectives with censored samples (Beal's M3), computed by R
# alone (base R + stats), independently of libpk. Run from the repository root:
#   Rscript tests/reference/make_population_m3_reference.R
# It writes tests/reference/population_m3_reference.csv (case,ID,ofv_i; ID "all"
# for the sum) and prints its self-checks.
#
# Conventions (as NONMEM's METHOD=COND LAPLACIAN with F_FLAG=1 for the censored
# rows; -2 log L without the n*log(2*pi) constant of the uncensored rows):
#   P_i = theta_P * exp(eta_P), eta_i ~ N(0, Omega)
#   l_i(eta) = sum_{values}   [ (y - f)^2 / V(f) + log V(f) ]
#            + sum_{censored} -2 log Phi(s (y - f) / sqrt(V(f)))      (y = the limit, s = CENS)
#            + eta' Omega^-1 eta
#   eta_hat = argmin l_i;  OFV_i = l_i(eta_hat) + log|Omega| + log|1/2 d2 l_i/deta2|
# d2 l_i/deta2 is exact: f's first and second derivatives from stats::deriv, the
# terms' derivatives in f written out below.
#
# Data: datasets/theophylline_blq.csv (theophylline with the samples below 2 mg/L
# censored: CENS=1, DV=2), 1cmt_oral, one oral dose into the depot;
# theta KA = 1.5, CL = 2.8, V = 32; Omega = diag(0.4, 0.07, 0.02).
#   blq_add   additive a = 0.7
#   blq_comb  combined a = 0.3, b = 0.1 (V depends on f: interaction)

options(digits = 17)
d <- read.csv("datasets/theophylline_blq.csv")

oral <- deriv(
  ~ D * exp(lka) / (exp(lv) * (exp(lka) - exp(lcl - lv))) *
    (exp(-exp(lcl - lv) * tau) - exp(-exp(lka) * tau)),
  c("lka", "lcl", "lv"), function.arg = c("lka", "lcl", "lv", "D", "tau"), hessian = TRUE)

theta <- c(1.5, 2.8, 32)
Omega <- diag(c(0.4, 0.07, 0.02))
Oinv <- solve(Omega)

# One subject: observations (values and limits), their CENS, and the (obs, dose) pairs.
subject_data <- function(rows) {
  obs <- which(rows$EVID == 0 & rows$MDV == 0)
  doses <- which(rows$EVID == 1)
  pairs <- NULL
  for (k in seq_along(obs)) for (j in doses) {
    if (j < obs[k]) pairs <- rbind(pairs, data.frame(obs = k, D = rows$AMT[j], tau = rows$TIME[obs[k]] - rows$TIME[j]))
  }
  list(y = rows$DV[obs], s = rows$CENS[obs], n = length(obs), pairs = pairs)
}

predict <- function(eta, subj) {
  lp <- log(theta) + eta
  v <- oral(lp[1], lp[2], lp[3], subj$pairs$D, subj$pairs$tau)
  f <- as.vector(rowsum(as.vector(v), subj$pairs$obs, reorder = TRUE))
  G <- rowsum(attr(v, "gradient"), subj$pairs$obs, reorder = TRUE)
  H <- array(rowsum(matrix(attr(v, "hessian"), nrow(subj$pairs)), subj$pairs$obs, reorder = TRUE), c(subj$n, 3, 3))
  list(f = f, G = unname(G), H = H)
}

resvar <- function(f, cs) {
  if (cs$error == "additive") return(list(V = rep(cs$a^2, length(f)), V1 = 0 * f, V2 = 0 * f))
  list(V = cs$a^2 + (cs$b * f)^2, V1 = 2 * cs$b^2 * f, V2 = rep(2 * cs$b^2, length(f)))
}

# Each sample's term c(f) with dc/df and d2c/df2.
terms <- function(y, s, f, cs) {
  rv <- resvar(f, cs); V <- rv$V; V1 <- rv$V1; V2 <- rv$V2
  r <- y - f
  c0 <- r^2 / V + log(V)
  c1 <- -2 * r / V - r^2 * V1 / V^2 + V1 / V
  c2 <- 2 / V + 4 * r * V1 / V^2 + 2 * r^2 * V1^2 / V^3 - r^2 * V2 / V^2 + V2 / V - V1^2 / V^2
  cens <- s != 0
  if (any(cens)) {
    sc <- s[cens]; Vc <- V[cens]; V1c <- V1[cens]; V2c <- V2[cens]; rc <- r[cens]
    z <- sc * rc / sqrt(Vc)
    z1 <- -sc / sqrt(Vc) - z * V1c / (2 * Vc)                    # dz/df
    z2 <- sc / 2 * Vc^-1.5 * V1c -                                # d2z/df2
      (z1 * V1c / (2 * Vc) + z * V2c / (2 * Vc) - z * V1c^2 / (2 * Vc^2))
    logcdf <- pnorm(z, log.p = TRUE)
    m <- exp(dnorm(z, log = TRUE) - logcdf)                       # phi/Phi
    c0[cens] <- -2 * logcdf
    c1[cens] <- -2 * m * z1
    c2[cens] <- 2 * m * (z + m) * z1^2 - 2 * m * z2
  }
  list(c0 = c0, c1 = c1, c2 = c2)
}

cond <- function(eta, subj, cs) {
  p <- predict(eta, subj)
  t <- terms(subj$y, subj$s, p$f, cs)
  value <- sum(t$c0) + drop(t(eta) %*% Oinv %*% eta)
  grad <- drop(crossprod(p$G, t$c1)) + 2 * drop(Oinv %*% eta)
  H <- crossprod(p$G * t$c2, p$G) + 2 * Oinv
  for (j in seq_len(subj$n)) H <- H + t$c1[j] * p$H[j, , ]
  list(value = value, grad = grad, H = H)
}

# BFGS (optim, analytic gradient) near the mode, then Newton with the exact Hessian to rounding.
mode_of <- function(subj, cs) {
  eta <- optim(rep(0, 3), function(e) cond(e, subj, cs)$value, function(e) cond(e, subj, cs)$grad,
               method = "BFGS", control = list(reltol = 1e-14, maxit = 1000))$par
  for (it in 1:50) {
    c <- cond(eta, subj, cs)
    step <- -solve(c$H, c$grad)
    eta <- eta + step
    if (max(abs(step)) < 1e-13) break
  }
  eta
}

cases <- list(blq_add = list(error = "additive", a = 0.7),
              blq_comb = list(error = "combined", a = 0.3, b = 0.1))
out <- NULL
for (name in names(cases)) {
  cs <- cases[[name]]
  total <- 0
  for (id in unique(d$ID)) {
    subj <- subject_data(d[d$ID == id, ])
    eta <- mode_of(subj, cs)
    c <- cond(eta, subj, cs)
    # Self-checks: the gradient vanishes at the mode; the exact gradient and Hessian
    # agree with central differences.
    h <- 1e-5
    fd <- sapply(1:3, function(k) { e <- diag(3)[, k] * h
      (cond(eta + e, subj, cs)$value - cond(eta - e, subj, cs)$value) / (2 * h) })
    fdh <- sapply(1:3, function(k) { e <- diag(3)[, k] * h
      (cond(eta + e, subj, cs)$grad - cond(eta - e, subj, cs)$grad) / (2 * h) })
    stopifnot(max(abs(c$grad)) < 1e-10, max(abs(fd - c$grad)) < 1e-6,
              max(abs(fdh - c$H)) < 1e-5 * max(abs(c$H)))
    ofv <- c$value + determinant(Omega)$modulus[1] + determinant(c$H / 2)$modulus[1]
    out <- rbind(out, data.frame(case = name, ID = as.character(id), ofv_i = ofv))
    total <- total + ofv
  }
  out <- rbind(out, data.frame(case = name, ID = "all", ofv_i = total))
  cat(name, ": OFV", format(total, digits = 15), "with", sum(d$CENS == 1 & d$EVID == 0), "censored samples\n")
}
write.csv(out, "tests/reference/population_m3_reference.csv", row.names = FALSE, quote = FALSE)
