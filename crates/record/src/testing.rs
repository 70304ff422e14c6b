//! Fixtures the crate's unit tests share: an in-process session recorded to a file. Test-only.

use std::path::Path;

/// Runs `cfg` in-process with `seed`, recorded to a finished MCAP file at `path`; returns the
/// run's final distribution.
pub(crate) fn record_session(
    cfg: &session::RunConfig,
    seed: u64,
    path: &Path,
) -> pi2cma::Distribution {
    let mut rec = crate::McapRecorder::create(path).unwrap();
    let (_, last) = session::run_session(cfg, seed, &mut rec).unwrap();
    rec.finish().unwrap();
    last
}
