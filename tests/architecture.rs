//! "The application knows no wire": the code under tasks/ never touches a clock, a file, a
//! thread, the network or the runtime's drivers. It uses the program interface only.

use std::path::Path;

const FORBIDDEN: &[&str] = &[
    "std::fs",
    "std::net",
    "std::time",
    "std::thread",
    "std::io",
    "std::process",
    "std::env",
    "Instant",
    "SystemTime",
    "tokio",
    "println!",
    "eprintln!",
    "crate::bus",
    "crate::run",
    "crate::timing",
    "crate::status",
    "crate::plc",
    "crate::config",
];

fn rust_files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("readable directory") {
        let path = entry.expect("directory entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn the_application_uses_no_clock_file_thread_or_wire() {
    let mut files = Vec::new();
    rust_files(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tasks"), &mut files);
    assert!(!files.is_empty());
    let mut offences = Vec::new();
    for file in &files {
        let text = std::fs::read_to_string(file).expect("readable source");
        for (n, line) in text.lines().enumerate() {
            let code = line.split("//").next().unwrap_or("");
            for word in FORBIDDEN {
                if code.contains(word) {
                    offences.push(format!("{}:{}: {word}", file.display(), n + 1));
                }
            }
        }
    }
    assert!(
        offences.is_empty(),
        "the application must not use:\n{}",
        offences.join("\n")
    );
}
