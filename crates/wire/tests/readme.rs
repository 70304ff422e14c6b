//! README.md's "Wire layout (for workers in other languages)" is the wire contract as a worker
//! or tool in C, C++ or Python reads it: it builds its structs from that section's C block and
//! opens services by the names, type names and sizes of its table. Nothing in the build ties
//! that text to this crate, so this tidy test (after rust-analyzer's) fails when either changes
//! alone:
//!
//! - the table: every service the crate's functions open, opened as a process of a run opens
//!   it, has a row whose name, payload and user header are what iceoryx2 recorded for it (the
//!   type name and size a foreign process must match to connect); every row is such a service;
//! - the C block: each `#[repr(C)]` struct of the crate is declared, and the C layout of the
//!   declared field types (natural alignment) puts every field where `offset_of!` has it, with
//!   the struct's size and alignment and, as the section promises, no padding;
//! - the crate itself: every `#[repr(C)]` struct in src/lib.rs, with all its fields, and every
//!   public function that opens a service is known to this test, so a new one cannot go
//!   unchecked (and undocumented).
//!
//! What it is not: a test of the protocol (the end-to-end tests run it), nor of
//! tools/pi2cma_worker.py's ctypes declarations (tests/python_worker.rs checks those).

mod structs;

use std::collections::BTreeSet;

use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe;
use iceoryx2::service::static_config::message_type_details::{TypeDetail, TypeVariant};
use structs::rust_structs;

const README: &str = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/../../README.md"));
const LIB: &str = include_str!("../src/lib.rs");
const SECTION: &str = "### Wire layout (for workers in other languages)";

/// The worker slot the table's `<w>` stands for here.
const W: u32 = 3;

/// The README section, up to the next heading.
fn section() -> &'static str {
    let start = README
        .find(SECTION)
        .expect("README.md has the wire layout section");
    let rest = &README[start + SECTION.len()..];
    let end = ["\n## ", "\n### "]
        .iter()
        .filter_map(|h| rest.find(h))
        .min()
        .unwrap_or(rest.len());
    &rest[..end]
}

/// A row of the section's table: `| service | payload | user header | direction |`.
struct Row {
    service: &'static str,
    payload: &'static str,
    header: &'static str,
    direction: &'static str,
}

fn rows() -> Vec<Row> {
    section()
        .lines()
        .filter(|l| l.starts_with("| `"))
        .map(|l| {
            let cells: Vec<&str> = l.trim_matches('|').splitn(4, " | ").collect();
            assert!(cells.len() == 4, "README table row with fewer cells: {l}");
            Row {
                service: cells[0].trim().trim_matches('`'),
                payload: cells[1].trim(),
                header: cells[2].trim(),
                direction: cells[3].trim_end_matches(" |").trim(),
            }
        })
        .collect()
}

/// A type as a table cell gives it: `` `Name` (`type.name`, 184 B) ``.
#[derive(Debug)]
struct Typed<'a> {
    name: &'a str,
    type_name: &'a str,
    size: usize,
}

fn typed(cell: &str) -> Option<Typed<'_>> {
    let (name, rest) = cell.strip_prefix('`')?.split_once('`')?;
    let (type_name, rest) = rest.strip_prefix(" (`")?.split_once("`, ")?;
    let (size, _) = rest.split_once(" B)")?;
    Some(Typed {
        name,
        type_name,
        size: size.parse().ok()?,
    })
}

/// A service of a run as iceoryx2 recorded it when the crate's function opened it: the types
/// every process that opens it must match.
struct Opened {
    function: &'static str,
    name: String,
    payload: TypeDetail,
    header: TypeDetail,
}

fn opened<P, H>(
    function: &'static str,
    service: publish_subscribe::PortFactory<wire::Service, P, H>,
) -> Opened
where
    P: std::fmt::Debug + IceoryxSend + ?Sized,
    H: std::fmt::Debug + ZeroCopySend,
{
    let types = service.static_config().message_type_details();
    Opened {
        function,
        name: service.name().as_str().to_string(),
        payload: types.payload,
        header: types.user_header,
    }
}

/// Opens `wire::<function>(args)`; evaluates to (function name, what was opened).
macro_rules! open {
    ($f:ident($($arg:expr),*)) => {
        opened(
            stringify!($f),
            wire::$f($($arg),*).unwrap_or_else(|e| panic!("wire::{}: {e}", stringify!($f))),
        )
    };
}

/// Removes the test run's iceoryx2 directory and shared memory (iceoryx2 leaves its
/// management segment behind), also when an assertion failed.
struct RunFiles(u64);

impl Drop for RunFiles {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(wire::iceoryx_root(self.0));
        let prefix = wire::file_prefix(self.0);
        for file in std::fs::read_dir("/dev/shm")
            .into_iter()
            .flatten()
            .flatten()
        {
            if file.file_name().to_string_lossy().starts_with(&prefix) {
                let _ = std::fs::remove_file(file.path());
            }
        }
    }
}

/// The crate's public functions that open a service of a run (they return its port factory).
fn service_functions() -> BTreeSet<&'static str> {
    LIB.split("\npub fn ")
        .skip(1)
        .filter_map(|f| {
            let signature = &f[..f.find('{')?];
            let returns = signature.split_once("-> ")?.1;
            let opens = [
                "SliceService<",
                "FixedService<",
                "CountService<",
                "EventService",
            ]
            .iter()
            .any(|t| returns.contains(t));
            opens.then(|| &f[..f.find('(').unwrap_or(0)])
        })
        .collect()
}

#[test]
fn the_readme_table_gives_every_service_with_its_name_and_types() {
    // A run id of this test's own (see crates/supervisor/tests/e2e.rs, `run_id`).
    let run = (u64::from(std::process::id()) << 20) ^ 5700;
    let _files = RunFiles(run);
    let node = wire::node(run, "readme-test").expect("node");
    let limits = wire::Limits {
        max_workers: 4,
        rollouts: 5,
        dim: 2,
        steps: 11,
    };
    let l = &limits;
    let services = vec![
        open!(distribution(&node, run, l)),
        open!(work(&node, run, W, l)),
        open!(costs(&node, run, l)),
        open!(ready(&node, run, l)),
        open!(overdue(&node, run, l)),
        open!(progress(&node, run, l)),
        open!(recorded(&node, run, l)),
        open!(lifecycle(&node, run, l)),
        open!(joined(&node, run, l)),
        open!(control(&node, run, l)),
        open!(reruns(&node, run, l)),
        open!(notes(&node, run, l)),
    ];
    let prefix = format!("pi2cma/{}/", wire::run_id_hex(run));
    let row_name = |row: &Row| format!("{prefix}{}", row.service.replace("<w>", &W.to_string()));
    let rows = rows();
    let mut problems = Vec::new();

    for s in &services {
        let Some(row) = rows.iter().find(|r| row_name(r) == s.name) else {
            problems.push(format!(
                "wire::{} opens `{}`, which README's table does not list (rows: {})",
                s.function,
                s.name,
                rows.iter()
                    .map(|r| r.service)
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
            continue;
        };
        let mut compare = |what: &str, cell: &str, detail: &TypeDetail| {
            let (type_name, size) = (detail.type_name().to_string(), detail.size());
            if let Some(element) = cell.strip_prefix("`[").and_then(|c| c.split_once("]`")) {
                if detail.variant() != TypeVariant::Dynamic || element.0 != type_name {
                    problems.push(format!(
                        "`{}` {what}: README says a slice of {}, the crate sends {type_name} \
                         ({:?})",
                        row.service,
                        element.0,
                        detail.variant()
                    ));
                }
            } else if cell == "–" {
                if size != 0 {
                    problems.push(format!(
                        "`{}` {what}: README says none, the crate's is `{type_name}`, {size} B",
                        row.service
                    ));
                }
            } else {
                match typed(cell) {
                    Some(t) if t.type_name == type_name && t.size == size => {}
                    Some(t) => problems.push(format!(
                        "`{}` {what}: README says `{}`, {} B; the crate's is `{type_name}`, \
                         {size} B",
                        row.service, t.type_name, t.size
                    )),
                    None => problems.push(format!(
                        "`{}` {what}: README's cell `{cell}` is not `Name` (`type name`, N B); \
                         the crate's is `{type_name}`, {size} B",
                        row.service
                    )),
                }
            }
        };
        compare("payload", row.payload, &s.payload);
        compare("user header", row.header, &s.header);
    }

    // Doorbells: one event service per receiving process.
    let owners = [
        wire::process::UPDATER.to_string(),
        wire::process::SAMPLER.to_string(),
        wire::process::SUPERVISOR.to_string(),
        wire::process::RECORDER.to_string(),
        wire::worker_doorbell(W),
    ];
    let doorbells: Vec<String> = owners
        .iter()
        .map(|owner| {
            let bell = wire::doorbell(&node, run, owner, l).expect("doorbell");
            let name = bell.name().as_str();
            name.strip_prefix(&prefix).unwrap_or(name).to_string()
        })
        .collect();
    match rows.iter().find(|r| r.service == "wake/<owner>") {
        None => problems.push("README's table has no `wake/<owner>` row".into()),
        Some(row) => {
            let owners = row.direction.split_once("doorbell of ").map_or("", |o| o.1);
            let listed: Vec<String> = owners
                .split(", ")
                .map(|o| {
                    format!(
                        "wake/{}",
                        o.trim_matches('`').replace("<w>", &W.to_string())
                    )
                })
                .collect();
            if listed != doorbells {
                problems.push(format!(
                    "`wake/<owner>`: README lists {listed:?}, the crate's doorbells are \
                     {doorbells:?}"
                ));
            }
            for (id, name) in [(wire::WAKE, "WAKE"), (wire::HOLD, "HOLD")] {
                let said = format!("{} (`{name}`", id.as_value());
                if !row.payload.contains(&said) {
                    problems.push(format!(
                        "`wake/<owner>`: README does not give event id {said}`): {}",
                        row.payload
                    ));
                }
            }
        }
    }

    // Every row is a service of the crate, and every service function was opened above.
    for row in &rows {
        let known =
            row.service == "wake/<owner>" || services.iter().any(|s| s.name == row_name(row));
        if !known {
            problems.push(format!(
                "README's table lists `{}`, which no function of the crate opens",
                row.service
            ));
        }
    }
    let mut tested: BTreeSet<&str> = services.iter().map(|s| s.function).collect();
    tested.insert("doorbell");
    let functions = service_functions();
    for gone in tested.difference(&functions) {
        problems.push(format!(
            "wire::{gone} is opened here, but src/lib.rs shows no such service function: \
             service_functions() no longer reads the source right"
        ));
    }
    for new in functions.difference(&tested) {
        problems.push(format!(
            "wire::{new} opens a service this test does not: open it here and give it a row in \
             README's table"
        ));
    }
    assert!(problems.is_empty(), "\n{}\n", problems.join("\n"));
}

/// A struct of the README's C block, laid out as a C compiler does (natural alignment).
#[derive(Debug)]
struct CStruct {
    name: String,
    size: usize,
    align: usize,
    /// Name, offset, and the padding before it.
    fields: Vec<(String, usize, usize)>,
}

/// Size (= alignment) of the C types the block may use.
fn c_scalar(ty: &str) -> Option<usize> {
    Some(match ty {
        "uint8_t" | "int8_t" | "char" => 1,
        "uint16_t" | "int16_t" => 2,
        "uint32_t" | "int32_t" | "float" => 4,
        "uint64_t" | "int64_t" | "double" => 8,
        _ => return None,
    })
}

fn c_structs() -> Vec<CStruct> {
    let block = section()
        .split_once("```c\n")
        .and_then(|(_, rest)| rest.split_once("\n```"))
        .expect("README's wire layout section has a ```c block")
        .0;
    // Comments out, then one `struct Name { declarations };` after another.
    let mut text = String::new();
    let mut rest = block;
    while let Some((before, after)) = rest.split_once("/*") {
        text.push_str(before);
        rest = after.split_once("*/").map_or("", |(_, a)| a);
    }
    text.push_str(rest);
    text.split("struct ")
        .skip(1)
        .map(|s| {
            let (name, body) = s.split_once('{').expect("struct Name {");
            let name = name.trim().to_string();
            let body = body.split_once("};").expect("struct ends with };").0;
            let (mut offset, mut align, mut fields) = (0usize, 1, Vec::new());
            for declaration in body.split(';').map(str::trim).filter(|d| !d.is_empty()) {
                let (ty, names) = declaration
                    .split_once(char::is_whitespace)
                    .expect("type names");
                let size = c_scalar(ty)
                    .unwrap_or_else(|| panic!("README struct {name}: unknown C type {ty}"));
                for declarator in names.split(',').map(str::trim) {
                    let (field, count) = match declarator.split_once('[') {
                        Some((f, n)) => (f.trim(), n.trim_end_matches(']').parse().expect("[N]")),
                        None => (declarator, 1),
                    };
                    let at = offset.next_multiple_of(size);
                    fields.push((field.to_string(), at, at - offset));
                    offset = at + size * count;
                    align = align.max(size);
                }
            }
            CStruct {
                name,
                size: offset.next_multiple_of(align),
                align,
                fields,
            }
        })
        .collect()
}

/// The README's name for a Rust field: C has no use for Rust's "unused" underscore.
fn c_name(rust_field: &str) -> &str {
    rust_field.trim_start_matches('_')
}

#[test]
fn the_readme_declares_every_struct_with_the_rust_layout() {
    let c = c_structs();
    let table: Vec<Typed> = rows()
        .iter()
        .flat_map(|r| [typed(r.payload), typed(r.header)])
        .flatten()
        .collect();
    let rust = rust_structs();
    let mut problems = Vec::new();
    for r in &rust {
        let name = r.name;
        match table.iter().find(|t| t.name == name) {
            None => problems.push(format!("{name}: not in README's table")),
            Some(t) if t.type_name != r.type_name || t.size != r.size => problems.push(format!(
                "{name}: README's table says `{}`, {} B; Rust's is `{}`, {} B",
                t.type_name, t.size, r.type_name, r.size
            )),
            Some(_) => {}
        }
        let Some(cs) = c.iter().find(|s| s.name == name) else {
            problems.push(format!("{name}: not declared in README's C block"));
            continue;
        };
        if (cs.size, cs.align) != (r.size, r.align) {
            problems.push(format!(
                "{name}: README's C declaration is {} B aligned to {}; Rust's struct is {} B \
                 aligned to {}",
                cs.size, cs.align, r.size, r.align
            ));
        }
        for (field, rust_offset, _) in &r.fields {
            match cs.fields.iter().find(|f| f.0 == c_name(field)) {
                None => problems.push(format!(
                    "{name}.{field}: missing from README's C declaration (Rust offset \
                     {rust_offset})"
                )),
                Some((_, offset, _)) if offset != rust_offset => problems.push(format!(
                    "{name}.{field}: README offset {offset}, Rust offset {rust_offset}"
                )),
                Some(_) => {}
            }
        }
        for (field, offset, padding) in &cs.fields {
            if !r.fields.iter().any(|(f, _, _)| c_name(f) == field) {
                problems.push(format!(
                    "{name}.{field}: in README's C declaration (offset {offset}), not in Rust's"
                ));
            }
            if *padding > 0 {
                problems.push(format!(
                    "{name}.{field}: README's C declaration has {padding} B of padding before \
                     it; the section promises none"
                ));
            }
        }
    }
    for s in &c {
        if !rust.iter().any(|r| r.name == s.name) {
            problems.push(format!(
                "README's C block declares {}, not a wire struct",
                s.name
            ));
        }
    }
    assert!(problems.is_empty(), "\n{}\n", problems.join("\n"));
}

/// The `#[repr(C)]` structs of src/lib.rs with their field names, from the source: what
/// `rust_structs!` must list.
fn repr_c_structs_in_source() -> Vec<(&'static str, Vec<&'static str>)> {
    LIB.split("\n#[repr(C)]\n")
        .skip(1)
        .map(|s| {
            let s = s.split_once("pub struct ").expect("a struct follows").1;
            let (name, body) = s.split_once(" {").expect("pub struct Name {");
            let body = body.split_once("\n}").expect("struct ends").0;
            let fields = body
                .lines()
                .filter_map(|l| l.trim().strip_prefix("pub ")?.split_once(':'))
                .map(|(field, _)| field)
                .collect();
            (name, fields)
        })
        .collect()
}

#[test]
fn every_repr_c_struct_of_the_crate_is_checked() {
    let in_source = repr_c_structs_in_source();
    assert!(in_source.len() >= 11, "{in_source:?}");
    let listed = rust_structs();
    let mut problems = Vec::new();
    for (name, fields) in &in_source {
        let fields: BTreeSet<&str> = fields.iter().copied().collect();
        let known = listed.iter().find(|r| r.name == *name);
        let known_fields = known.map(|r| r.fields.iter().map(|f| f.0).collect::<BTreeSet<_>>());
        if known_fields.as_ref() != Some(&fields) {
            problems.push(format!(
                "src/lib.rs has #[repr(C)] {name} {{ {} }}; rust_structs! here lists {:?}: \
                 list all its fields (and declare them in README's wire layout)",
                fields.iter().copied().collect::<Vec<_>>().join(", "),
                known_fields.unwrap_or_default()
            ));
        }
    }
    assert!(problems.is_empty(), "\n{}\n", problems.join("\n"));
    assert_eq!(
        listed.len(),
        in_source.len(),
        "rust_structs! lists a struct that src/lib.rs no longer has as #[repr(C)]"
    );
}
