//! Heap settings for the one-shot analysis commands (`calibrate`, `diagnose`).
//!
//! Those commands allocate and free column-sized buffers (0.1-1 MB: the recording's columns, the
//! wild-value screen's per-channel series, the solver's residuals) many times over. glibc's
//! defaults serve each such block with a fresh `mmap` and give it back with `munmap` (or trim
//! the heap top), so every reuse faults its pages in again and the kernel zeroes them: on the
//! 100,000 x 4 bench recording 17,250 page faults and ~20 % of the process's CPU time
//! (BENCHMARKS.md). Keeping freed memory in the process turns a reuse into a plain write.
//! The results do not depend on this (the same code runs on the same values).

/// Serve blocks up to 32 MiB from the heap (glibc's largest mmap threshold) and do not trim the
/// heap before 1 GiB is free. Only for short-lived commands: a daemon would keep its peak.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator parameters; it is called on the main thread before
    // the command's work starts, and a refused setting (return 0) leaves glibc's default.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
    }
}
