//! The program that planned to NaN (four lines of a few millimetres at F6000 near home) through
//! every entry point but the screen's MDI (`nc_jobs.rs`): `nc check` on every machine, `run
//! --program`, and a `--programs` library beside files that do not read or plan, which are not
//! offered, with why, while the PLC starts.

use crate::common;

use common::{pkm, stderr, stdout};

/// The program of the report: more than half of such random programs planned to NaN on every
/// machine before the planner was rewritten, and this one took the PLC down.
pub const NAN_PROGRAM: &str =
    "G1 X1.791 Y0.907 F6000\nG1 X-3.581 Y3.181 F6000\nG1 X-2.717 Y2.844 F6000\nG1 X-4.204 Y2.846 F6000\nM2\n";

const MACHINES: [&str; 5] = ["trijoint", "pn101", "ox-x", "ox-o", "hexapod"];

#[test]
fn nc_check_plans_it_finite_on_every_machine() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("nan.ngc");
    std::fs::write(&file, NAN_PROGRAM).expect("write");
    let file = file.to_str().expect("utf-8");
    for machine in MACHINES {
        let json = dir.path().join(format!("{machine}.json"));
        let o = pkm(&[
            "nc",
            "check",
            file,
            "--machine",
            machine,
            "--json",
            json.to_str().expect("utf-8"),
        ]);
        assert_eq!(o.status.code(), Some(0), "{machine}: {}", stderr(&o));
        assert!(!stdout(&o).contains("NaN"), "{machine}: {}", stdout(&o));
        let r = common::read_json(&json);
        let planned = r["planned_time_s"].as_f64().expect("a number");
        // 16.0 mm of lines at 100 mm/s at the most, from rest to rest at every reversal.
        assert!(planned > 0.16 && planned < 10.0, "{machine}: planned {planned} s");
    }
}

#[test]
fn run_program_runs_it_to_its_end() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("nan.ngc");
    std::fs::write(&file, NAN_PROGRAM).expect("write");
    for machine in ["ox-x", "hexapod"] {
        let summary = dir.path().join(format!("{machine}.summary.json"));
        let o = pkm(&[
            "run",
            "--virtual",
            "--duration",
            "40",
            "--machine",
            machine,
            "--program",
            file.to_str().expect("utf-8"),
            "--summary",
            summary.to_str().expect("utf-8"),
        ]);
        assert_eq!(o.status.code(), Some(0), "{machine}: {}", stderr(&o));
        let s = common::read_json(&summary);
        assert_eq!(s["main"]["state"], "READY", "{machine}: {s}");
        assert_eq!(s["program"]["completed"], true, "{machine}: {s}");
    }
}

/// A library of four files: the program of the report (offered), one that does not read (not
/// UTF-8), one the interpreter refuses, one out of the machine's reach. The PLC starts, the
/// three are logged with why, and the screen lists them (`hmi.rs` checks the list it is given).
#[test]
fn a_library_offers_what_plans_and_says_why_the_rest_is_not_offered() {
    let dir = tempfile::tempdir().expect("tempdir");
    let library = dir.path().join("library");
    std::fs::create_dir(&library).expect("a directory");
    std::fs::write(library.join("a-nan.ngc"), NAN_PROGRAM).expect("write");
    std::fs::write(library.join("b-binary.ngc"), [0x47, 0x31, 0xff, 0xfe, 0x0a]).expect("write");
    std::fs::write(library.join("c-refused.ngc"), "G1 X1 F600\nG5 X2\nM2\n").expect("write");
    std::fs::write(library.join("d-far.ngc"), "G1 X500 F600\nM2\n").expect("write");
    let summary = dir.path().join("summary.json");
    let o = common::pkm_command()
        .args(["run", "--machine", "ox-x", "--duration", "0.5", "--hmi", "127.0.0.1:0"])
        .args(["--joystick", "none", "--summary", summary.to_str().expect("utf-8")])
        .args(["--programs", library.to_str().expect("utf-8")])
        .env("RUST_LOG", "info")
        .output()
        .expect("the binary runs");
    let log = stderr(&o);
    assert_eq!(o.status.code(), Some(0), "{log}");
    let lib = library.display();
    for why in [
        format!("screen: not offered: {lib}/b-binary.ngc: cannot read the program: "),
        format!("screen: not offered: {lib}/c-refused.ngc:2:1: "),
        format!("screen: not offered: {lib}/d-far.ngc: the program leaves what ox-x can reach"),
    ] {
        assert!(log.contains(&why), "{why}\nnot in:\n{log}");
    }
    assert!(!log.contains("a-nan.ngc"), "{log}");
    // It ran: cycles counted in its summary.
    let s = common::read_json(&summary);
    assert!(s["main"]["state"].is_string(), "{s}");
}
