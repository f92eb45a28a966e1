//! The layers, checked: "the runtime knows no machine; the application knows no wire".
//!
//! - The application crates (`tasks/`: the program interface, kinematics, machines) have nothing
//!   in their dependency tree that touches a wire, a clock, a thread or a terminal (`cargo tree`).
//! - Their sources use no clock, file, thread, network or process of std either (the compiler
//!   cannot see that one: std is always there).
//! - The runtime (`src/`) names a machine crate in one place only, the list of machines.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The application crates.
const APPLICATION_CRATES: &[&str] = &[
    "pkm-api",
    "pkm-drives",
    "pkm-joints",
    "pkm-kinematics",
    "pkm-nc",
    "pkm-trijoint",
];

/// Crates that touch a wire, a clock, a thread or a terminal, or belong to the command line.
const RUNTIME_CRATES: &[&str] = &[
    "pkm-plc",
    "tokio",
    "tokio-serial",
    "tokio-modbus",
    "serialport",
    "mio",
    "clap",
    "evdev",
    "nix",
    "libc",
    "tracing-subscriber",
    "plotters",
    "triple_buffer",
    "flate2",
    "hdrhistogram",
    "vcd",
];

/// The names of every crate in `package`'s normal (non-dev, non-build) dependency tree.
fn dependency_tree(package: &str) -> Vec<String> {
    let out = Command::new(env!("CARGO"))
        .args([
            "tree",
            "--offline",
            "--edges",
            "normal",
            "--prefix",
            "none",
            "--format",
            "{p}",
            "-p",
            package,
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo tree runs");
    assert!(
        out.status.success(),
        "cargo tree -p {package}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .map(str::to_string)
        .collect()
}

#[test]
fn application_crates_depend_on_nothing_that_touches_a_wire_a_clock_or_a_terminal() {
    let mut offences = Vec::new();
    for package in APPLICATION_CRATES {
        let tree = dependency_tree(package);
        assert!(
            tree.iter().any(|c| c == package),
            "{package} is in its own tree: {tree:?}"
        );
        for name in tree.iter().filter(|c| RUNTIME_CRATES.contains(&c.as_str())) {
            offences.push(format!("{package} depends on {name}"));
        }
    }
    assert!(
        offences.is_empty(),
        "application crates must not: {}",
        offences.join("; ")
    );
}

#[test]
fn the_runtime_depends_on_the_application_crates_not_the_reverse() {
    let tree = dependency_tree("pkm-plc");
    for package in APPLICATION_CRATES {
        assert!(tree.iter().any(|c| c == package), "pkm-plc links {package}");
    }
    assert!(
        tree.iter().any(|c| c == "tokio"),
        "the check sees the runtime's crates: {tree:?}"
    );
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("readable directory") {
        let path = entry.expect("directory entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// Lines of the Rust files under `dir` (comments stripped) that contain one of `words`.
fn uses(dir: &str, words: &[&str], allowed: &[&str]) -> Vec<String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(&root.join(dir), &mut files);
    assert!(!files.is_empty(), "{dir} holds Rust files");
    let mut offences = Vec::new();
    for file in files.iter().filter(|f| !allowed.iter().any(|a| f.ends_with(a))) {
        let text = std::fs::read_to_string(file).expect("readable source");
        for (n, line) in text.lines().enumerate() {
            let code = line.split("//").next().unwrap_or("");
            for word in words.iter().filter(|w| code.contains(**w)) {
                offences.push(format!("{}:{}: {word}", file.display(), n + 1));
            }
        }
    }
    offences
}

#[test]
fn the_application_uses_no_clock_file_thread_or_process_of_std() {
    let forbidden = [
        "std::fs",
        "std::net",
        "std::time",
        "std::thread",
        "std::io",
        "std::process",
        "std::env",
        "Instant",
        "SystemTime",
        "println!",
        "eprintln!",
    ];
    let offences = uses("tasks", &forbidden, &[]);
    assert!(
        offences.is_empty(),
        "the application must not use:\n{}",
        offences.join("\n")
    );
}

#[test]
fn the_runtime_names_a_machine_in_the_list_of_machines_only() {
    // The kinematics command of the command line computes any model's kinematics: it may use
    // the kinematics crate, and draws its workspaces; the NC check builds the configured
    // machine's kinematics from the model the machine names (for `nc check` and `run --program`),
    // and so do the screen's jobs (where the tool stands: the kinematics of its set-points).
    let offences = uses(
        "src",
        &["pkm_trijoint", "pkm_joints", "pkm_kinematics"],
        &[
            "src/compose/machines.rs",
            "src/cli/kin.rs",
            "src/cli/kin_svg.rs",
            "src/cli/nc.rs",
            "src/compose/nc_job.rs",
            "src/compose/screen_job.rs",
            "src/services/hmi/mechanism.rs",
        ],
    );
    assert!(
        offences.is_empty(),
        "the runtime must not name a machine:\n{}",
        offences.join("\n")
    );
    let machine_types = uses("src", &["Trijoint", "TRIJOINT_"], &["src/compose/machines.rs"]);
    assert!(
        machine_types.is_empty(),
        "machine types in the runtime:\n{}",
        machine_types.join("\n")
    );
}
