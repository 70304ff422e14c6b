//! The signals the binaries stop (or suspend) on — SIGINT, SIGTERM, SIGHUP, SIGTSTP — delivered
//! by name to a closure on a thread of its own, where it may lock, allocate and print.
//!
//! A SIGHUP or SIGTSTP the process was started with ignored stays ignored: `nohup` ignores
//! SIGHUP so that a run outlives the terminal it was started from (the `ctrlc` crate, used
//! before, installed its handler over it: a `nohup supervisor run &` stopped its run when the
//! user logged out), and a process started without job control keeps Ctrl-Z ignored. SIGINT and
//! SIGTERM are always taken: a shell without job control ignores SIGINT in every background
//! job it starts, as a side effect rather than the user's wish, and a script's or test
//! harness's `kill -INT` must still stop a run (keeping that ignore made them hang).
//!
//! Not a general signal library: one delivery per process, a handful of signals, no masks.

use std::io;
use std::sync::atomic::{AtomicI32, Ordering};

/// A signal number with its name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Signal(pub libc::c_int);

impl Signal {
    pub const INT: Signal = Signal(libc::SIGINT);
    pub const TERM: Signal = Signal(libc::SIGTERM);
    pub const HUP: Signal = Signal(libc::SIGHUP);
    pub const TSTP: Signal = Signal(libc::SIGTSTP);
    pub const ABRT: Signal = Signal(libc::SIGABRT);
    pub const QUIT: Signal = Signal(libc::SIGQUIT);
    /// What the binaries stop on.
    pub const STOP: [Signal; 3] = [Signal::INT, Signal::TERM, Signal::HUP];

    /// `SIGINT`, …; `signal N` for one this crate has no name for.
    pub fn name(self) -> String {
        let name = match self.0 {
            libc::SIGINT => "SIGINT",
            libc::SIGTERM => "SIGTERM",
            libc::SIGHUP => "SIGHUP",
            libc::SIGTSTP => "SIGTSTP",
            libc::SIGQUIT => "SIGQUIT",
            libc::SIGABRT => "SIGABRT",
            libc::SIGUSR1 => "SIGUSR1",
            libc::SIGUSR2 => "SIGUSR2",
            n => return format!("signal {n}"),
        };
        name.to_owned()
    }
}

impl std::fmt::Display for Signal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum SignalError {
    #[error("signals are already delivered to a handler in this process")]
    AlreadyDelivering,
    #[error("{what}: {source}")]
    Os {
        what: String,
        #[source]
        source: io::Error,
    },
}

fn os(what: impl Into<String>) -> SignalError {
    SignalError::Os {
        what: what.into(),
        source: io::Error::last_os_error(),
    }
}

/// The write end of the pipe the handler wakes the delivering thread through (-1: none yet).
static WAKE_FD: AtomicI32 = AtomicI32::new(-1);

extern "C" fn on_signal(signal: libc::c_int) {
    let fd = WAKE_FD.load(Ordering::Relaxed);
    if fd < 0 {
        return;
    }
    // The interrupted code may be between a failing call and its read of errno.
    // SAFETY: __errno_location returns this thread's errno; write(2) is async-signal-safe and
    // the byte outlives the call (the pipe is non-blocking: with it full, a signal is dropped
    // rather than the process hung in its handler).
    #[allow(unsafe_code)]
    unsafe {
        let errno = *libc::__errno_location();
        libc::write(fd, [signal as u8].as_ptr().cast(), 1);
        *libc::__errno_location() = errno;
    }
}

/// Calls `on` with each of `signals` the process receives, in order, on a thread named
/// `signals`. Returns the signals left alone because the process was started with them
/// ignored (any but SIGINT and SIGTERM; see the crate's doc). Once per process.
pub fn deliver(
    signals: &[Signal],
    mut on: impl FnMut(Signal) + Send + 'static,
) -> Result<Vec<Signal>, SignalError> {
    let mut fds = [0; 2];
    // SAFETY: pipe2 writes two descriptors into the array it is given.
    #[allow(unsafe_code)]
    let made = unsafe { libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) };
    if made != 0 {
        return Err(os("cannot make the signal pipe"));
    }
    let [read_fd, write_fd] = fds;
    // SAFETY: fcntl on a descriptor this function owns.
    #[allow(unsafe_code)]
    let nonblocking = unsafe { libc::fcntl(write_fd, libc::F_SETFL, libc::O_NONBLOCK) };
    if nonblocking != 0
        || WAKE_FD
            .compare_exchange(-1, write_fd, Ordering::SeqCst, Ordering::SeqCst)
            .is_err()
    {
        let error = if nonblocking != 0 {
            os("cannot make the signal pipe non-blocking")
        } else {
            SignalError::AlreadyDelivering
        };
        // SAFETY: both descriptors are this function's and used nowhere else.
        #[allow(unsafe_code)]
        unsafe {
            libc::close(read_fd);
            libc::close(write_fd);
        }
        return Err(error);
    }
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || loop {
            let mut b = [0u8; 1];
            // SAFETY: reads at most one byte into a local buffer.
            #[allow(unsafe_code)]
            let n = unsafe { libc::read(read_fd, b.as_mut_ptr().cast(), 1) };
            if n == 1 {
                on(Signal(libc::c_int::from(b[0])));
            } else if n < 0 && io::Error::last_os_error().kind() == io::ErrorKind::Interrupted {
                continue;
            } else {
                return;
            }
        })
        .map_err(|source| SignalError::Os {
            what: "cannot start the signal thread".into(),
            source,
        })?;
    let mut ignored = Vec::new();
    for &signal in signals {
        // SAFETY: sigaction reads and writes plain structs on this stack; the handler only
        // does what is async-signal-safe (above).
        #[allow(unsafe_code)]
        unsafe {
            let mut old: libc::sigaction = std::mem::zeroed();
            if libc::sigaction(signal.0, std::ptr::null(), &mut old) != 0 {
                return Err(os(format!("cannot read how {signal} is handled")));
            }
            let always = [libc::SIGINT, libc::SIGTERM].contains(&signal.0);
            if old.sa_sigaction == libc::SIG_IGN && !always {
                ignored.push(signal);
                continue;
            }
            let mut sa: libc::sigaction = std::mem::zeroed();
            sa.sa_sigaction = on_signal as *const () as usize;
            sa.sa_flags = libc::SA_RESTART;
            libc::sigemptyset(&mut sa.sa_mask);
            if libc::sigaction(signal.0, &sa, std::ptr::null_mut()) != 0 {
                return Err(os(format!("cannot install the {signal} handler")));
            }
        }
    }
    Ok(ignored)
}

/// Gives `signals` their default action again (for one a library caught without need).
pub fn restore_default(signals: &[Signal]) -> Result<(), SignalError> {
    for &signal in signals {
        // SAFETY: signal(2) with SIG_DFL installs no code of ours.
        #[allow(unsafe_code)]
        let old = unsafe { libc::signal(signal.0, libc::SIG_DFL) };
        if old == libc::SIG_ERR {
            return Err(os(format!("cannot restore the default action of {signal}")));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc::channel;
    use std::time::Duration;

    // One test: delivery is once per process, and dispositions are process-wide.
    #[test]
    fn delivers_by_name_and_keeps_an_inherited_ignore_except_of_sigint_and_sigterm() {
        // SAFETY: setting dispositions to ignored, as nohup does for SIGHUP and a shell
        // without job control for SIGINT in a background job.
        #[allow(unsafe_code)]
        unsafe {
            libc::signal(libc::SIGUSR2, libc::SIG_IGN);
            libc::signal(libc::SIGINT, libc::SIG_IGN);
        }
        let (tx, rx) = channel();
        let watched = [Signal(libc::SIGUSR1), Signal(libc::SIGUSR2), Signal::INT];
        let ignored = deliver(&watched, move |s| {
            let _ = tx.send(s);
        })
        .expect("delivery starts");
        assert_eq!(ignored, vec![Signal(libc::SIGUSR2)]);
        // SAFETY: raise(2) has no memory-safety preconditions; every signal raised is handled
        // or ignored (above), so none ends the test process.
        #[allow(unsafe_code)]
        unsafe {
            libc::raise(libc::SIGUSR2);
            libc::raise(libc::SIGUSR1);
            libc::raise(libc::SIGUSR1);
            libc::raise(libc::SIGINT);
        }
        let next = || rx.recv_timeout(Duration::from_secs(5)).ok();
        let usr1 = Signal(libc::SIGUSR1);
        assert_eq!(next().map(Signal::name).as_deref(), Some("SIGUSR1"));
        assert_eq!(next(), Some(usr1), "each one delivered");
        assert_eq!(next(), Some(Signal::INT), "SIGINT taken although ignored");
        assert!(
            rx.recv_timeout(Duration::from_millis(100)).is_err(),
            "SIGUSR2 stayed ignored"
        );
        assert!(matches!(
            deliver(&[], |_| {}),
            Err(SignalError::AlreadyDelivering)
        ));
        assert_eq!(Signal(64).name(), "signal 64");
        restore_default(&[Signal(libc::SIGUSR2)]).expect("restored");
        // SAFETY: reads the disposition into a local struct.
        #[allow(unsafe_code)]
        let now = unsafe {
            let mut now: libc::sigaction = std::mem::zeroed();
            libc::sigaction(libc::SIGUSR2, std::ptr::null(), &mut now);
            now.sa_sigaction
        };
        assert_eq!(now, libc::SIG_DFL);
        assert_eq!(Signal::TERM.to_string(), "SIGTERM");
    }
}
