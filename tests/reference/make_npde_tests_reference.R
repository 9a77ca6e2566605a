# The npde package's tests of N(0, 1) as R computes them, for tests/test_npde.cc: t.test(x)'s and wilcox.test(x)'s
# p-value (exact below 50 values without ties or zeros, else the normal approximation with continuity
# and ties' corrections), the variance test 2 min(pchisq(c, n - 1), 1 - pchisq(c, n - 1)) with
# c = (n - 1) var(x) (npde's gof.test), and shapiro.test(x)'s W and p-value (3 to 5000 values).
# Sets of values chosen to reach each branch: n = 3, 4, 5 (Royston's small-sample coefficients), 6, 11, 12
# (the two p-value polynomials), exact and approximate Wilcoxon, ties, zeros, skewed values, NPDE-like
# discretised values, and 6000 values (no Shapiro-Wilk). Shapiro-Wilk's p of 1e-99 (swilk.c's n <= 11 guard)
# is not reached by any valid W. The global p-value: npde's gof.test (parametric = TRUE, its default).
# Run from the repository root: Rscript tests/reference/make_npde_tests_reference.R
set.seed(20261127)
npde_like <- function(n, k) qnorm(pmin(pmax(round(runif(n) * k) / k, 1 / (2 * k)), 1 - 1 / (2 * k)))
sets <- list(rnorm(3), rnorm(4), rnorm(5), rnorm(6), rnorm(11, 0.3), rnorm(12), rnorm(30), rnorm(49, 0.4),
             rnorm(50), rnorm(200, 0, 1.2), rnorm(1000), round(rnorm(40), 1), c(0, 0, rnorm(20)),
             rexp(100) - 1, npde_like(300, 60), rt(500, 3), rnorm(6000))
inp <- do.call(rbind, lapply(seq_along(sets), function(s) data.frame(SET = s - 1, VALUE = sprintf("%.17g", sets[[s]]))))
write.csv(inp, "tests/reference/npde_tests_input.csv", row.names = FALSE, quote = FALSE)
f17 <- function(x) ifelse(is.na(x), "", sprintf("%.17g", x))
ref <- do.call(rbind, lapply(seq_along(sets), function(s) {
  x <- as.numeric(sprintf("%.17g", sets[[s]]))
  n <- length(x)
  wp <- suppressWarnings(wilcox.test(x)$p.value)
  tp <- t.test(x)$p.value
  chi <- var(x) * (n - 1)
  fp <- 2 * min(pchisq(chi, n - 1), 1 - pchisq(chi, n - 1))
  sw <- if (n >= 3 && n <= 5000) shapiro.test(x) else list(statistic = NA, p.value = NA)
  # npde's global test (gof.test, parametric = TRUE): Bonferroni over the t, variance and Shapiro-Wilk tests
  # (over the two others where Shapiro-Wilk cannot be made, as libpk does; npde itself stops there).
  ps <- c(tp, fp, sw$p.value)
  gp <- min(1, sum(!is.na(ps)) * min(ps, na.rm = TRUE))
  data.frame(SET = s - 1, N = n, WILCOXON_P = f17(wp), VARIANCE_P = f17(fp), SHAPIRO_W = f17(unname(sw$statistic)),
             SHAPIRO_P = f17(sw$p.value), T_P = f17(tp), GLOBAL_P = f17(gp))
}))
write.csv(ref, "tests/reference/npde_tests_reference.csv", row.names = FALSE, quote = FALSE)
print(ref)
