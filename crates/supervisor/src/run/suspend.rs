//! Ctrl-Z (SIGTSTP) suspends the whole run. The run's processes lead process groups of their
//! own (so that a group can be killed whole), which the terminal's Ctrl-Z does not reach: it
//! stopped the supervisor alone, and the run went on unsupervised (a robot's rollouts went on
//! while nothing would restart, scale or stop its workers). The handler here only wakes the
//! event loop, which stops every child's group and then the supervisor, and continues them when
//! the supervisor is continued (`fg`). It is not a way to pause a run for long (stop it and
//! `--resume`): only what a shell does to a job.

use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::mpsc::Sender;

use anyhow::bail;

use super::Event;

/// The write end of the pipe the handler wakes the reading thread through (-1: none).
static WAKE_FD: AtomicI32 = AtomicI32::new(-1);

extern "C" fn on_tstp(_: libc::c_int) {
    let fd = WAKE_FD.load(Ordering::Relaxed);
    if fd >= 0 {
        // SAFETY: write(2) is async-signal-safe; the buffer outlives the call.
        #[allow(unsafe_code)]
        unsafe {
            libc::write(fd, [1u8].as_ptr().cast(), 1);
        }
    }
}

/// Turns each SIGTSTP into [`Event::Suspend`] on `tx`, unless SIGTSTP is ignored (a supervisor
/// started without job control, as `nohup` does, keeps it so).
pub(super) fn forward_sigtstp(tx: Sender<Event>) -> anyhow::Result<()> {
    // SAFETY: plain libc calls on valid pointers to local storage; the handler only writes to
    // a pipe.
    #[allow(unsafe_code)]
    unsafe {
        let mut old: libc::sigaction = std::mem::zeroed();
        if libc::sigaction(libc::SIGTSTP, std::ptr::null(), &mut old) != 0 {
            bail!("cannot read the SIGTSTP disposition");
        }
        if old.sa_sigaction == libc::SIG_IGN {
            return Ok(());
        }
        let mut fds = [0; 2];
        if libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) != 0 {
            bail!("cannot make the SIGTSTP pipe");
        }
        let read_fd = fds[0];
        std::thread::Builder::new()
            .name("sigtstp".into())
            .spawn(move || loop {
                let mut b = [0u8; 1];
                let n = libc::read(read_fd, b.as_mut_ptr().cast(), 1);
                if n == 1 {
                    if tx.send(Event::Suspend).is_err() {
                        return;
                    }
                } else if n < 0
                    && std::io::Error::last_os_error().kind() == std::io::ErrorKind::Interrupted
                {
                    continue;
                } else {
                    return;
                }
            })?;
        WAKE_FD.store(fds[1], Ordering::Relaxed);
        let mut sa: libc::sigaction = std::mem::zeroed();
        sa.sa_sigaction = on_tstp as *const () as usize;
        sa.sa_flags = libc::SA_RESTART;
        libc::sigemptyset(&mut sa.sa_mask);
        if libc::sigaction(libc::SIGTSTP, &sa, std::ptr::null_mut()) != 0 {
            bail!("cannot install the SIGTSTP handler");
        }
    }
    Ok(())
}

/// Stops the supervisor itself (as SIGTSTP's default would have); returns once it is continued.
pub(super) fn stop_self() {
    // SAFETY: raise(2) has no memory-safety preconditions.
    #[allow(unsafe_code)]
    unsafe {
        libc::raise(libc::SIGSTOP);
    }
}
