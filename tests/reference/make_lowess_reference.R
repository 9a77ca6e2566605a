# R's lowess() on two small sets, for tests/test_report.cc (the LOWESS smoother of the
# goodness-of-fit plots must equal R's). Run: Rscript tests/reference/make_lowess_reference.R
x <- c(1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 15)
y <- c(2.1, 3.9, 6.2, 7.8, 10.1, 12.2, 13.8, 16.1, 18.3, 19.7, 30, 29)  # an outlier at x = 12
cat("line with an outlier, f = 2/3, iter = 3:\n")
cat(sprintf("%.17g", lowess(x, y)$y), sep = ", ")
x2 <- 0:40 / 4
noise <- c(0.3, -0.2, 0.5, -0.4, 0.1, 0.0, -0.3, 0.2, -0.1, 0.4, -0.5, 0.3, 0.1, -0.2, 0.0, 0.2, -0.3, 0.1,
           0.4, -0.1, 0.2, -0.4, 0.3, 0.0, -0.2, 0.1, 0.5, -0.3, 0.2, -0.1, 0.0, 0.3, -0.2, 0.1, -0.4, 0.2,
           0.0, -0.1, 0.3, -0.3, 0.1)
cat("\nsine with noise, f = 0.3:\n")
cat(sprintf("%.17g", lowess(x2, sin(x2) + noise, f = 0.3)$y), sep = ", ")
# Ties and points closer than delta = range/100: x repeated, and 200 points on [0, 1].
x3 <- c(0, 0, 1, 1, 1, 2, 3, 3, 4, 5, 5, 6)
y3 <- c(1, 1.2, 2.1, 1.9, 2.3, 2.8, 4.1, 3.7, 4.4, 5.2, 4.9, 6.3)
cat("\nties, f = 0.5:\n")
cat(sprintf("%.17g", lowess(x3, y3, f = 0.5)$y), sep = ", ")
x4 <- (0:199)^2 / 199^2
cat("\n200 points, delta skipping, f = 2/3:\n")
cat(sprintf("%.17g", lowess(x4, cos(3 * x4) + 0.1 * sin(37 * x4))$y[c(1, 2, 50, 101, 150, 199, 200)]), sep = ", ")
cat("\n")
# n = 10: f·n = 6.67 points, truncated to 6 by R.
x5 <- 1:10
y5 <- c(2, 4.1, 5.8, 8.3, 9.9, 12.4, 13.7, 16.2, 18.1, 19.6)
cat("n = 10:\n")
cat(sprintf("%.17g", lowess(x5, y5)$y), sep = ", ")
# Ties at the window's edge with a half-width of 0: the ties beyond the window count.
cat("\nties at the edge, h = 0:\n")
cat(sprintf("%.17g", lowess(c(rep(1, 7), 2, 3), 1:9)$y), sep = ", ")
# x far from 0: the spread of x is taken about its mean.
x6 <- 1e7 + (0:29) / 10
cat("\nx far from 0:\n")
cat(sprintf("%.17g", lowess(x6, sin(0:29 / 3))$y[c(1, 10, 20, 30)]), sep = ", ")
cat("\n")
