//! Measures the operator screen (README, "The operator's screen"): the update latency from a
//! cycle to the browser, and the 10 ms class's lateness and execution time with N headless
//! Chromium browsers connected.
//!
//! `cargo build --release && cargo run --release --example hmi_latency -- [BROWSERS] [SECONDS]
//! [PROGRAM|none] [SETTLE]` (3 browsers, 30 s by default; 0 browsers measures the PLC alone). Needs Chromium
//! (`apt-get install chromium`) and runs `target/release/pkm-plc run --machine ox-x` (with
//! `--program PROGRAM`, which then runs: the screen draws its cut path as it goes). It also
//! measures what the pages cost the browsers: the CPU time of every Chromium process of each
//! browser (its profile's), as a share of one core, from SETTLE seconds (5 by default; 20 lets
//! the O-X glide reference first) after the pages opened, in all and per kind of Chromium
//! process (renderer, GPU process: its software compositor).
//!
//! Environment: `PKM_PLC` another build of pkm-plc to measure (two builds side by side, one run
//! each); `HMI_LATENCY_HZ` the page's drawing rate (`?hz=`); `HMI_LATENCY_CHROME_ARGS` more
//! Chromium switches.

use std::io::BufRead;
use std::process::{Command, Stdio};
use std::time::Duration;

// The tests' small Chrome DevTools Protocol client.
#[path = "../tests/common/cdp.rs"]
#[allow(dead_code)]
mod cdp;

use cdp::Browser;

fn fail(message: String) -> ! {
    eprintln!("hmi_latency: {message}");
    std::process::exit(1)
}

#[tokio::main]
async fn main() {
    let mut args = std::env::args().skip(1);
    let browsers: usize = args.next().map_or(3, |a| {
        a.parse()
            .unwrap_or_else(|_| fail(format!("{a} is not a number of browsers")))
    });
    let seconds: u64 = args.next().map_or(30, |a| {
        a.parse()
            .unwrap_or_else(|_| fail(format!("{a} is not a number of seconds")))
    });
    let program: Option<String> = args.next().filter(|p| p != "none");
    let settle: u64 = args.next().map_or(5, |a| {
        a.parse()
            .unwrap_or_else(|_| fail(format!("{a} is not a number of seconds")))
    });
    let dir = std::env::temp_dir().join(format!("hmi-latency-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| fail(format!("{}: {e}", dir.display())));
    let summary = dir.join("summary.json");
    // PKM_PLC: another build to measure (two builds side by side, each in its own run).
    let binary = std::env::var("PKM_PLC").unwrap_or_else(|_| "target/release/pkm-plc".into());
    let mut plc = Command::new(&binary)
        .args([
            "run",
            "--machine",
            "ox-x",
            "--joystick",
            "none",
            "--hmi",
            "127.0.0.1:0",
            "--duration",
        ])
        .arg((seconds + settle + 10).to_string())
        .args(program.iter().flat_map(|p| ["--program", p.as_str()]))
        .arg("--summary")
        .arg(&summary)
        .env("RUST_LOG", "info")
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| fail(format!("{binary}: {e} (cargo build --release first)")));
    let stderr = plc.stderr.take().unwrap_or_else(|| fail("no stderr".into()));
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stderr).lines().map_while(Result::ok) {
            if let Some(at) = line.split("operator screen at ").nth(1) {
                let _ = tx.send(at.split_whitespace().next().unwrap_or("").to_string());
            }
        }
    });
    let url = rx
        .recv_timeout(Duration::from_secs(30))
        .unwrap_or_else(|_| fail("the screen's address was not logged".into()));
    // HMI_LATENCY_HZ: the page's drawing rate in every state (`?hz=`), not the shipped one.
    let url = match std::env::var("HMI_LATENCY_HZ") {
        Ok(hz) => format!("{url}{}hz={hz}", if url.contains('?') { '&' } else { '?' }),
        Err(_) => url,
    };
    let chromium = cdp::chromium();
    // HMI_LATENCY_CHROME_ARGS: more switches for Chromium, `name=value` each (a trace of where
    // its time goes: `trace-startup=cc,viz,blink trace-startup-duration=45
    // trace-startup-file=/tmp/trace.json trace-startup-format=json`).
    let extra = std::env::var("HMI_LATENCY_CHROME_ARGS").unwrap_or_default();
    let extra: Vec<(&str, &str)> = extra.split_whitespace().filter_map(|a| a.split_once('=')).collect();
    let mut open = Vec::new();
    for i in 0..browsers {
        let Some(chromium) = chromium.as_deref() else {
            fail("no chromium on the PATH (apt-get install chromium)".into())
        };
        let browser = Browser::launch(chromium, &dir.join(format!("profile-{i}")), &extra)
            .await
            .unwrap_or_else(|e| fail(format!("Chromium: {e}")));
        let page = browser
            .new_page(url.as_str())
            .await
            .unwrap_or_else(|e| fail(format!("the page: {e}")));
        open.push((browser, page));
    }
    // The browsers' CPU time from `settle` s after the pages opened (their start and first
    // drawing left out, and the referencing where it asks for it).
    tokio::time::sleep(Duration::from_secs(settle)).await;
    let profiles: Vec<String> = (0..browsers)
        .map(|i| dir.join(format!("profile-{i}")).display().to_string())
        .collect();
    let (cpu_from, wall_from) = (browsers_cpu_s(&profiles), std::time::Instant::now());
    tokio::time::sleep(Duration::from_secs(seconds)).await;
    let cpu_to = browsers_cpu_s(&profiles);
    let wall = wall_from.elapsed().as_secs_f64();
    let by_kind: Vec<(String, f64)> = cpu_to
        .iter()
        .map(|(kind, s)| (kind.clone(), s - cpu_from.get(kind).copied().unwrap_or(0.0)))
        .collect();
    let cpu: f64 = by_kind.iter().map(|(_, s)| s).sum();
    let mut all: Vec<f64> = Vec::new();
    for (_, page) in &open {
        let latency: Vec<f64> = page
            .evaluate("window.latency")
            .await
            .ok()
            .and_then(|r| serde_json::from_value(r).ok())
            .unwrap_or_default();
        all.extend(latency);
    }
    for (browser, _) in open {
        browser.close().await;
    }
    let status = plc.wait().unwrap_or_else(|e| fail(e.to_string()));
    if !status.success() {
        fail(format!("pkm-plc ended with {status}"));
    }
    let text = std::fs::read_to_string(&summary).unwrap_or_else(|e| fail(e.to_string()));
    let s: serde_json::Value = serde_json::from_str(&text).unwrap_or_else(|e| fail(e.to_string()));
    let fast = &s["task_classes"][0];
    println!(
        "{browsers} browsers, {seconds} s: 10 ms class lateness p50/p99/max {}/{}/{} µs, execution mean/p99/max {}/{}/{} µs, {} overruns",
        fast["lateness_us"]["p50"],
        fast["lateness_us"]["p99"],
        fast["lateness_us"]["max"],
        fast["exec_us"]["mean"],
        fast["exec_us"]["p99"],
        fast["exec_us"]["max"],
        fast["overruns"]
    );
    if browsers > 0 {
        println!(
            "the pages cost the browsers {:.1} % of one core each ({:.2} CPU-s over {wall:.1} s, {browsers} browsers)",
            cpu / wall / browsers as f64 * 100.0,
            cpu
        );
        let parts: Vec<String> = by_kind
            .iter()
            .map(|(kind, s)| format!("{kind} {:.1} %", s / wall / browsers as f64 * 100.0))
            .collect();
        println!("  by process: {}", parts.join(", "));
    }
    if !all.is_empty() {
        all.sort_by(f64::total_cmp);
        let mean = all.iter().sum::<f64>() / all.len() as f64;
        let p99 = all[(all.len() * 99 / 100).min(all.len() - 1)];
        println!(
            "update latency (publication in the cycle → the page's handler): mean {mean:.2} ms, p99 {p99:.2} ms, max {:.2} ms over {} frames",
            all[all.len() - 1],
            all.len()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The CPU time (user and system, s) of every process whose command line names one of
/// `profiles` (a Chromium's browser, renderer, GPU and utility processes all carry its profile
/// directory), per kind of process (its `--type`: renderer, gpu-process, utility; the
/// browser's own has none).
fn browsers_cpu_s(profiles: &[String]) -> std::collections::BTreeMap<String, f64> {
    let ticks_per_s = 100.0; // USER_HZ on Linux
    let mut total = std::collections::BTreeMap::new();
    let Ok(entries) = std::fs::read_dir("/proc") else {
        return total;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let Ok(cmdline) = std::fs::read(path.join("cmdline")) else {
            continue;
        };
        let cmdline = String::from_utf8_lossy(&cmdline);
        if !profiles.iter().any(|p| cmdline.contains(p.as_str())) {
            continue;
        }
        let Ok(stat) = std::fs::read_to_string(path.join("stat")) else {
            continue;
        };
        // After the command's name in parentheses: fields 14 and 15 (utime, stime).
        let Some(after) = stat.rsplit_once(')').map(|(_, a)| a) else {
            continue;
        };
        let fields: Vec<&str> = after.split_whitespace().collect();
        let get = |k: usize| fields.get(k).and_then(|f| f.parse::<u64>().ok()).unwrap_or(0);
        // Chromium rewrites its children's command lines into one space-separated string.
        let kind = cmdline
            .split(['\0', ' '])
            .find_map(|a| a.strip_prefix("--type="))
            .unwrap_or("browser")
            .to_string();
        *total.entry(kind).or_insert(0.0) += (get(11) + get(12)) as f64 / ticks_per_s;
    }
    total
}
