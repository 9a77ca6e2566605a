// libpk over MPI: population estimation with the subjects split across processes (library
// pk::mpi, built when CMake finds MPI and PK_MPI is ON; no MPI type appears here).
//
//   int main(int argc, char** argv) {
//     pk::MpiSession mpi(&argc, &argv);
//     pk::PopulationOptions options;
//     options.distribution = mpi.Distribution();   // every process calls FitPopulation alike
//     if (!mpi.AllReady(true)) return 1;            // another process failed to read its input
//     const pk::PopulationSummary fit = pk::FitPopulation(problem, initial, options);
//     if (mpi.rank() == 0) std::cout << fit.FullReport();
//   }
//
//   mpirun -np 4 ./app
//
// Every process reads the same data and runs the same outer optimisation; each solves its own
// subjects' conditional modes (on PopulationOptions::threads threads); an MPI_Allreduce per
// evaluation (two more per implicit gradient) shares them. The estimates equal one process's to
// the bit on identical machines (pk/population.h).
#ifndef PK_MPI_H_
#define PK_MPI_H_

#include <memory>

#include "pk/population.h"

namespace pk {

/// True when this process was started by an MPI launcher (mpirun, mpiexec, srun): its environment
/// names a rank (OMPI_COMM_WORLD_SIZE, PMIX_RANK or PMI_SIZE). An app can then create an
/// MpiSession, and run as one ordinary process otherwise.
bool LaunchedByMpi();

/// MPI_Init_thread (MPI_THREAD_FUNNELED: only the thread that constructs it uses MPI) on construction,
/// unless MPI is already initialised, and MPI_Finalize on destruction when it initialised it.
/// One per process. Throws std::runtime_error when MPI cannot be initialised.
class MpiSession {
 public:
  MpiSession(int* argc, char*** argv);
  ~MpiSession();
  MpiSession(const MpiSession&) = delete;
  MpiSession& operator=(const MpiSession&) = delete;

  /// This process's rank in MPI_COMM_WORLD, and the number of processes.
  int rank() const { return rank_; }
  int size() const { return size_; }
  /// The subjects of a population problem split across MPI_COMM_WORLD.
  std::shared_ptr<const SubjectDistribution> Distribution() const;
  /// True when every process passes `ready` = true. Every process calls it once, at the same point
  /// before the first collective step (FitPopulation): those ready to fit with true, and one that
  /// failed before it (its input, say) with false on its way out. Otherwise the others would wait
  /// for that one in their first MPI_Allreduce forever; this way each learns of it and can stop.
  bool AllReady(bool ready) const;

 private:
  bool finalize_ = false;
  int rank_ = 0, size_ = 1;
};

}  // namespace pk

#endif  // PK_MPI_H_
