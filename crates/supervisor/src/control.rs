//! The control socket: one line per command, the reply until EOF (first line `ok` or `error`).

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, Sender};
use std::time::Duration;

use anyhow::{bail, Context};

/// A command from `supervisor status|scale|set|stop`.
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    Status,
    Scale(usize),
    Set(String, f64),
    Stop,
    /// `stop --after-update`.
    StopAfterUpdate,
    Record,
}

impl Command {
    pub fn parse(line: &str) -> Result<Self, String> {
        let parts: Vec<&str> = line.split_whitespace().collect();
        match parts.as_slice() {
            ["status"] => Ok(Self::Status),
            ["stop"] => Ok(Self::Stop),
            ["stop", "after-update"] => Ok(Self::StopAfterUpdate),
            ["record"] => Ok(Self::Record),
            ["scale", n] => n
                .parse()
                .map(Self::Scale)
                .map_err(|_| format!("scale: `{n}` is not a worker count")),
            ["set", name, value] => value
                .parse()
                .map(|v| Self::Set(name.to_string(), v))
                .map_err(|_| format!("set: `{value}` is not a number")),
            _ => Err(format!("unknown command `{line}`")),
        }
    }
}

/// A command with the channel its reply goes to.
pub type Request = (Command, Sender<Result<String, String>>);

/// The directory holding one directory per active run.
pub fn runs_dir() -> PathBuf {
    match std::env::var_os("PI2CMA_RUN_DIR") {
        Some(d) => PathBuf::from(d),
        None => {
            // SAFETY: getuid cannot fail and has no preconditions.
            #[allow(unsafe_code)]
            let uid = unsafe { libc::getuid() };
            PathBuf::from(format!("/tmp/pi2cma-{uid}"))
        }
    }
}

pub fn socket_path(run_dir: &Path) -> PathBuf {
    run_dir.join("control.sock")
}

/// Whether a supervisor accepts connections on the run's socket (a killed one leaves the socket
/// file, which then refuses them).
pub fn serving(run_dir: &Path) -> bool {
    UnixStream::connect(socket_path(run_dir)).is_ok()
}

/// Accepts connections on the run's socket and forwards each command to `tx`.
pub fn serve(run_dir: &Path, tx: Sender<super::run::Event>) -> anyhow::Result<()> {
    let path = socket_path(run_dir);
    let listener =
        UnixListener::bind(&path).with_context(|| format!("cannot bind {}", path.display()))?;
    std::thread::Builder::new()
        .name("control".into())
        .spawn(move || {
            for stream in listener.incoming() {
                let Ok(stream) = stream else { continue };
                let tx = tx.clone();
                // One short-lived thread per connection, so a client that never sends a line
                // cannot block the others.
                let _ = std::thread::Builder::new()
                    .name("control-conn".into())
                    .spawn(move || handle(stream, tx));
            }
        })?;
    Ok(())
}

fn handle(stream: UnixStream, tx: Sender<super::run::Event>) {
    let _ = stream.set_read_timeout(Some(Duration::from_secs(5)));
    let mut line = String::new();
    let mut reader = BufReader::new(&stream);
    if reader.read_line(&mut line).is_err() {
        return;
    }
    let reply = match Command::parse(line.trim()) {
        Err(e) => Err(e),
        Ok(cmd) => {
            let (rtx, rrx) = mpsc::channel();
            if tx.send(super::run::Event::Command((cmd, rtx))).is_err() {
                Err("the run is shutting down".to_string())
            } else {
                rrx.recv_timeout(Duration::from_secs(5))
                    .unwrap_or_else(|_| Err("the run is shutting down".to_string()))
            }
        }
    };
    let mut w = &stream;
    let _ = match reply {
        Ok(text) => write!(w, "ok\n{text}"),
        Err(text) => write!(w, "error\n{text}"),
    };
}

/// The active runs' directories under `base`.
fn active_runs(base: &Path) -> Vec<PathBuf> {
    let mut found: Vec<PathBuf> = std::fs::read_dir(base)
        .map(|entries| {
            entries
                .flatten()
                .map(|e| e.path())
                .filter(|p| serving(p))
                .collect()
        })
        .unwrap_or_default();
    found.sort();
    found
}

/// "ID (name), ID (name), …" of run directories, for choosing among several.
fn describe_runs(dirs: &[PathBuf]) -> String {
    dirs.iter()
        .map(|dir| {
            let id = dir
                .file_name()
                .map(|n| n.to_string_lossy().to_string())
                .unwrap_or_default();
            match session::RunConfig::load(&dir.join("config.toml")) {
                Ok(cfg) => format!("{id} ({})", cfg.run.name),
                Err(_) => id,
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// Finds the run to talk to: `run` (a whole id, or the start of exactly one active run's) if
/// given, else the only active run.
fn find_run(run: Option<&str>) -> anyhow::Result<PathBuf> {
    let base = runs_dir();
    // `supervisor run --run-id 2222` runs as 0000000000002222: the id as it was given names it
    // too.
    let padded = run
        .and_then(|id| pipeline::parse_run_id(id).ok())
        .map(|id| format!("{id:016x}"))
        .filter(|id| base.join(id).exists());
    let run = padded.as_deref().or(run);
    if let Some(prefix) = run.filter(|id| !base.join(id).exists()) {
        let matching: Vec<PathBuf> = active_runs(&base)
            .into_iter()
            .filter(|d| {
                d.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with(prefix))
            })
            .collect();
        match matching.len() {
            0 => {}
            1 => return Ok(matching.into_iter().next().expect("one match")),
            _ => bail!(
                "`{prefix}` is the start of {} active runs' ids: {}",
                matching.len(),
                describe_runs(&matching)
            ),
        }
    }
    if let Some(id) = run {
        let dir = base.join(id);
        if !socket_path(&dir).exists() {
            // A mistyped id is the usual cause: the ids there are what the user wants.
            let active = active_runs(&base);
            let which = match active.len() {
                0 => "there is none".to_string(),
                _ => format!("active: {}", describe_runs(&active)),
            };
            bail!("no active run `{id}` under {} ({which})", base.display());
        }
        if !serving(&dir) {
            bail!(
                "run `{id}` under {} is not active: its supervisor was killed (the next \
                 `supervisor run` removes what it left behind){}",
                base.display(),
                crate::run::unfinished_recording(&dir).map_or(String::new(), |part| format!(
                    "; {}",
                    crate::run::unfinished_text(&part)
                ))
            );
        }
        return Ok(dir);
    }
    let mut found = active_runs(&base);
    match found.len() {
        0 => bail!("no active run under {}", base.display()),
        1 => Ok(found.remove(0)),
        _ => bail!(
            "{} active runs under {}; choose one with --run (the start of its id will do): {}",
            found.len(),
            base.display(),
            describe_runs(&found)
        ),
    }
}

/// How long a command waits for the supervisor's reply.
const REPLY_WAIT: Duration = Duration::from_secs(10);

/// The supervisor's reply on `stream`, until EOF. A supervisor stopped by a signal (Ctrl-Z in
/// its terminal, SIGSTOP) still takes the connection but does not answer; the command waited
/// 10 s and said `Resource temporarily unavailable (os error 11)`. It is now looked for while
/// waiting, and named.
fn read_reply(stream: &mut UnixStream, dir: &Path) -> anyhow::Result<String> {
    use std::io::{ErrorKind, Read};
    let pid = crate::run::supervisor_pid(dir).ok().flatten();
    let who = pid.map_or("the run's supervisor".to_string(), |pid| {
        format!("the run's supervisor (pid {pid})")
    });
    let end = std::time::Instant::now() + REPLY_WAIT;
    stream.set_read_timeout(Some(Duration::from_millis(200)))?;
    let mut reply = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        match stream.read(&mut buf) {
            Ok(0) => return Ok(String::from_utf8_lossy(&reply).into_owned()),
            Ok(n) => reply.extend_from_slice(&buf[..n]),
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                if let Some(pid) = pid.filter(|&pid| crate::run::process_stopped(pid)) {
                    bail!(
                        "{who} is stopped by a signal (Ctrl-Z in its terminal, which suspends \
                         the run's processes with it; SIGSTOP, which leaves them running \
                         unsupervised) and answers no command until it is continued (`fg` in \
                         its terminal, or `kill -CONT {pid}`)"
                    );
                }
                if std::time::Instant::now() >= end {
                    bail!("{who} did not answer within {} s", REPLY_WAIT.as_secs());
                }
            }
            Err(e) => return Err(e).context("reading the supervisor's reply"),
        }
    }
}

/// Sends one command to a running supervisor and returns its reply.
pub fn client(run: Option<&str>, command: &str) -> anyhow::Result<String> {
    let dir = find_run(run)?;
    let path = socket_path(&dir);
    let mut stream = UnixStream::connect(&path).with_context(|| {
        format!(
            "cannot reach the run's supervisor at {} (stale run directory?)",
            path.display()
        )
    })?;
    writeln!(stream, "{command}")?;
    let reply = read_reply(&mut stream, &dir)?;
    match reply.split_once('\n') {
        Some(("ok", text)) => Ok(text.to_string()),
        Some(("error", text)) => bail!("{text}"),
        _ if reply == "ok" => Ok(String::new()),
        _ => bail!("unexpected reply from the supervisor: {reply:?}"),
    }
}
