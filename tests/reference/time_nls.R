# Wall time of R nls + SSfol (default settings) on the 12 theophylline subjects,
# the baseline of docs/performance.md. Run from the repository root:
#   Rscript tests/reference/time_nls.R
theo <- read.csv("datasets/theophylline.csv")
fits <- function() for (id in unique(theo$ID)) {
  s <- theo[theo$ID == id, ]; obs <- s[s$EVID == 0, ]
  d <- data.frame(Time = obs$TIME, conc = obs$DV, Dose = s$AMT[s$EVID == 1][1])
  nls(conc ~ SSfol(Dose, Time, lKe, lKa, lCl), data = d)
}
fits()
t <- system.time(for (r in 1:5) fits())[["elapsed"]] / 5
cat(sprintf("R nls SSfol defaults, 12 theophylline fits: %.1f ms\n", t * 1000))
