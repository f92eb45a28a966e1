//! The layers, checked: "the runtime knows no machine; the application knows no wire".
//!
//! - The application crates (`tasks/`: the program interface, kinematics, machines) have nothing
//!   in their dependency tree that touches a wire, a clock, a thread or a terminal (`cargo tree`).
//! - Their sources use no clock, file, thread, network or process of std either (the compiler
//!   cannot see that one: std is always there).
//! - The runtime (`src/`) names a machine crate in one place only, the list of machines.
//! - `src/` is in layers (core, services, composition, command line) whose imports run one way,
//!   and no two modules of a crate import each other.

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
    // The kinematics command of the command line (its arguments name a model) computes any
    // model's kinematics: it may use
    // the kinematics crate, and draws its workspaces; the NC check builds the configured
    // machine's kinematics from the model the machine names (for `nc check` and `run --program`),
    // and so do the screen's jobs (where the tool stands: the kinematics of its set-points).
    let offences = uses(
        "src",
        &["pkm_trijoint", "pkm_joints", "pkm_kinematics"],
        &[
            "src/compose/machines.rs",
            "src/compose/setup.rs",
            "src/cli/args.rs",
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

/// The runtime's layers, lowest first: a module may import from its own layer and those below.
/// The command line (`src/cli/`, `src/main.rs`) is the binary's, above them all.
const LAYERS: &[&str] = &["runtime", "services", "compose", "cli"];

/// A module of `src/` by its path (`["services", "hmi", "server"]`), with its file.
struct Module {
    path: Vec<String>,
    file: PathBuf,
}

/// Every module of the crate whose sources are in `dir` (`src`, `tasks/nc/src`) but its roots.
fn modules(dir: &str) -> Vec<Module> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join(dir);
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files
        .into_iter()
        .filter_map(|file| {
            let rel = file.strip_prefix(&src).ok()?.with_extension("");
            let mut path: Vec<String> = rel.iter().map(|p| p.to_string_lossy().into_owned()).collect();
            if path.last().is_some_and(|l| l == "mod") {
                path.pop();
            }
            (!path.is_empty() && path != ["lib"] && path != ["main"]).then_some(Module { path, file })
        })
        .collect()
}

/// The module paths that `text` (the code of module `at`, before its tests) names through
/// `crate::` and `super::`, each as written (it may go on into an item).
fn named_paths(text: &str, at: &[String]) -> Vec<Vec<String>> {
    let code: String = text
        .split("#[cfg(test)]")
        .next()
        .unwrap_or("")
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n");
    let ident = |s: &str| s.chars().all(|c| c.is_alphanumeric() || c == '_') && !s.is_empty();
    let mut out = Vec::new();
    for (i, _) in code.match_indices("::") {
        let head_start = code[..i]
            .rfind(|c: char| !(c.is_alphanumeric() || c == '_'))
            .map_or(0, |k| k + 1);
        let head = &code[head_start..i];
        let preceded = code[..head_start].ends_with("::");
        if preceded || !(head == "crate" || head == "super") {
            continue;
        }
        let mut base: Vec<String> = if head == "crate" {
            Vec::new()
        } else {
            at[..at.len().saturating_sub(1)].to_vec()
        };
        let rest = &code[i + 2..];
        let end = rest
            .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
            .unwrap_or(rest.len());
        for part in rest[..end].split("::").filter(|p| !p.is_empty()) {
            if part == "super" {
                base.pop();
            } else if ident(part) {
                base.push(part.to_string());
            }
        }
        // `crate::a::{b, c::d}`: each member of the group.
        if rest[end..].starts_with('{') {
            let group = &rest[end + 1..rest[end..].find('}').map_or(end + 1, |k| end + k)];
            for member in group.split(',') {
                let member = member.split(" as ").next().unwrap_or("").trim();
                if member.is_empty() || member == "self" {
                    continue;
                }
                let mut path = base.clone();
                path.extend(member.split("::").filter(|p| ident(p)).map(str::to_string));
                out.push(path);
            }
        }
        out.push(base);
    }
    out
}

/// The module `path` names: its longest prefix that is a module.
fn resolve<'a>(path: &[String], modules: &'a [Module]) -> Option<&'a Module> {
    (1..=path.len())
        .rev()
        .find_map(|k| modules.iter().find(|m| m.path == path[..k]))
}

/// Each module of the crate in `dir` with the modules it imports (not itself, not its tests).
fn imports(dir: &str) -> Vec<(String, Vec<String>)> {
    let modules = modules(dir);
    modules
        .iter()
        .map(|m| {
            let text = std::fs::read_to_string(&m.file).expect("readable source");
            let mut to: Vec<String> = named_paths(&text, &m.path)
                .iter()
                .filter_map(|p| resolve(p, &modules))
                .filter(|t| t.path != m.path)
                .map(|t| t.path.join("/"))
                .collect();
            to.sort();
            to.dedup();
            (m.path.join("/"), to)
        })
        .collect()
}

fn layer(module: &str) -> Option<usize> {
    LAYERS.iter().position(|l| module.split('/').next() == Some(*l))
}

#[test]
fn src_is_in_layers_and_imports_run_downwards() {
    let imports = imports("src");
    assert!(
        imports.len() > 50 && imports.iter().all(|(m, _)| layer(m).is_some()),
        "every module of src/ is in a layer ({LAYERS:?}): {:?}",
        imports
            .iter()
            .filter(|(m, _)| layer(m).is_none())
            .map(|(m, _)| m)
            .collect::<Vec<_>>()
    );
    let upward: Vec<String> = imports
        .iter()
        .flat_map(|(m, to)| {
            to.iter()
                .filter(|t| layer(t) > layer(m))
                .map(move |t| format!("{m} → {t}"))
        })
        .collect();
    assert!(upward.is_empty(), "imports against the layers:\n{}", upward.join("\n"));
    // The check sees imports: the composition builds on the services and the core.
    let compose = imports.iter().find(|(m, _)| m == "compose").expect("compose");
    assert!(
        compose.1.iter().any(|t| t.starts_with("services/")) && compose.1.iter().any(|t| t.starts_with("runtime/")),
        "{compose:?}"
    );
}

#[test]
fn no_two_modules_of_a_crate_import_each_other() {
    let crates = [
        "src",
        "tasks/api/src",
        "tasks/drives/src",
        "tasks/joints/src",
        "tasks/kinematics/src",
        "tasks/nc/src",
        "tasks/trijoint/src",
    ];
    let mut circles = Vec::new();
    for dir in crates {
        let imports = imports(dir);
        assert!(
            imports.iter().any(|(_, to)| !to.is_empty()),
            "{dir}: the check sees imports"
        );
        for (a, to) in &imports {
            for b in to.iter().filter(|b| a < *b) {
                if imports.iter().any(|(m, back)| m == b && back.contains(a)) {
                    circles.push(format!("{dir}: {a} ⇄ {b}"));
                }
            }
        }
    }
    assert!(circles.is_empty(), "two-module circles:\n{}", circles.join("\n"));
}
