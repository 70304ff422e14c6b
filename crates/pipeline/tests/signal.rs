//! SIGTERM is seen by every later check, not only by the first: iceoryx2 hands its signal flag
//! out once. (A test binary of its own: the signal stays with the process.)

use std::time::{Duration, Instant};

#[test]
fn a_termination_request_stays_seen() {
    assert!(!pipeline::termination_requested(), "installs the handler");
    let sent = std::process::Command::new("kill")
        .args(["-TERM", &std::process::id().to_string()])
        .status()
        .expect("kill runs");
    assert!(sent.success());
    let end = Instant::now() + Duration::from_secs(10);
    while !pipeline::termination_requested() {
        assert!(Instant::now() < end, "SIGTERM never seen");
        std::thread::sleep(Duration::from_millis(1));
    }
    for _ in 0..3 {
        assert!(pipeline::termination_requested(), "seen once, then lost");
    }
}
