// NONMEM's output files of a population fit, in the layout that PsN, xpose, Pirana, pharmpy,
// mrgsolve's read_nmext, NMdata's NMreadExt and nonmem2R read: the .ext (parameter history and
// final estimates) and the .phi (each subject's η̂, its conditional covariance and OFV_i).
#ifndef PK_NONMEM_FILES_H_
#define PK_NONMEM_FILES_H_

#include <string>

#include "pk/population.h"

namespace pk {

/// The fit as NONMEM 7 writes its `.ext` table (`pkpop` writes it as `pkpop.ext`):
///
///     TABLE NO.     1: First Order Conditional Estimation with Interaction: Goal Function=…
///      ITERATION    THETA1       THETA2       THETA3       SIGMA(1,1)   OMEGA(1,1)   OMEGA(2,1)   OMEGA(2,2)   OBJ
///                 0  5.00000E-03  1.00000E+00  1.00000E-01  1.00000E-01  1.00000E+00  …   598.1325054994285
///       -1000000000  …final estimates…
///
/// libpk's model maps onto NONMEM's as docs/population.md writes it: THETA1, … are θ in
/// PopulationSummary::estimates order followed by each residual-error σ (an SD, NONMEM's
/// `W = THETA(k)*F` with `$SIGMA 1 FIX`); SIGMA(k,k) = 1, fixed, one EPS per output's error model;
/// OMEGA(i,j) is Ω's whole lower triangle by rows over the η in eta_names order (0 and fixed outside
/// its blocks). Values are NONMEM's 5-decimal E format (population_estimates.csv keeps every
/// digit); OBJ is the OFV in the shortest text that reads back exactly. A fit without estimates
/// (stopped at its starting point) gives the header alone.
///
/// Rows: one per objective evaluation that lowered the OFV (ITERATION = the evaluation's number
/// less 1, so 0 is the initial estimates); −1000000000 the final estimates and OFV; with a covariance
/// step, −1000000001 the SEs (1.0E+10 for what is fixed, 0 where the step gave none); −1000000004 Ω and Σ as SDs and
/// correlations (THETA columns 0, as NONMEM writes them); with SEs, −1000000005 their SEs by the
/// delta method over the covariance matrix; −1000000006 1 for each fixed element. NONMEM's
/// −1000000002/3 (eigenvalues, PRINT=E), −1000000007 (termination codes) and −1000000008 (the
/// gradient) are not written.
std::string NonmemExtTable(const PopulationSummary& fit);

/// The fit's subjects as NONMEM 7 writes its `.phi` table (`pkpop` writes `pkpop.phi`):
///
///     TABLE NO.     1: First Order Conditional Estimation with Interaction: Goal Function=…
///      SUBJECT_NO   ID           ETA(1)       ETA(2)       ETC(1,1)     ETC(2,1)     ETC(2,2)     OBJ
///                 1            1 -4.38581E-02  5.44221E-03  2.48827E-02 -2.99914E-03  7.15709E-03    5.947340253766742
///
/// One row per subject whose mode was found (the others are in PopulationSummary::subjects with
/// their reason): its position among the subjects (from 1), ID, η̂ in eta_names order, ETC = the
/// lower triangle of PopulationSubject::eta_covariance (H_i⁻¹, η's conditional covariance) and
/// OBJ = OFV_i, whose sum over the subjects is the OFV.
std::string NonmemPhiTable(const PopulationSummary& fit);

}  // namespace pk

#endif  // PK_NONMEM_FILES_H_
