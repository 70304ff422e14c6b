//! Fixtures that the analysis' unit tests share: a [`Recording`] in memory with given eval
//! costs and a task change. Test-only; nothing here reads or writes a file.

use crate::{proto, Recording};

pub(super) fn rec_with(costs: &[f64], change: Option<u64>) -> Recording {
    let mut r = Recording::default();
    if let Some(u) = change {
        let c = proto::TaskChange {
            update: u,
            ..Default::default()
        };
        r.digest.add_task_change(&c);
        r.task_changes.push(c);
    }
    for (u, c) in costs.iter().enumerate() {
        r.digest.add_update(&proto::Update {
            update: u as u64,
            eval_cost: *c,
            lambda: 1.0,
            ..Default::default()
        });
    }
    r
}
