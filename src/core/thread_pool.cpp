#include "thread_pool.hpp"

namespace thurston {

ThreadPool::ThreadPool(unsigned threads) {
  if (threads == 0) threads = std::max(1u, std::thread::hardware_concurrency());
  try {
    for (unsigned i = 0; i < threads; ++i) workers_.emplace_back([this] { work(); });
  } catch (const std::exception& error) {  // std::system_error, or std::bad_alloc growing the list
    // The workers already started wait on wake_: they must be stopped and joined here, or the
    // unwinding would destroy the condition variable under them (a deadlock) or a joinable thread.
    const std::size_t started = workers_.size();
    stop_workers();
    throw ThreadStartError("cannot start " + std::to_string(threads) +
                           " threads: the system refused thread " + std::to_string(started + 1) +
                           " (" + error.what() + ")");
  }
}

ThreadPool::~ThreadPool() { stop_workers(); }

void ThreadPool::stop_workers() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    quit_ = true;
  }
  wake_.notify_all();
  for (auto& worker : workers_) worker.join();
}

void ThreadPool::start(const std::function<void()>& task) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    task_ = &task;
    busy_ = size();
    error_ = nullptr;
    ++generation_;
  }
  wake_.notify_all();
}

bool ThreadPool::wait_for(std::chrono::milliseconds timeout) {
  std::unique_lock<std::mutex> lock(mutex_);
  return idle_.wait_for(lock, timeout, [this] { return busy_ == 0; });
}

void ThreadPool::work() {
  std::uint64_t seen = 0;
  for (;;) {
    const std::function<void()>* task;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [&] { return quit_ || generation_ != seen; });
      if (quit_) return;
      seen = generation_;
      task = task_;
    }
    std::exception_ptr error;
    try {
      (*task)();
    } catch (...) {
      error = std::current_exception();
    }
    std::lock_guard<std::mutex> lock(mutex_);
    if (error && !error_) error_ = error;
    if (--busy_ == 0) idle_.notify_all();
  }
}

}  // namespace thurston
