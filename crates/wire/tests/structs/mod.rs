//! The `#[repr(C)]` structs of the wire contract as Rust lays them out, for the tests that hold
//! other declarations of them to it (README's C block: readme.rs; the Python worker's ctypes
//! structs: python_worker.rs).

use std::mem::{align_of, offset_of, size_of};

use iceoryx2::service::static_config::message_type_details::{TypeDetail, TypeVariant};

/// A `#[repr(C)]` type of the contract as Rust lays it out.
pub struct RustStruct {
    pub name: &'static str,
    /// The name iceoryx2 matches the type by (`#[type_name]`).
    pub type_name: String,
    pub size: usize,
    pub align: usize,
    /// Name, offset and size of each field, as listed in `rust_structs!`.
    pub fields: Vec<(&'static str, usize, usize)>,
}

/// Each struct with all its fields: one the crate no longer has is a compile error, one it has
/// more of fails readme.rs's `every_repr_c_struct_of_the_crate_is_checked`.
macro_rules! rust_structs {
    ($($t:ident { $($f:ident),* $(,)? })*) => {
        vec![$(RustStruct {
            name: stringify!($t),
            type_name: TypeDetail::new::<wire::$t>(TypeVariant::FixedSize).type_name().to_string(),
            size: size_of::<wire::$t>(),
            align: align_of::<wire::$t>(),
            fields: vec![$((
                stringify!($f),
                offset_of!(wire::$t, $f),
                size_of_field(|s: &wire::$t| &s.$f),
            )),*],
        }),*]
    };
}

pub fn rust_structs() -> Vec<RustStruct> {
    rust_structs! {
        DistributionHeader {
            run_id, update, seed, dim, rollouts, steps, flags, settings_len, _reserved, lambda,
            settings, previous_settings,
        }
        WorkHeader {
            run_id, update, chunk, rollout, chunk_len, worker, steps, settings_len, flags,
            settings, previous_settings,
        }
        CostHeader {
            run_id, update, rollout, worker, duration_ns, terminal, start_ns, settings_len,
            _reserved, settings,
        }
        Ready { run_id, chunk, worker, incarnation, pid, flags }
        Overdue {
            run_id, update, chunk, held_ms, stalled_ms, worker, incarnation, rollouts, _reserved,
        }
        Progress {
            run_id, updates, elapsed_ns, eval_cost, lambda, flags, settings_len, settings,
            last_change_seq, last_change_from, refused, last_refused_setting,
            last_refused_value, last_refused_update, rollouts_done, rollouts,
        }
        RecorderAck { run_id, next_update, taken, synced }
        Lifecycle { run_id, pid, role, worker, incarnation }
        Control { run_id, kind, worker, incarnation, reason, name_len, pid, name, value, seq, sent }
        RerunHeader { run_id, update }
        RunNote { run_id, level, text_len, text }
    }
}

/// The size of the field `field` projects to, without a value of its struct.
fn size_of_field<S, F>(_field: impl Fn(&S) -> &F) -> usize {
    size_of::<F>()
}
