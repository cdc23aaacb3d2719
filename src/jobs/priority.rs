//! Job threads run at a lower CPU priority than the HTTP runtime.
//!
//! Jobs are throughput work: they keep every core busy for seconds. The API
//! is latency work: a `GET /v1/jobs/{id}` needs a few microseconds of CPU,
//! but when it competes as an equal with two busy job threads on two cores
//! its tail latency becomes the scheduler's time slice. So the threads that
//! run jobs (one per running attempt) and the rayon pool the pipeline fans
//! out on get nice +10 (a tenth of a nice-0 thread's CPU share when both
//! want the CPU, and all of it when the API is idle): the runtime's
//! threads, left at the process's priority, win every contention.
//!
//! On Linux `setpriority(PRIO_PROCESS, tid, …)` changes one thread (through
//! rustix's safe wrappers); raising a nice value needs no privilege.
//! Elsewhere this is a no-op.

/// The nice value of job threads.
pub const JOB_NICE: i32 = 10;

/// Lowers the calling thread's CPU priority to [`JOB_NICE`] (best effort:
/// a failure is logged and the thread runs at its old priority).
pub fn lower_this_thread() {
    #[cfg(target_os = "linux")]
    {
        let tid = rustix::thread::gettid();
        if let Err(e) = rustix::process::setpriority_process(Some(tid), JOB_NICE) {
            tracing::debug!(error = %e, "could not lower a job thread's priority");
        }
    }
}

/// The calling thread's nice value (Linux; `None` elsewhere or on error).
pub fn this_thread_nice() -> Option<i32> {
    #[cfg(target_os = "linux")]
    {
        rustix::process::getpriority_process(Some(rustix::thread::gettid())).ok()
    }
    #[cfg(not(target_os = "linux"))]
    {
        None
    }
}

/// Makes the global rayon pool's threads job threads (lower priority).
/// Call before anything uses rayon; when the pool already exists (another
/// server in the same test process built it) its threads keep their
/// priority and this returns `false`.
pub fn lower_rayon_pool() -> bool {
    rayon::ThreadPoolBuilder::new()
        .thread_name(|i| format!("rayon-{i}"))
        .start_handler(|_| lower_this_thread())
        .build_global()
        .is_ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_os = "linux")]
    #[test]
    fn a_lowered_thread_runs_at_job_nice_and_others_do_not() {
        let before = this_thread_nice().expect("nice of this thread");
        let inside = std::thread::spawn(|| {
            lower_this_thread();
            this_thread_nice()
        })
        .join()
        .unwrap();
        assert_eq!(inside, Some(JOB_NICE.max(before)));
        // Only that thread changed.
        assert_eq!(this_thread_nice(), Some(before));
    }
}
