// The fused kernels' thread pool (see pool.h for what it guarantees).
#include "pool.h"

#include <ATen/Parallel.h>
#include <pthread.h>

#include <atomic>
#include <condition_variable>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define ARCSEM_PAUSE() _mm_pause()
#else
#define ARCSEM_PAUSE() ((void)0)
#endif

namespace arcsem {
namespace {

thread_local bool tl_in_pool = false;  // set in workers and in a caller while it runs a job

struct Job {
  const std::function<void(int64_t, int)>* f = nullptr;
  int64_t n = 0;
  int max_workers = 1;              // the caller counts as one
  std::atomic<int64_t> next{0};     // next chunk to hand out
  std::atomic<int> joined{1};       // workers that took part (their indices: 1, 2, ...)
  std::atomic<bool> failed{false};
  std::exception_ptr error;         // the first exception thrown by f (rethrown by the caller)
};

void work(Job& job, int w) {
  for (int64_t c = job.next++; c < job.n; c = job.next++) {
    if (job.failed.load(std::memory_order_relaxed)) continue;  // drain the counter, skip the work
    try {
      (*job.f)(c, w);
    } catch (...) {
      if (!job.failed.exchange(true)) job.error = std::current_exception();
    }
  }
}

class Pool {
 public:
  void run(int64_t n, int nw, const std::function<void(int64_t, int)>& f) {
    std::unique_lock<std::mutex> busy(run_mutex_, std::try_to_lock);
    if (!busy.owns_lock() || tl_in_pool || nw <= 1 || n <= 1) {
      for (int64_t c = 0; c < n; ++c) f(c, 0);
      return;
    }
    ensure_workers(nw - 1);
    Job job;
    job.f = &f;
    job.n = n;
    job.max_workers = nw;
    {
      std::lock_guard<std::mutex> lk(m_);
      job_ = &job;
      ++generation_;
    }
    wake_.notify_all();
    tl_in_pool = true;
    work(job, 0);
    tl_in_pool = false;
    {
      std::lock_guard<std::mutex> lk(m_);
      job_ = nullptr;  // a worker that wakes from now on does not join
    }
    // wait for the chunks other workers hold: spin briefly (they are usually nearly done), then sleep so that
    // a descheduled worker can have this core
    for (int i = 0; i < 4000 && users_.load(std::memory_order_acquire) > 0; ++i) ARCSEM_PAUSE();
    if (users_.load(std::memory_order_acquire) > 0) {
      std::unique_lock<std::mutex> lk(m_);
      done_.wait(lk, [&] { return users_.load() == 0; });
    }
    if (job.error) std::rethrow_exception(job.error);
  }

 private:
  void ensure_workers(int k) {
    std::lock_guard<std::mutex> lk(m_);
    while (int(threads_.size()) < k) {
      threads_.emplace_back([this] { loop(); });
      threads_.back().detach();  // the pool lives as long as the process
    }
  }

  void loop() {
    tl_in_pool = true;
    uint64_t seen = 0;
    std::unique_lock<std::mutex> lk(m_);
    seen = generation_;
    for (;;) {
      wake_.wait(lk, [&] { return generation_ != seen; });
      seen = generation_;
      Job* job = job_;
      if (job == nullptr) continue;
      const int w = job->joined.fetch_add(1);
      if (w >= job->max_workers) continue;
      users_.fetch_add(1);
      lk.unlock();
      work(*job, w);
      lk.lock();
      if (users_.fetch_sub(1) == 1) done_.notify_all();
    }
  }

  std::mutex run_mutex_;  // one job at a time; a second caller runs its work serially
  std::mutex m_;
  std::condition_variable wake_, done_;
  uint64_t generation_ = 0;
  Job* job_ = nullptr;
  std::atomic<int> users_{0};
  std::vector<std::thread> threads_;
};

Pool* g_pool = nullptr;
std::once_flag g_once;

void after_fork_in_child() { g_pool = new Pool(); }  // the child has none of the parent's workers; leak the old

Pool& pool() {
  std::call_once(g_once, [] {
    g_pool = new Pool();
    pthread_atfork(nullptr, nullptr, after_fork_in_child);
  });
  return *g_pool;
}

}  // namespace

int num_workers(int64_t n) {
  const int t = std::max(1, at::get_num_threads());
  return n < 0 ? t : int(std::max<int64_t>(1, std::min<int64_t>(t, n)));
}

void parallel_chunks(int64_t n, const std::function<void(int64_t, int)>& f) {
  if (n <= 0) return;
  pool().run(n, num_workers(n), f);
}

}  // namespace arcsem
