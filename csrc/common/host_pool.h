// A deterministic parallel loop on plain std::threads, for the eager host entry
// points (called through ctypes, which releases the GIL).
//
// The work [0, n) is cut into fixed chunks of `chunk` items whatever the thread
// count; threads take chunks in any order, and every chunk writes only its own
// outputs, so the results do not depend on the number of threads.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

namespace voxax {
namespace spatial {

inline int resolve_threads(int requested) {
  if (requested > 0) return std::min(requested, 256);
  const unsigned hw = std::thread::hardware_concurrency();
  return hw == 0 ? 1 : static_cast<int>(std::min(hw, 256u));
}

// Calls fn(chunk_index, begin, end) for every chunk. Rethrows the first
// exception (by chunk index) after all threads have joined.
template <typename Fn>
void parallel_chunks(int64_t n, int64_t chunk, int threads, Fn&& fn) {
  if (n <= 0) return;
  const int64_t chunks = (n + chunk - 1) / chunk;
  const int workers = static_cast<int>(std::min<int64_t>(resolve_threads(threads), chunks));
  std::atomic<int64_t> next{0};
  std::mutex mu;
  int64_t failed_chunk = -1;
  std::exception_ptr error;
  auto work = [&]() {
    for (;;) {
      const int64_t c = next.fetch_add(1);
      if (c >= chunks) return;
      try {
        fn(c, c * chunk, std::min(n, (c + 1) * chunk));
      } catch (...) {
        std::lock_guard<std::mutex> lock(mu);
        if (failed_chunk < 0 || c < failed_chunk) {
          failed_chunk = c;
          error = std::current_exception();
        }
      }
    }
  };
  if (workers <= 1) {
    work();
  } else {
    std::vector<std::thread> pool;
    pool.reserve(workers - 1);
    try {
      for (int i = 1; i < workers; ++i) pool.emplace_back(work);
    } catch (...) {
      // Could not start every thread: the ones running and this one finish the work.
    }
    work();
    for (auto& t : pool) t.join();
  }
  if (error) std::rethrow_exception(error);
}

}  // namespace spatial
}  // namespace voxax
