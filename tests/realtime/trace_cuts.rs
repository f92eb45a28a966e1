//! Traces that a crash cut short, and traces that lie: a killed run leaves a trace that replays
//! up to the cut; cut, out-of-order and oversized traces are read as far as they are sound and
//! the rest is a clear message.

use crate::common;

use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use common::{pkm, stderr, stdout, write_realtime_config};
use pkm_plc::services::trace::read::TraceReader;

/// Records one second of virtual time into `dir/name`; returns its path and its lines.
fn recorded(dir: &Path, name: &str) -> (PathBuf, Vec<String>) {
    let trace = common::record_trace(dir, name, 1, "[]");
    let text = std::fs::read_to_string(&trace).expect("trace");
    (trace, text.lines().map(str::to_string).collect())
}

/// Every complete record of a trace: (count, time of the last one in s, where it was cut).
fn read_all(path: &Path) -> (u64, f64, Option<String>) {
    let mut reader = TraceReader::open(path).expect("the header is readable");
    let (mut n, mut last) = (0, 0.0);
    while let Some(r) = reader.next_record().expect("every complete record is readable") {
        n += 1;
        last = r.t_us as f64 * 1e-6;
    }
    (n, last, reader.cut().map(ToString::to_string))
}

/// Runs the soft-PLC in real time with a trace, SIGKILLs it after 3.3 s (once the
/// file on disk holds two seconds of records: the writer flushes while the run goes on), and
/// checks what is left.
fn killed_run_leaves_a_replayable_trace(name: &str) {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = write_realtime_config(dir.path());
    let trace = dir.path().join(name);
    let mut child = common::pkm_command()
        .args(["run", "--config", config.to_str().expect("utf-8"), "--joystick", "none"])
        .arg("--trace")
        .arg(&trace)
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    let mut log = std::io::BufReader::new(child.stderr.take().expect("stderr"));
    let mut seen = String::new();
    while !seen.contains("running in real time") {
        let n = log.read_line(&mut seen).expect("read the log");
        assert!(n > 0, "the run ended before it was ready:\n{seen}");
    }
    let ready = Instant::now();
    // What is on disk grows while the run goes on: the writer flushes, the test does not guess.
    loop {
        if std::fs::metadata(&trace).is_ok_and(|m| m.len() > 0) {
            let (_, last, _) = read_all(&trace);
            if last >= 2.0 {
                break;
            }
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    // Then a kill at a time unrelated to the writer's flushes.
    std::thread::sleep(std::time::Duration::from_millis(3300).saturating_sub(ready.elapsed()));
    child.kill().expect("SIGKILL");
    let killed = ready.elapsed().as_secs_f64();
    child.wait().expect("wait");

    let (records, last, cut) = read_all(&trace);
    let lost = killed - last;
    eprintln!("{name}: {records} records up to t = {last:.3} s; killed at ≈ {killed:.3} s: {lost:.3} s lost; {cut:?}");
    assert!(records > 200, "{records} records");
    // The writer flushes every 0.5 s; a second more for a busy machine.
    assert!(lost < 1.5, "{lost:.3} s of the run are missing from the trace");

    let o = pkm(&[
        "replay",
        trace.to_str().expect("utf-8"),
        "--config",
        config.to_str().expect("utf-8"),
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let line = stdout(&o);
    let path = trace.display();
    let whole = format!("{path}: identical: {records} records over {last:.1} s");
    let cut_short = format!("{path}: identical up to the cut: {records} records over {last:.1} s");
    assert!(line.starts_with(&whole) || line.starts_with(&cut_short), "{line}");
    if let Some(cut) = cut {
        assert!(line.trim_end().ends_with(&cut), "{line}");
    }
    assert!(!stderr(&o).contains("panicked"), "{}", stderr(&o));
}

#[test]
fn a_killed_run_leaves_a_plain_trace_that_replays() {
    killed_run_leaves_a_replayable_trace("live.jsonl");
}

#[test]
fn a_killed_run_leaves_a_gzip_trace_that_replays_up_to_the_cut() {
    killed_run_leaves_a_replayable_trace("live.jsonl.gz");
}

#[test]
fn replay_vcd_and_plot_use_every_record_before_a_cut_and_say_where() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, lines) = recorded(dir.path(), "t.jsonl");
    // Cut in the middle of line 101 (the 100th record), as a crash during a write leaves it.
    let mut text = lines[..100].join("\n") + "\n";
    text.push_str(&lines[100][..40]);
    let plain = dir.path().join("cut.jsonl");
    std::fs::write(&plain, &text).expect("write");
    // The gzip stream of the same text, sync-flushed and without its trailer.
    let gz = dir.path().join("cut.jsonl.gz");
    let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    encoder.write_all(text.as_bytes()).expect("compress");
    encoder.flush().expect("sync flush");
    std::fs::write(&gz, encoder.get_ref()).expect("write");

    let t = read_all(&plain).1;
    for (path, why) in [
        (&plain, "the last line is incomplete (40 bytes, no end of line)"),
        (
            &gz,
            "the gzip stream ends without its trailer, 40 bytes into the next line",
        ),
    ] {
        let cut = format!("the trace is cut after line 100 (t = {t:.3} s): {why}");
        let o = pkm(&["replay", path.to_str().expect("utf-8")]);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        assert!(
            stdout(&o).starts_with(&format!(
                "{}: identical up to the cut: 99 records over {t:.1} s of recorded time",
                path.display()
            )),
            "{}",
            stdout(&o)
        );
        assert!(stdout(&o).trim_end().ends_with(&cut), "{}", stdout(&o));
        let vcd = dir.path().join("t.vcd");
        let o = pkm(&[
            "trace",
            "vcd",
            path.to_str().expect("utf-8"),
            vcd.to_str().expect("utf-8"),
        ]);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        assert_eq!(stdout(&o), format!("{}: 99 records written ({cut})\n", vcd.display()));
        let svg = dir.path().join("t.svg");
        let o = pkm(&[
            "trace",
            "plot",
            path.to_str().expect("utf-8"),
            svg.to_str().expect("utf-8"),
        ]);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        assert_eq!(stdout(&o), format!("{}: 99 records written ({cut})\n", svg.display()));
    }

    // A cut trace still differs where it differs: the comparison runs up to the cut.
    let tampered = text.replacen("\"state\":\"REBOOT\"", "\"state\":\"READY\"", 1);
    std::fs::write(&plain, tampered).expect("write");
    let o = pkm(&["replay", plain.to_str().expect("utf-8")]);
    assert_eq!(o.status.code(), Some(1), "{}", stdout(&o));
    assert!(
        stderr(&o).contains("state recorded READY, replayed REBOOT"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn records_at_impossible_times_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, lines) = recorded(dir.path(), "t.jsonl");
    let header = &lines[0];
    let fast: Vec<&String> = lines[1..].iter().filter(|l| l.contains("\"task\":\"fast\"")).collect();
    let check = |name: &str, content: String, expected: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, content).expect("write");
        let o = pkm(&["replay", path.to_str().expect("utf-8")]);
        assert_eq!(o.status.code(), Some(2), "{name}: {}", stdout(&o));
        assert_eq!(stderr(&o), format!("error: {}{expected}\n", path.display()), "{name}");
    };
    // The second fast cycle claims t = 0 again.
    check(
        "backwards.jsonl",
        format!(
            "{header}\n{}\n{}\n",
            fast[0],
            fast[1].replace("\"t_us\":10000,", "\"t_us\":0,")
        ),
        ":3: t_us 0 is not after the previous cycle of task class \"fast\" (t_us 0)",
    );
    check(
        "max.jsonl",
        format!(
            "{header}\n{}\n",
            fast[0].replace("\"t_us\":0,", &format!("\"t_us\":{},", u64::MAX))
        ),
        &format!(
            ":2: t_us {} is beyond the latest time a trace can hold ({})",
            u64::MAX,
            u64::MAX / 1000
        ),
    );
    check(
        "between.jsonl",
        format!("{header}\n{}\n", fast[0].replace("\"t_us\":0,", "\"t_us\":12345,")),
        ":2: t_us 12345 is not a release of task class \"fast\" (a multiple of its cycle time, 10000 µs)",
    );
    check(
        "cycle.jsonl",
        header.replacen("\"cycle_us\":10000", "\"cycle_us\":2305843009213703952", 1) + "\n",
        ":1: bad header: task class \"fast\" has cycle_us 2305843009213703952: a cycle time is 200 … 10000000 µs",
    );
}

#[test]
fn oversized_lines_fifos_and_devices_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, lines) = recorded(dir.path(), "t.jsonl");
    let check = |path: &Path, expected: &str| {
        for args in [
            vec!["replay", path.to_str().expect("utf-8")],
            vec!["trace", "vcd", path.to_str().expect("utf-8"), "/dev/null"],
        ] {
            let o = pkm(&args);
            assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stdout(&o));
            assert_eq!(stderr(&o), format!("error: {}{expected}\n", path.display()), "{args:?}");
        }
    };
    // A line of 64 MiB in a gzip stream of 64 kB: read no further than 4 MiB of it.
    let bomb = dir.path().join("bomb.jsonl.gz");
    let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    encoder
        .write_all(format!("{}\n", lines[0]).as_bytes())
        .expect("compress");
    let chunk = vec![b'a'; 1 << 20];
    for _ in 0..64 {
        encoder.write_all(&chunk).expect("compress");
    }
    std::fs::write(&bomb, encoder.finish().expect("compress")).expect("write");
    check(&bomb, ":2: the line is longer than 4 MiB: not a trace line");

    let fifo = dir.path().join("fifo.jsonl");
    assert!(Command::new("mkfifo").arg(&fifo).status().expect("mkfifo").success());
    check(&fifo, ": cannot open: a FIFO: only a regular file can be read here");
    check(
        Path::new("/dev/zero"),
        ": cannot open: a character device: only a regular file can be read here",
    );
}

#[test]
fn a_plot_of_values_near_the_limits_of_f64_ends() {
    // Regression: a value of ±1e308 made the axis span infinite and the plot spin.
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, lines) = recorded(dir.path(), "t.jsonl");
    let mut out = vec![lines[0].clone()];
    let mut main = 0;
    for line in &lines[1..] {
        let mut record: serde_json::Value = serde_json::from_str(line).expect("json");
        if record["task"] == "main" && main < 3 {
            record["out"]["TOOL_X"] = serde_json::json!([1e308, -1e308, f64::MAX][main]);
            main += 1;
        }
        out.push(record.to_string());
    }
    let trace = dir.path().join("huge.jsonl");
    std::fs::write(&trace, out.join("\n") + "\n").expect("write");
    let svg = dir.path().join("huge.svg");
    let o = pkm(&[
        "trace",
        "plot",
        trace.to_str().expect("utf-8"),
        svg.to_str().expect("utf-8"),
        "--vars",
        "TOOL_X",
    ]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(std::fs::read_to_string(&svg).expect("svg").contains("TOOL_X"));
}
