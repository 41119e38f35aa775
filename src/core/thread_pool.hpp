// A persistent pool of worker threads that all run one task at a time.
#pragma once

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <functional>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace thurston {

// The system could not start as many threads as asked for.
struct ThreadStartError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class ThreadPool {
 public:
  // 0: one per hardware thread. Throws ThreadStartError, with no thread left running, where the
  // system cannot start them all.
  explicit ThreadPool(unsigned threads);
  ~ThreadPool();
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  unsigned size() const { return static_cast<unsigned>(workers_.size()); }

  // Starts `task` on every worker; the task must stay alive until wait_for reports completion.
  // The task shares out its own work (typically through an atomic counter).
  void start(const std::function<void()>& task);

  // Waits up to `timeout` for the running task to finish on all workers; true when it has.
  bool wait_for(std::chrono::milliseconds timeout);

  // The first exception a worker's task threw during the last run, if any.
  std::exception_ptr error() const { return error_; }

 private:
  void work();
  void stop_workers();  // tells the workers to quit and joins them

  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable wake_;
  std::condition_variable idle_;
  const std::function<void()>* task_ = nullptr;
  std::uint64_t generation_ = 0;
  unsigned busy_ = 0;
  bool quit_ = false;
  std::exception_ptr error_;
};

}  // namespace thurston
