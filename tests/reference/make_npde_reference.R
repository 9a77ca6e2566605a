# NPDE and PD computed independently of libpk, for tests/test_npde.cc.
# Normalised prediction distribution errors (Brendel et al., Pharm Res 2006;23:2036-2049;
# Comets, Brendel, Mentre, Comput Methods Programs Biomed 2008;90:154-166, the npde R
# package), written out here from the formulas alone:
#   EPRED = row means of the K simulations; pd = fraction of simulations below the
#   observation (0 -> 1/(2K), 1 -> 1 - 1/(2K)), NPD = qnorm(pd); V = cov of the
#   simulations (divisor K - 1), R = chol(V), W = R^-1, decorrelated simulations and
#   observation t(W) (x - EPRED), pde/NPDE as pd/NPD on the decorrelated values.
# Subjects 0..4 have n = 1, 2, 3, 5, 8 samples, K = 60 simulations from N(mu, Sigma) and
# an observation from N(mu + 0.3, 1.5 Sigma). Subject 5 (n = 3) has simulations whose
# third row equals the first, so V is singular, chol fails and PDE/NPDE are empty.
# Every value is rounded with signif(x, 10) before use and written with %.17g.
# Run from the repository root: Rscript tests/reference/make_npde_reference.R
# Writes tests/reference/npde_input.csv (SUBJECT,SAMPLE,SIM,VALUE; SIM 0 = observation),
# npde_reference.csv (SUBJECT,SAMPLE,EPRED,PD,NPD,PDE,NPDE) and
# npde_moments_reference.csv (STATISTIC,VALUE over all finite NPDE).
set.seed(20261127)
K <- 60
ns <- c(1, 2, 3, 5, 8, 3)
mvn <- function(m, mu, Sigma) mu + t(chol(Sigma)) %*% matrix(rnorm(length(mu) * m), length(mu), m)
clamp <- function(p) ifelse(p == 0, 1 / (2 * K), ifelse(p == 1, 1 - 1 / (2 * K), p))
f17 <- function(x) ifelse(is.na(x), "", sprintf("%.17g", x))
inp <- list(); ref <- list()
for (s in seq_along(ns)) {
  n <- ns[s]
  A <- matrix(rnorm(n * n), n, n)
  Sigma <- A %*% t(A) + diag(0.1, n)
  mu <- runif(n, 1, 10)
  S <- signif(mvn(K, mu, Sigma), 10)               # n x K, one simulation per column
  y <- signif(as.vector(mvn(1, mu + 0.3, 1.5 * Sigma)), 10)
  if (s == 6) S[3, ] <- S[1, ]                     # degenerate: singular covariance
  inp[[s]] <- data.frame(SUBJECT = s - 1, SAMPLE = rep(0:(n - 1), K + 1),
                         SIM = rep(0:K, each = n), VALUE = c(y, S))
  epred <- rowMeans(S)
  pd <- clamp(rowSums(S < y) / K)
  pde <- rep(NA_real_, n)
  R <- tryCatch(chol(cov(t(S))), error = function(e) NULL)
  if (!is.null(R)) {
    W <- solve(R)
    D <- t(W) %*% (S - epred)
    d <- as.vector(t(W) %*% (y - epred))
    pde <- clamp(rowSums(D < d) / K)
  }
  cat(sprintf("subject %d: n = %d, chol %s\n", s - 1, n, if (is.null(R)) "FAILED" else "ok"))
  ref[[s]] <- data.frame(SUBJECT = s - 1, SAMPLE = 0:(n - 1), EPRED = epred, PD = pd,
                         NPD = qnorm(pd), PDE = pde, NPDE = qnorm(pde))
}
inp <- do.call(rbind, inp); ref <- do.call(rbind, ref)
inp$VALUE <- f17(inp$VALUE)
write.csv(inp, "tests/reference/npde_input.csv", row.names = FALSE, quote = FALSE)
out <- ref
for (col in c("EPRED", "PD", "NPD", "PDE", "NPDE")) out[[col]] <- f17(ref[[col]])
write.csv(out, "tests/reference/npde_reference.csv", row.names = FALSE, quote = FALSE)

x <- ref$NPDE[is.finite(ref$NPDE)]                 # already in SUBJECT, SAMPLE order
m <- length(x); dx <- x - mean(x); v <- var(x)
mom <- data.frame(
  STATISTIC = c("count", "mean", "variance", "skewness", "kurtosis", "mean_se", "variance_se"),
  VALUE = f17(c(m, mean(x), v, (sum(dx^3) / m) / (sum(dx^2) / m)^1.5,
                m * sum(dx^4) / sum(dx^2)^2 - 3, sqrt(v / m), v * sqrt(2 / (m - 1)))))
write.csv(mom, "tests/reference/npde_moments_reference.csv", row.names = FALSE, quote = FALSE)

# Checks: PD and PDE are multiples of 1/K or the boundary values; subject 5 has no PDE.
ok <- function(p) all(abs(p * K - round(p * K)) < 1e-9 | abs(p - 1 / (2 * K)) < 1e-15 |
                      abs(p - (1 - 1 / (2 * K))) < 1e-15)
stopifnot(ok(ref$PD), ok(na.omit(ref$PDE)), all(is.na(ref$PDE[ref$SUBJECT == 5])),
          !anyNA(ref$PDE[ref$SUBJECT != 5]), nrow(inp) == sum(ns * (K + 1)))
back <- read.csv("tests/reference/npde_input.csv")  # round trip of the written doubles
stopifnot(identical(back$VALUE, as.numeric(inp$VALUE)))
