# A VPC's statistics computed independently of libpk, for tests/test_population_simulation.cc.
# Writes vpc_input.csv (an observed design and 30 replicates of simulated values, random numbers
# from R's own generator: the statistics, not a model, are under test) and vpc_reference.csv (the
# VPC with bin edges 0, 3, 8, 30 and the 10th, 50th, 90th percentiles, their 80% interval: plain
# (CORRECTED 0), prediction-corrected with lower bound 0 (1) and with lower bound 0.5 (2), and
# prediction- and variability-corrected with lower bound 0 (3) and 0.5 (4)), percentiles by R's
# quantile(type = 7).
# Run from the repository root: Rscript tests/reference/make_vpc_reference.R
set.seed(20261127)
subjects <- 20
times <- c(0.5, 1, 2, 4, 6, 8, 12, 24)
design <- expand.grid(SAMPLE = seq_along(times), SUBJECT = seq_len(subjects))
design$TIME <- times[design$SAMPLE] + round(runif(nrow(design), -0.2, 0.2), 3)
design$TIME[design$TIME < 0.1] <- 0.1
design$DVID <- ifelse(design$SAMPLE %% 3 == 0, 2, 1)  # two outputs, to bin apart
design$PRED <- signif(10 * exp(-0.1 * design$TIME) * (1 + 0.3 * design$SUBJECT / subjects) * design$DVID, 8)
replicates <- 30
rows <- list()
for (rep in 0:replicates) {  # replicate 0 is the observed data
  sd <- if (rep == 0) 0.35 else 0.3
  dv <- signif(design$PRED * exp(rnorm(nrow(design), 0, sd)), 8)
  rows[[rep + 1]] <- data.frame(REP = rep, SUBJECT = design$SUBJECT - 1, SAMPLE = design$SAMPLE - 1,
                                TIME = design$TIME, DVID = design$DVID, PRED = design$PRED, DV = dv)
}
input <- do.call(rbind, rows)
write.csv(input, "tests/reference/vpc_input.csv", row.names = FALSE, quote = FALSE)

edges <- c(0, 3, 8, 30)
percentiles <- c(10, 50, 90)
interval <- 80
bin_of <- function(t) findInterval(t, edges, rightmost.closed = TRUE)
pc_values <- function(d, bins, lb) {  # Bergstrand 2011: lb + (y - lb) (PRED_bin - lb) / (PRED - lb)
  observed <- input[input$REP == 0, ]
  pred_bin <- tapply(observed$PRED, list(observed$DVID, bin_of(observed$TIME)), median)
  lb + (d$DV - lb) * (pred_bin[cbind(as.character(d$DVID), as.character(bins))] - lb) / (d$PRED - lb)
}
# pvcVPC (Bergstrand 2011): PRED_bin + (pcY - PRED_bin) sd_bin / sd_ij, sd_ij the standard deviation of
# sample ij's pcY over the replicates (1..30), sd_bin the median of the sd_ij of its bin.
pvc_values <- function(d, lb) {
  observed <- input[input$REP == 0, ]
  bins <- bin_of(d$TIME)
  pred_bin <- tapply(observed$PRED, list(observed$DVID, bin_of(observed$TIME)), median)
  pb <- pred_bin[cbind(as.character(d$DVID), as.character(bins))]
  simulated <- input[input$REP > 0, ]
  pc <- pc_values(simulated, bin_of(simulated$TIME), lb)
  sd_ij <- tapply(pc, list(simulated$SUBJECT, simulated$SAMPLE), sd)
  first <- simulated$REP == 1
  sd_bin <- tapply(sd_ij[cbind(simulated$SUBJECT[first] + 1, simulated$SAMPLE[first] + 1)],
                   list(simulated$DVID[first], bin_of(simulated$TIME[first])), median)
  s <- sd_ij[cbind(d$SUBJECT + 1, d$SAMPLE + 1)]
  pb + (pc_values(d, bins, lb) - pb) * sd_bin[cbind(as.character(d$DVID), as.character(bins))] / s
}
out <- list()
for (corrected in c(0, 1, 2, 3, 4)) {
  lb <- if (corrected %in% c(2, 4)) 0.5 else 0
  for (dvid in sort(unique(input$DVID))) {
    for (b in seq_len(length(edges) - 1)) {
      observed <- input[input$REP == 0, ]
      values_of <- function(d) {
        keep <- d$DVID == dvid & bin_of(d$TIME) == b
        v <- if (corrected >= 3) pvc_values(d, lb) else if (corrected > 0) pc_values(d, bin_of(d$TIME), lb) else d$DV
        v[keep]
      }
      obs <- values_of(observed)
      if (length(obs) == 0) next
      for (p in percentiles) {
        sim <- sapply(1:replicates, function(r) quantile(values_of(input[input$REP == r, ]), p / 100, type = 7))
        tail <- (100 - interval) / 2
        out[[length(out) + 1]] <- data.frame(
          CORRECTED = corrected, DVID = dvid, BIN = b, N = length(obs), PERCENTILE = p,
          TIME = median(observed$TIME[observed$DVID == dvid & bin_of(observed$TIME) == b]),
          OBSERVED = quantile(obs, p / 100, type = 7),
          SIM_LOWER = quantile(sim, tail / 100, type = 7), SIM_MEDIAN = quantile(sim, 0.5, type = 7),
          SIM_UPPER = quantile(sim, 1 - tail / 100, type = 7))
      }
    }
  }
}
reference <- do.call(rbind, out)
write.csv(format(reference, digits = 17), "tests/reference/vpc_reference.csv", row.names = FALSE, quote = FALSE)
