// NONMEM's .ext file of a population fit: the parameter history and final estimates in the layout
// that PsN, xpose, Pirana, pharmpy, mrgsolve's read_nmext, NMdata's NMreadExt and nonmem2R read.
#ifndef PK_NONMEM_EXT_H_
#define PK_NONMEM_EXT_H_

#include <string>

#include "pk/population.h"

namespace pk {

/// The fit as NONMEM 7 writes its `.ext` table (`pkpop` writes it as `pkpop.ext`):
///
///     TABLE NO.     1: First Order Conditional Estimation with Interaction: Goal Function=…
///      ITERATION    THETA1       THETA2       THETA3       SIGMA(1,1)   OMEGA(1,1)   OMEGA(2,1)   OMEGA(2,2)   OBJ
///                 0  4.70000E-03  9.90000E-01  1.30000E-01  1.00000E+00  …                                   742.52…
///       -1000000000  …final estimates…
///
/// libpk's model maps onto NONMEM's as docs/population.md writes it: THETA1, … are θ in
/// PopulationSummary::estimates order followed by each residual-error σ (an SD, NONMEM's
/// `W = THETA(k)*F` with `$SIGMA 1 FIX`); SIGMA(k,k) = 1, fixed, one EPS per output's error model;
/// OMEGA(i,j) is Ω's whole lower triangle by rows over the η in eta_names order (0 and fixed outside
/// its blocks). Values are NONMEM's 5-decimal E format (population_estimates.csv keeps every
/// digit); OBJ is the OFV to 17 digits.
///
/// Rows: one per objective evaluation that lowered the OFV (ITERATION = the evaluation's number
/// less 1, so 0 is the initial estimates); −1000000000 the final estimates and OFV; with a covariance
/// step, −1000000001 the SEs (1.0E+10 for what is fixed); −1000000004 Ω and Σ as SDs and
/// correlations (THETA columns 0, as NONMEM writes them); with SEs, −1000000005 their SEs by the
/// delta method over the covariance matrix; −1000000006 1 for each fixed element. NONMEM's
/// −1000000002/3 (eigenvalues, PRINT=E), −1000000007 (termination codes) and −1000000008 (the
/// gradient) are not written.
std::string NonmemExtTable(const PopulationSummary& fit);

}  // namespace pk

#endif  // PK_NONMEM_EXT_H_
