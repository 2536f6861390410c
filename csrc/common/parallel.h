// A deterministic parallel loop over XLA's intra-op thread pool.
#pragma once

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <functional>
#include <memory>
#include <mutex>
#include <type_traits>
#include <utility>

#include "xla/ffi/api/ffi.h"

namespace voxax {

namespace ffi = xla::ffi;

// Runs body(i) -- or body(i, worker) -- for i in [0, n) on XLA's thread pool
// and the calling thread. Every index is processed at most once, and exactly
// once when nothing throws; which thread runs it does not affect results
// because each index writes disjoint memory. `worker` is a slot in
// [0, workers(pool, n)) that no two concurrent calls of body share, so the
// caller can give each worker its own scratch memory for the duration of the
// loop.
//
// An exception thrown by the body stops the loop from starting further
// indices and is rethrown in the calling thread once the started ones have
// finished (the one from the lowest index, when several threw). Workers that
// start after all indices are claimed return without touching the caller's
// data, so the caller only waits for claimed work, never for a pool thread to
// become free.
class ParallelFor {
 public:
  static int64_t workers(ffi::ThreadPool* pool, int64_t n) {
    const int64_t threads = pool ? std::max<int64_t>(1, pool->num_threads()) : 1;
    return std::max<int64_t>(1, std::min<int64_t>(threads, n));
  }

  template <typename Body>
  static void run(ffi::ThreadPool* pool, int64_t n, Body&& body) {
    if (n <= 0) return;
    const int64_t slots = workers(pool, n);
    if (slots <= 1) {
      for (int64_t i = 0; i < n; ++i) call(body, i, 0);
      return;
    }
    auto state = std::make_shared<State>();
    state->n = n;
    state->body = [&body](int64_t i, int worker) { call(body, i, worker); };
    // If scheduling fails (out of memory), the threads scheduled so far and
    // the caller do the work.
    try {
      for (int64_t t = 1; t < slots; ++t) {
        const int worker = static_cast<int>(t);
        pool->Schedule([state, worker]() { work(*state, worker); });
      }
    } catch (...) {
    }
    work(*state, 0);
    {
      std::unique_lock<std::mutex> lock(state->mutex);
      state->cv.wait(lock, [&] { return state->done.load() == state->n; });
    }
    // Drop the reference to the caller's body before returning.
    state->body = nullptr;
    if (state->error) std::rethrow_exception(state->error);
  }

 private:
  template <typename Body>
  static void call(Body& body, int64_t i, int worker) {
    if constexpr (std::is_invocable_v<Body&, int64_t, int>) {
      body(i, worker);
    } else {
      body(i);
    }
  }

  struct State {
    std::atomic<int64_t> next{0};
    std::atomic<int64_t> done{0};
    std::atomic<bool> failed{false};
    int64_t n = 0;
    std::function<void(int64_t, int)> body;
    std::mutex mutex;
    std::condition_variable cv;
    std::exception_ptr error;  // guarded by mutex
    int64_t error_index = 0;   // guarded by mutex
  };

  static void work(State& s, int worker) {
    for (;;) {
      const int64_t i = s.next.fetch_add(1);
      if (i >= s.n) return;
      if (!s.failed.load()) {
        try {
          s.body(i, worker);
        } catch (...) {
          std::lock_guard<std::mutex> lock(s.mutex);
          if (!s.error || i < s.error_index) {
            s.error = std::current_exception();
            s.error_index = i;
          }
          s.failed.store(true);
        }
      }
      if (s.done.fetch_add(1) + 1 == s.n) {
        std::lock_guard<std::mutex> lock(s.mutex);
        s.cv.notify_all();
      }
    }
  }
};

}  // namespace voxax
