// Work on items 0..n-1 in parallel, delivered in order (not installed).
#ifndef PK_SRC_ORDERED_PARALLEL_H_
#define PK_SRC_ORDERED_PARALLEL_H_

#include <algorithm>
#include <condition_variable>
#include <exception>
#include <functional>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

namespace pk {
namespace internal {

/// Runs `work(i)` for i = 0..n-1 on `jobs` threads and `deliver(i, result)` on the calling thread
/// in the order of i, as results become ready. At most `window` results are held at once (done but
/// not delivered, or in progress), so memory stays bounded however large n is. An exception from
/// `work(i)` is rethrown when item i's turn to be delivered comes, after every earlier item was
/// delivered (as a serial loop would): the workers stop taking new items, and finish those they hold.
template <typename T>
void OrderedParallel(int n, int jobs, int window, const std::function<T(int)>& work,
                     const std::function<void(int, T&&)>& deliver) {
  if (jobs <= 1 || n <= 1) {
    for (int i = 0; i < n; ++i) deliver(i, work(i));
    return;
  }
  struct Slot {
    std::optional<T> result;
    std::exception_ptr error;
    bool ready = false;
  };
  window = std::max(window, jobs);
  std::vector<Slot> slots(static_cast<size_t>(window));
  std::mutex mutex;
  std::condition_variable changed;
  int next = 0, delivered = 0;
  bool stop = false;
  auto worker = [&] {
    std::unique_lock<std::mutex> lock(mutex);
    for (;;) {
      changed.wait(lock, [&] { return stop || next >= n || next < delivered + window; });
      if (stop || next >= n) return;
      const int i = next++;
      lock.unlock();
      Slot done;
      try {
        done.result.emplace(work(i));
      } catch (...) {
        done.error = std::current_exception();
      }
      done.ready = true;
      lock.lock();
      slots[static_cast<size_t>(i % window)] = std::move(done);
      changed.notify_all();
    }
  };
  std::vector<std::thread> threads;
  for (int j = 0; j < jobs; ++j) threads.emplace_back(worker);
  std::exception_ptr failure;
  try {
    for (int i = 0; i < n; ++i) {
      Slot slot;
      {
        std::unique_lock<std::mutex> lock(mutex);
        Slot& s = slots[static_cast<size_t>(i % window)];
        changed.wait(lock, [&] { return s.ready; });
        slot = std::move(s);
        s = Slot();
      }
      if (slot.error) std::rethrow_exception(slot.error);
      deliver(i, std::move(*slot.result));
      std::lock_guard<std::mutex> lock(mutex);
      ++delivered;
      changed.notify_all();
    }
  } catch (...) {
    failure = std::current_exception();
  }
  {
    std::lock_guard<std::mutex> lock(mutex);
    stop = true;
    changed.notify_all();
  }
  for (std::thread& t : threads) t.join();
  if (failure) std::rethrow_exception(failure);
}

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_ORDERED_PARALLEL_H_
