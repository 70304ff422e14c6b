//! Ctrl-Z (SIGTSTP) suspends the whole run. The run's processes lead process groups of their
//! own (so that a group can be killed whole), which the terminal's Ctrl-Z does not reach: it
//! stopped the supervisor alone, and the run went on unsupervised (a robot's rollouts went on
//! while nothing would restart, scale or stop its workers). The signal (delivered by the
//! `signals` crate, unless the supervisor was started with it ignored) only wakes the event loop, which stops every child's group and then the supervisor, and continues them when
//! the supervisor is continued (`fg`). It is not a way to pause a run for long (stop it and
//! `--resume`): only what a shell does to a job.

/// Stops the supervisor itself (as SIGTSTP's default would have); returns once it is continued.
pub(super) fn stop_self() {
    // SAFETY: raise(2) has no memory-safety preconditions.
    #[allow(unsafe_code)]
    unsafe {
        libc::raise(libc::SIGSTOP);
    }
}
