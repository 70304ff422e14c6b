//! Library side of the `pi2cma` command: experiments over configs and seeds, their CSV output
//! and figures, and the update benchmarks. It drives the core through the `session` crate's
//! in-process executor; it is not the multiprocess pipeline.

#![warn(missing_docs)]

pub mod bench;
pub mod experiment;
pub mod figures;
