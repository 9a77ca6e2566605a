# theophylline_blq.csv: theophylline.csv with a limit of quantification of
# 2 mg/L imposed. Samples below it become censored (CENS=1, DV = the limit 2),
# the convention of Monolix and nlmixr2 for BLQ data (Beal's M3 in pkfit:
# --error additive|proportional|combined). Other rows get CENS=0.
# Run from the repository root:
#   Rscript datasets/make_blq.R
lloq <- 2
d <- read.csv("datasets/theophylline.csv")
blq <- d$EVID == 0 & d$DV < lloq
d$CENS <- as.integer(blq)
d$DV[blq] <- lloq
write.csv(d, "datasets/theophylline_blq.csv", row.names = FALSE, quote = FALSE)
cat(sprintf("%d of %d samples censored at %g mg/L\n", sum(blq), sum(d$EVID == 0), lloq))
