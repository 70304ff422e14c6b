//! Compiles proto/ with the pure-Rust `protox` (no `protoc` binary needed) into a
//! FileDescriptorSet, which is both the input of prost's code generator and the schema data
//! embedded in every recording.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let files = ["pi2cma/record/record.proto", "foxglove/Log.proto"];
    for f in &files {
        println!("cargo:rerun-if-changed=proto/{f}");
    }
    let fds = protox::compile(files, ["proto"])?;
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR")?);
    std::fs::write(
        out.join("descriptors.bin"),
        prost::Message::encode_to_vec(&fds),
    )?;
    prost_build::Config::new().compile_fds(fds)?;
    Ok(())
}
