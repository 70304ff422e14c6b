//! tools/pi2cma_worker.py, the rollout worker for Python users, declares the wire structs it
//! sends and receives as ctypes Structures of its own, with the iceoryx2 type names it opens the
//! services by. Nothing in the build ties them to this crate: a field added, moved or retyped
//! here and not there makes the worker read other numbers, or not connect at all. This test
//! imports the worker module in Python and holds each of its Structures to the Rust struct of
//! the same name: type name, size, alignment, and every field's name, order, offset and size.
//!
//! What it is not: a test of the protocol (the end-to-end tests run the worker), nor of which
//! structs the worker needs. Needs python3 with `python3 -m pip install -r tools/requirements.txt`
//! (the worker imports iceoryx2), as tests/python_reader.rs does.

mod structs;

use std::path::PathBuf;
use std::process::Command;

use structs::rust_structs;

/// Prints each ctypes Structure of the worker module (the base class excepted) as a line
/// `struct NAME TYPE_NAME SIZE ALIGN`, then its fields in declaration order as
/// `field NAME OFFSET SIZE`.
const LIST_STRUCTS: &str = r#"
import ctypes, sys
sys.path.insert(0, sys.argv[1])
import pi2cma_worker as w
for name, t in vars(w).items():
    # A module variable bound to a class (a loop's) is not another declaration of it.
    if isinstance(t, type) and issubclass(t, ctypes.Structure) and t is not w.WireStruct \
            and t.__name__ == name:
        print("struct", name, t.type_name(), ctypes.sizeof(t), ctypes.alignment(t))
        for field in t._fields_:
            d = getattr(t, field[0])
            print("field", field[0], d.offset, d.size)
"#;

/// A Structure as the worker declares it.
#[derive(Debug, Default)]
struct PyStruct {
    name: String,
    type_name: String,
    size: usize,
    align: usize,
    fields: Vec<(String, usize, usize)>,
}

fn parse(listing: &str) -> Vec<PyStruct> {
    let mut structs: Vec<PyStruct> = Vec::new();
    for line in listing.lines() {
        let words: Vec<&str> = line.split_whitespace().collect();
        let number = |i: usize| -> usize {
            words
                .get(i)
                .and_then(|w| w.parse().ok())
                .unwrap_or_else(|| panic!("not a number at word {i}: {line:?}"))
        };
        match words.first() {
            Some(&"struct") => structs.push(PyStruct {
                name: words[1].to_string(),
                type_name: words[2].to_string(),
                size: number(3),
                align: number(4),
                ..PyStruct::default()
            }),
            Some(&"field") => structs
                .last_mut()
                .expect("a field after its struct")
                .fields
                .push((words[1].to_string(), number(2), number(3))),
            _ => panic!("unexpected line from the listing: {line:?}"),
        }
    }
    structs
}

#[test]
fn the_python_worker_declares_each_struct_with_the_rust_layout_and_type_name() {
    let tools = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tools");
    let out = Command::new("python3")
        .arg("-c")
        .arg(LIST_STRUCTS)
        .arg(&tools)
        .output()
        .expect("python3 starts (then: python3 -m pip install -r tools/requirements.txt)");
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(
        out.status.success(),
        "importing tools/pi2cma_worker.py failed (are tools/requirements.txt installed?)\n\
         {stdout}\n{stderr}"
    );
    let python = parse(&stdout);
    // The worker's four: what it receives (WorkHeader) and sends (CostHeader, Ready, Lifecycle).
    assert!(python.len() >= 4, "{python:?}");
    let rust = rust_structs();
    let mut problems = Vec::new();
    for p in &python {
        let name = &p.name;
        let Some(r) = rust.iter().find(|r| r.name == name) else {
            problems.push(format!(
                "{name}: declared in pi2cma_worker.py, not a wire struct"
            ));
            continue;
        };
        if (p.type_name.as_str(), p.size, p.align) != (r.type_name.as_str(), r.size, r.align) {
            problems.push(format!(
                "{name}: pi2cma_worker.py has type name `{}`, {} B aligned to {}; Rust's is \
                 `{}`, {} B aligned to {}",
                p.type_name, p.size, p.align, r.type_name, r.size, r.align
            ));
        }
        // Rust's fields in memory order, as ctypes lays out its own in declaration order.
        let mut fields: Vec<(String, usize, usize)> = r
            .fields
            .iter()
            .map(|(f, offset, size)| (f.to_string(), *offset, *size))
            .collect();
        fields.sort_by_key(|f| f.1);
        if p.fields != fields {
            let show = |fields: &[(String, usize, usize)]| {
                fields
                    .iter()
                    .map(|(f, offset, size)| format!("{f}@{offset}:{size}"))
                    .collect::<Vec<_>>()
                    .join(" ")
            };
            problems.push(format!(
                "{name}: pi2cma_worker.py's fields (name@offset:size)\n  {}\nRust's\n  {}",
                show(&p.fields),
                show(&fields)
            ));
        }
    }
    assert!(problems.is_empty(), "\n{}\n", problems.join("\n"));
}
