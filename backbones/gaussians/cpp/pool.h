// A small thread pool for the fused kernels, made for a shared machine.
//
// parallel_chunks(n, f) runs f(chunk, worker) for chunk in [0, n). Chunks are handed out one at a time to
// whichever thread asks (the calling thread works too), and the caller then waits only for chunks that
// another thread has already taken: a worker that the scheduler has not run yet (the machine is busy)
// finds no work left when it wakes, and nobody waits for it. Idle workers sleep (no spinning), so
// between kernels the cores are free for other processes. Worker 0 is the calling thread; worker
// indices are < num_workers(). The thread count follows at::get_num_threads().
#pragma once
#include <algorithm>
#include <cstdint>
#include <functional>

namespace arcsem {

// Workers a parallel_chunks call may use (>= 1): at::get_num_threads(), capped by n when given.
int num_workers(int64_t n = -1);

// f(chunk, worker) for every chunk in [0, n); returns when all have run. A call made from inside f, from a
// second thread while the pool is busy, or with one worker runs serially on the calling thread.
void parallel_chunks(int64_t n, const std::function<void(int64_t, int)>& f);

// f(begin, end, worker) over [0, n) in chunks of `grain` items (the last may be shorter).
template <class F>
inline void parallel_range(int64_t n, int64_t grain, const F& f) {
  const int64_t chunks = (n + grain - 1) / grain;
  parallel_chunks(chunks, [&](int64_t c, int w) { f(c * grain, std::min(n, (c + 1) * grain), w); });
}

}  // namespace arcsem
