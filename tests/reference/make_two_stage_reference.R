# Reference two-stage population estimates for theophylline (1cmt_oral), by an
# implementation independent of libpk's. Run from the repository root:
#   Rscript tests/reference/make_two_stage_reference.R
# It writes tests/reference/two_stage_reference.csv (long format: OMEGA,
# STATISTIC, ID, PARAMETER, PARAMETER2, VALUE), read by tests/test_two_stage.cc.
#
# Stage one: each subject by nls on log KA, log CL, log V (least squares,
# uniform weights), started from SSfol's self-start, with vcov() as the
# covariance of the log estimates. Stage two: the standard two-stage statistics
# of the estimates, and the global two-stage ML estimates of mu and Omega,
# found by maximising the marginal likelihood of the log estimates,
# N(mu, Omega + C_i), directly (optim on mu and a Cholesky factor of Omega,
# from many starts), not by EM as libpk does.
theo <- read.csv("datasets/theophylline.csv")
names_p <- c("KA", "CL", "V")
phi <- list(); cov <- list(); ids <- c()
for (id in unique(theo$ID)) {
  s <- theo[theo$ID == id, ]
  dose <- s$AMT[s$EVID == 1][1]
  obs <- s[s$EVID == 0, ]
  d <- data.frame(Time = obs$TIME, conc = obs$DV, Dose = dose)
  st <- getInitial(conc ~ SSfol(Dose, Time, lKe, lKa, lCl), data = d)
  f <- conc ~ Dose * exp(lka) / (exp(lv) * (exp(lka) - exp(lcl - lv))) * (exp(-exp(lcl - lv) * Time) - exp(-exp(lka) * Time))
  start <- list(lka = st[["lKa"]], lcl = st[["lCl"]], lv = st[["lCl"]] - st[["lKe"]])
  fit <- NULL
  for (tol in c(1e-10, 1e-9, 1e-8, 1e-7, 1e-6)) {  # the tightest relative offset that converges
    fit <- tryCatch(nls(f, data = d, start = start, control = nls.control(maxiter = 1000, tol = tol, minFactor = 1e-12)),
                    error = function(e) NULL)
    if (!is.null(fit)) { cat(sprintf("ID %d: nls tol %g\n", id, tol)); break }
  }
  ids <- c(ids, id)
  phi[[length(phi) + 1]] <- unname(coef(fit))
  cov[[length(cov) + 1]] <- unname(vcov(fit))
}
n <- length(phi); p <- 3
rows <- list()
add <- function(omega, stat, par, par2, value, id = "") {
  rows[[length(rows) + 1]] <<- data.frame(OMEGA = omega, STATISTIC = stat, ID = id, PARAMETER = par,
                                          PARAMETER2 = par2, VALUE = sprintf("%.17g", value))
}

# Stage one: the estimates and the covariance of their logarithms.
for (i in seq_len(n)) {
  for (j in 1:p) add("", "estimate", names_p[j], "", exp(phi[[i]][j]), ids[i])
  for (j in 1:p) for (k in 1:p) add("", "cov_log", names_p[j], names_p[k], cov[[i]][j, k], ids[i])
}

# Standard two-stage statistics of the natural-scale estimates.
theta <- exp(do.call(rbind, phi))
for (j in 1:p) {
  x <- theta[, j]
  add("", "sts_mean", names_p[j], "", mean(x))
  add("", "sts_sd", names_p[j], "", sd(x))
  add("", "sts_cv_pct", names_p[j], "", 100 * sd(x) / mean(x))
  add("", "sts_geometric_mean", names_p[j], "", exp(mean(log(x))))
  add("", "sts_geometric_cv_pct", names_p[j], "", 100 * sqrt(exp(var(log(x))) - 1))
  add("", "sts_median", names_p[j], "", median(x))
  add("", "sts_min", names_p[j], "", min(x))
  add("", "sts_max", names_p[j], "", max(x))
}

# Global two-stage: -2 log-likelihood of the log estimates.
m2ll <- function(mu, omega) {
  s <- 0
  for (i in seq_len(n)) {
    sig <- omega + cov[[i]]
    r <- phi[[i]] - mu
    s <- s + as.numeric(determinant(sig, logarithm = TRUE)$modulus) + sum(r * solve(sig, r)) + p * log(2 * pi)
  }
  s
}
unpack <- function(v, diagonal) {
  mu <- v[1:p]
  L <- matrix(0, p, p)
  if (diagonal) {
    diag(L) <- exp(v[(p + 1):(2 * p)])
  } else {
    L[lower.tri(L, diag = TRUE)] <- v[(p + 1):length(v)]
    diag(L) <- exp(diag(L))
  }
  list(mu = mu, omega = L %*% t(L))
}
objective <- function(v, diagonal) {  # +Inf where Omega over- or underflows
  u <- unpack(v, diagonal)
  r <- tryCatch(m2ll(u$mu, u$omega), error = function(e) Inf)
  if (is.finite(r)) r else 1e300
}

for (diagonal in c(FALSE, TRUE)) {
  label <- if (diagonal) "diagonal" else "full"
  mu0 <- colMeans(do.call(rbind, phi))
  best <- NULL
  set.seed(7)
  for (start in 1:40) {
    sd0 <- runif(p, 0.05, 0.6)
    L0 <- diag(log(sd0))
    v0 <- if (diagonal) c(mu0 + rnorm(p, 0, 0.1), log(sd0)) else c(mu0 + rnorm(p, 0, 0.1), L0[lower.tri(L0, diag = TRUE)])
    o <- optim(v0, objective, diagonal = diagonal, method = "BFGS",
               control = list(reltol = 1e-15, maxit = 10000))
    o <- optim(o$par, objective, diagonal = diagonal, method = "Nelder-Mead",
               control = list(reltol = 1e-15, maxit = 20000))
    o <- optim(o$par, objective, diagonal = diagonal, method = "BFGS",
               control = list(reltol = 1e-16, maxit = 10000))
    if (is.null(best) || o$value < best$value) best <- o
  }
  u <- unpack(best$par, diagonal)
  add(label, "minus2ll", "", "", best$value)
  # Cov(mu) from the numerical Hessian of -l in mu at fixed Omega (the
  # observed information, which equals the expected one for mu).
  h <- optimHess(u$mu, function(m) m2ll(m, u$omega) / 2)
  cmu <- solve(h)
  # Expected information about Omega's free entries: 1/2 sum tr(S E_a S E_b).
  entries <- list()
  for (j in 1:p) for (k in 1:j) if (!diagonal || j == k) entries[[length(entries) + 1]] <- c(j, k)
  q <- length(entries)
  info <- matrix(0, q, q)
  for (i in seq_len(n)) {
    S <- solve(u$omega + cov[[i]])
    E <- lapply(entries, function(e) { m <- matrix(0, p, p); m[e[1], e[2]] <- 1; m[e[2], e[1]] <- 1; m })
    for (a in 1:q) for (b in 1:q) info[a, b] <- info[a, b] + 0.5 * sum(diag(S %*% E[[a]] %*% S %*% E[[b]]))
  }
  comega <- solve(info)
  for (j in 1:p) {
    add(label, "mu", names_p[j], "", u$mu[j])
    add(label, "typical", names_p[j], "", exp(u$mu[j]))
    add(label, "typical_se", names_p[j], "", exp(u$mu[j]) * sqrt(cmu[j, j]))
    add(label, "bsv_cv_pct", names_p[j], "", 100 * sqrt(exp(u$omega[j, j]) - 1))
  }
  for (a in 1:q) {
    e <- entries[[a]]
    add(label, "omega", names_p[e[1]], names_p[e[2]], u$omega[e[1], e[2]])
    add(label, "omega_se", names_p[e[1]], names_p[e[2]], sqrt(comega[a, a]))
  }
  cat(sprintf("%s Omega: -2LL %.10g\n", label, best$value))
  print(u)
}
write.csv(do.call(rbind, rows), "tests/reference/two_stage_reference.csv", row.names = FALSE, quote = FALSE)
