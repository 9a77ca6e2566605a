// pk::MpiSession and the MPI SubjectDistribution (pk/mpi.h): the one file that uses MPI.
#include <mpi.h>

#include <cstdlib>
#include <stdexcept>
#include <string>
#include <vector>

#include "pk/mpi.h"

namespace pk {
namespace {

void Check(int code, const char* what) {
  if (code != MPI_SUCCESS) throw std::runtime_error(std::string(what) + " failed (MPI error " + std::to_string(code) + ")");
}

class MpiDistribution : public SubjectDistribution {
 public:
  MpiDistribution(int rank, int size) : rank_(rank), size_(size) {}
  int rank() const override { return rank_; }
  int size() const override { return size_; }

  void Sum(double* values, int count) const override {
    Check(MPI_Allreduce(MPI_IN_PLACE, values, count, MPI_DOUBLE, MPI_SUM, MPI_COMM_WORLD), "MPI_Allreduce");
  }

  std::string Broadcast(const std::string& text, int root) const override {
    int length = static_cast<int>(text.size());
    Check(MPI_Bcast(&length, 1, MPI_INT, root, MPI_COMM_WORLD), "MPI_Bcast");
    std::vector<char> buffer(text.begin(), text.end());
    buffer.resize(static_cast<size_t>(length));
    if (length > 0) Check(MPI_Bcast(buffer.data(), length, MPI_CHAR, root, MPI_COMM_WORLD), "MPI_Bcast");
    return std::string(buffer.begin(), buffer.end());
  }

 private:
  int rank_, size_;
};

}  // namespace

bool LaunchedByMpi() {
  return std::getenv("OMPI_COMM_WORLD_SIZE") || std::getenv("PMIX_RANK") || std::getenv("PMI_SIZE");
}

MpiSession::MpiSession(int* argc, char*** argv) {
  int initialised = 0;
  Check(MPI_Initialized(&initialised), "MPI_Initialized");
  if (!initialised) {
    int provided = 0;
    Check(MPI_Init_thread(argc, argv, MPI_THREAD_FUNNELED, &provided), "MPI_Init_thread");
    finalize_ = true;
    if (provided < MPI_THREAD_FUNNELED) {
      throw std::runtime_error("MPI provides no thread support (MPI_THREAD_FUNNELED), which libpk's threads need");
    }
  }
  Check(MPI_Comm_rank(MPI_COMM_WORLD, &rank_), "MPI_Comm_rank");
  Check(MPI_Comm_size(MPI_COMM_WORLD, &size_), "MPI_Comm_size");
}

MpiSession::~MpiSession() {
  if (finalize_) MPI_Finalize();
}

bool MpiSession::AllReady(bool ready) const {
  int flag = ready ? 1 : 0;
  Check(MPI_Allreduce(MPI_IN_PLACE, &flag, 1, MPI_INT, MPI_MIN, MPI_COMM_WORLD), "MPI_Allreduce");
  return flag == 1;
}

std::shared_ptr<const SubjectDistribution> MpiSession::Distribution() const {
  return std::make_shared<MpiDistribution>(rank_, size_);
}

}  // namespace pk
