//! Helpers shared by the tests that run the simulated machine in virtual time. Each test file
//! uses a part of them.
#![allow(dead_code)]

pub mod cdp;
pub mod host;
pub mod soak;

use std::path::{Path, PathBuf};

use pkm_plc::compose::Setup;
use pkm_plc::image::Value;
use pkm_plc::program::Registry;
use pkm_plc::runtime::config::{self, ConfigError, LoadedConfig};
use pkm_plc::runtime::plc::Plc;
use pkm_plc::runtime::run::VirtualClock;
use pkm_plc::services::sim::bus::SimBus;
use pkm_trijoint::plant::Plant;

/// The repository's directory.
pub fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// A JSON file (a run's summary, a repository file) as JSON.
pub fn read_json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The repository's config.json as JSON, to be modified by a test.
pub fn repo_config() -> serde_json::Value {
    read_json(&root().join("config.json"))
}

/// A configuration from JSON, named `test-config.json`, with paths relative to the repository.
pub fn loaded(config: &serde_json::Value) -> LoadedConfig {
    let mut loaded = config::parse(&config.to_string(), "test-config.json").expect("the test configuration parses");
    loaded.dir = Some(PathBuf::from(root()));
    loaded
}

/// Builds the PLC on the simulated machine, with `scenario` (JSON text) if given.
pub fn sim_plc(loaded: &LoadedConfig, registry: &Registry, scenario: Option<&str>) -> Result<Plc, ConfigError> {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = scenario.map(|s| {
        let p = dir.path().join("scenario.json");
        std::fs::write(&p, s).expect("write the scenario");
        p
    });
    let bus = Setup::new(loaded.clone())?.sim_bus(path.as_deref())?;
    Plc::build(&loaded.config, registry, Box::new(bus)).map_err(|problems| ConfigError::Invalid {
        file: loaded.origin.clone(),
        problems,
    })
}

/// The configuration's I/O map (it must name a valid one).
pub fn io_map(loaded: &LoadedConfig) -> pkm_plc::services::io::map::IoMap {
    Setup::new(loaded.clone())
        .expect("known machine")
        .io_map()
        .expect("valid map")
        .expect("an io_map")
}

/// The simulated machine's plant, of type `P`: the machine's true state.
pub fn plant_of<P: 'static>(plc: &Plc) -> &P {
    plc.bus()
        .as_any()
        .downcast_ref::<SimBus>()
        .expect("the simulated bus")
        .plant()
        .as_any()
        .downcast_ref::<P>()
        .unwrap_or_else(|| panic!("a plant of type {}", std::any::type_name::<P>()))
}

/// The TRIJOINT's simulated plant.
pub fn plant(plc: &Plc) -> &Plant {
    plant_of(plc)
}

/// A joint-driven machine's configuration (`machines/NAME.json`), with `edit` applied to its
/// JSON first.
pub fn machine_config(name: &str, edit: impl FnOnce(&mut serde_json::Value)) -> LoadedConfig {
    let path = root().join("machines").join(format!("{name}.json"));
    let mut json = read_json(&path);
    edit(&mut json);
    let mut loaded =
        config::parse(&json.to_string(), &path.display().to_string()).expect("the machine's configuration parses");
    loaded.dir = Some(root().join("machines"));
    loaded
}

/// A joint-driven machine's simulated plant: its true state.
pub fn joint_plant(plc: &Plc) -> &pkm_joints::plant::Plant {
    plant_of(plc)
}

/// A joint-driven machine's simulated plant, to act on it as a person at the machine would.
pub fn joint_plant_mut(plc: &mut Plc) -> &mut pkm_joints::plant::Plant {
    plc.bus_mut()
        .as_any_mut()
        .downcast_mut::<SimBus>()
        .expect("the simulated bus")
        .plant_mut()
        .as_any_mut()
        .downcast_mut::<pkm_joints::plant::Plant>()
        .expect("a joint plant")
}

/// A seeded generator for the soaks' random scenarios: uniform in [0, 1).
pub struct Rng(pub u64);

impl Rng {
    /// The next number in [0, 1) (xorshift64).
    pub fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A whole number in [lo, hi).
    pub fn between(&mut self, lo: u64, hi: u64) -> u64 {
        lo + (self.next() * (hi - lo) as f64) as u64
    }
}

/// A variable of the published image as a value, by its typed name.
pub fn var<T>(plc: &Plc, var: pkm_plc::image::Var<T>) -> Value {
    let index = plc.vars().index_of(var.name());
    plc.global_image()[usize::from(index.unwrap_or_else(|| panic!("no variable {}", var.name())))]
}

/// A variable of the published image, by its typed name.
pub fn get<T: pkm_plc::image::PlcType>(plc: &Plc, var: pkm_plc::image::Var<T>) -> T {
    T::from_value(self::var(plc, var))
}

/// The main program's state.
pub fn state(plc: &Plc) -> &str {
    plc.app_status().map(|s| s.state).unwrap_or("")
}

/// Runs in virtual time from power-on; `each(plc, t_ms)` after every pass over the due classes.
pub fn run(plc: &mut Plc, until_ms: u64, mut each: impl FnMut(&Plc, u64)) {
    let mut clock = VirtualClock::default();
    plc.init(0, &mut clock);
    while plc.next_release() < until_ms * 1_000_000 {
        let t = plc.next_release();
        clock.advance_to(t);
        plc.run_due(&mut clock, u64::MAX);
        each(plc, t / 1_000_000);
    }
}

/// A state change of the main program: (time ms, state, error reason).
pub type Transition = (u64, String, Option<String>);

/// Runs as [`run`] does and returns the main program's state changes; `each(plc, t_ms)` after
/// every pass.
pub fn transitions(plc: &mut Plc, until_ms: u64, mut each: impl FnMut(&Plc, u64)) -> Vec<Transition> {
    let mut seen: Vec<Transition> = Vec::new();
    run(plc, until_ms, |plc, t| {
        let s = plc.app_status().expect("status");
        if seen.last().is_none_or(|(_, st, _)| st != s.state) {
            seen.push((t, s.state.to_string(), s.reason.map(str::to_string)));
        }
        each(plc, t);
    });
    seen
}

/// With [`realtime_config`], the machine is READY after this long (14.45 s of simulated time).
pub const FAST_READY_S: f64 = 14.45;

/// The repository's configuration for real-time end-to-end tests, which test an exchange (Modbus,
/// a joystick), not the scheduler's timing: referencing at up to 50 mm/s with short, quicker
/// approaches (READY after [`FAST_READY_S`] instead of 40.2 s); cycle time violations logged
/// rather than raising ERROR on a busy machine (timing has its own benchmarks); and the encoder
/// plausibility bound at 30 000 counts per cycle, so that inputs a busy machine delays by a few
/// cycles at 50 mm/s (3500 counts per 10 ms) are not an encoder fault. The I/O map's path is
/// absolute, so the configuration can be written anywhere.
pub fn realtime_config() -> serde_json::Value {
    let mut config = busy_machine_config();
    for class in config["task_classes"].as_array_mut().expect("classes") {
        for program in class["programs"].as_array_mut().expect("programs") {
            if program["program"] == "trijoint.main" {
                program["params"] = serde_json::json!({
                    "init_speed_mm_s": 50, "approach_speed_mm_s": 4, "creep_speed_mm_s": 0.1,
                    "approach_distance_mm": 1.0, "creep_distance_mm": 0.1
                });
            }
        }
    }
    config
}

/// The repository's configuration as a busy machine needs it for tests of something other than
/// timing: referencing as shipped, but cycle time violations logged rather than an ERROR, the
/// encoder plausibility bound at 30 000 counts per cycle (see [`realtime_config`]), and the
/// following-error bound at 20 mm instead of 5 (a busy machine delays a link's images by cycles,
/// and the set-point runs ahead of positions that come late: at 50 mm/s, 5 mm is 100 ms); the
/// I/O map's path absolute.
pub fn busy_machine_config() -> serde_json::Value {
    let mut config = repo_config();
    config["io_map"] = root().join("io-map/trijoint.json").to_str().expect("utf-8").into();
    for class in config["task_classes"].as_array_mut().expect("classes") {
        class["on_violation"] = "log".into();
        for program in class["programs"].as_array_mut().expect("programs") {
            if program["program"] == "trijoint.encoders" {
                program["params"] = serde_json::json!({ "max_counts_per_cycle": 30000 });
            }
            if program["program"] == "trijoint.control" {
                program["params"] = serde_json::json!({ "max_following_error_mm": 20.0 });
            }
        }
    }
    config
}

/// Writes [`busy_machine_config`] to `dir`; returns its path.
pub fn write_busy_machine_config(dir: &Path) -> PathBuf {
    write_config(dir, "busy-machine-config.json", &busy_machine_config())
}

/// Writes the configuration `config` to `dir/name`; returns its path.
pub fn write_config(dir: &Path, name: &str, config: &serde_json::Value) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, config.to_string()).expect("write the configuration");
    path
}

/// The configuration at `config` with its I/O map changed by `edit`: the map is copied beside
/// the configuration (as `io-map.json`), edited there, and the configuration rewritten to name
/// the copy.
pub fn edit_io_map(config: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let mut c = read_json(config);
    let dir = config.parent().expect("a configuration in a directory");
    let named = PathBuf::from(c["io_map"].as_str().expect("the configuration names an I/O map"));
    let mut map = read_json(&dir.join(named));
    edit(&mut map);
    let copy = dir.join("io-map.json");
    std::fs::write(&copy, map.to_string()).expect("write the I/O map");
    c["io_map"] = copy.to_str().expect("utf-8").into();
    std::fs::write(config, c.to_string()).expect("write the configuration");
}

/// The configuration at `config` with its I/O map's station the generic one (what `--exchange
/// image` needs), whatever the map names.
pub fn on_generic_station(config: &Path) {
    edit_io_map(config, |map| {
        map["station"] = "generic".into();
        if let Some(m) = map.as_object_mut() {
            m.remove("watchdog_ms");
        }
    });
}

/// The WebSocket of the screen at `url` (`http://…/`), as a page opens it.
type ScreenSocket = tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// Connects to the screen at `url` (`http://…/`) as a page does, runs `body` with the socket on
/// a runtime of its own, and closes the socket with the closing handshake: the screen has read
/// everything `body` sent when it answers the close (up to 30 s). A socket dropped right after
/// its last message lost it now and then on a busy machine: the screen's next frame met a
/// closed connection, which ended the session before the message was read. Returns what `body`
/// returned.
pub fn on_screen<T>(url: &str, body: impl AsyncFnOnce(&mut ScreenSocket) -> T) -> T {
    use futures::StreamExt;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    let ws = url.replacen("http://", "ws://", 1) + "ws";
    runtime.block_on(async {
        let (mut socket, _) = tokio_tungstenite::connect_async(ws.as_str()).await.expect("the screen");
        let done = body(&mut socket).await;
        let _ = socket.close(None).await;
        let drained = async { while let Some(Ok(_)) = socket.next().await {} };
        let _ = tokio::time::timeout(std::time::Duration::from_secs(30), drained).await;
        done
    })
}

/// Holds a jog on the screen at `url` (`http://…/`) at `x`, `y` for `hold`, as the page does
/// (a fresh command every 20 ms: the screen stops a jog that is not refreshed), then releases
/// it. For real-time tests that jog once the machine is READY, whatever time that took.
pub fn screen_jog(url: &str, x: f64, y: f64, hold: std::time::Duration) {
    use futures::SinkExt;
    use tokio_tungstenite::tungstenite::Message;
    let jog = |x: f64, y: f64| Message::Text(serde_json::json!({"cmd": "jog", "x": x, "y": y}).to_string().into());
    on_screen(url, async |socket| {
        let start = std::time::Instant::now();
        while start.elapsed() < hold {
            socket.send(jog(x, y)).await.expect("a jog");
            tokio::time::sleep(std::time::Duration::from_millis(20)).await;
        }
        socket.send(jog(0.0, 0.0)).await.expect("the release");
    });
}

/// Whether a machine stands still, from the values its main program shows (the tool's pose, the
/// joints) as they come: still once they have stayed within 2 µm of each other for half a
/// second. A DC drive's regulator rings for a while after a jog or a program stops (the
/// TRIJOINT's about 1.5 s over an RTU line whose exchange takes 7 ms), and positions are
/// checked only once it stands.
#[derive(Default)]
pub struct Stillness {
    /// The values seen, with their time (s), over the last half second and the one before it.
    seen: std::collections::VecDeque<(f64, Vec<f64>)>,
}

impl Stillness {
    /// The values shown at `t_s`; returns whether the machine stands still now.
    pub fn saw(&mut self, t_s: f64, values: Vec<f64>) -> bool {
        if self.seen.back().is_some_and(|(t, _)| *t >= t_s) {
            return self.still();
        }
        self.seen.push_back((t_s, values));
        while self.seen.len() > 2 && self.seen[1].0 <= t_s - 0.5 {
            self.seen.pop_front();
        }
        self.still()
    }

    /// Whether the values seen have stayed within 2 µm of each other for half a second.
    pub fn still(&self) -> bool {
        let (Some((first, v0)), Some((last, _))) = (self.seen.front(), self.seen.back()) else {
            return false;
        };
        last - first >= 0.5
            && (0..v0.len()).all(|k| {
                let (lo, hi) = self
                    .seen
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (_, v)| {
                        (lo.min(v[k]), hi.max(v[k]))
                    });
                hi - lo <= 0.002
            })
    }
}

/// Watches the screen at `url` (`http://…/`) until the machine stands still ([`Stillness`]),
/// at most `limit`; returns whether it does.
pub fn screen_until_still(url: &str, limit: std::time::Duration) -> bool {
    use futures::StreamExt;
    let mut still = false;
    on_screen(url, async |socket| {
        let mut stillness = Stillness::default();
        let start = std::time::Instant::now();
        while start.elapsed() < limit {
            let next = tokio::time::timeout(limit.saturating_sub(start.elapsed()), socket.next()).await;
            let Ok(Some(Ok(tokio_tungstenite::tungstenite::Message::Text(text)))) = next else {
                continue;
            };
            let Ok(frame) = serde_json::from_str::<serde_json::Value>(&text) else {
                continue;
            };
            if frame["type"] != "frame" {
                continue;
            }
            let values: Vec<f64> = frame["values"]
                .as_array()
                .into_iter()
                .flatten()
                .filter_map(|nv| nv[1].as_f64())
                .collect();
            if stillness.saw(frame["t_s"].as_f64().unwrap_or(0.0), values) {
                still = true;
                return;
            }
        }
    });
    still
}

/// Sends one command (`{"cmd": …}`) to the screen at `url` (`http://…/`), as the page does.
pub fn screen_command(url: &str, command: serde_json::Value) {
    use futures::SinkExt;
    use tokio_tungstenite::tungstenite::Message;
    on_screen(url, async |socket| {
        socket
            .send(Message::Text(command.to_string().into()))
            .await
            .expect("the command");
    });
}

/// Places shared by tests that load the machine (PLC-and-station sessions, say): at most `most`
/// taken at once; [`Places::take`] waits for one.
pub struct Places {
    taken: std::sync::Mutex<usize>,
    freed: std::sync::Condvar,
    most: usize,
}

/// A place taken, given back when dropped.
pub struct Place(&'static Places);

impl Places {
    /// At most `most` places taken at once.
    pub const fn new(most: usize) -> Places {
        Places {
            taken: std::sync::Mutex::new(0),
            freed: std::sync::Condvar::new(),
            most,
        }
    }

    /// Waits for a free place and takes it.
    pub fn take(&'static self) -> Place {
        let mut n = self.taken.lock().unwrap_or_else(|p| p.into_inner());
        while *n >= self.most {
            n = self.freed.wait(n).unwrap_or_else(|p| p.into_inner());
        }
        *n += 1;
        Place(self)
    }
}

impl Drop for Place {
    fn drop(&mut self) {
        *self.0.taken.lock().unwrap_or_else(|p| p.into_inner()) -= 1;
        self.0.freed.notify_one();
    }
}

/// Every machine's name, as `--machine` takes it.
pub const MACHINES: [&str; 5] = ["trijoint", "pn101", "ox-x", "ox-o", "hexapod"];

/// `machine`'s configuration for end-to-end tests over a link, written to `dir/NAME.json`, its
/// I/O map's path absolute: **every limit as shipped** — the drives' following-error and counter
/// bounds, the steppers' pull-in, the task classes' reaction to a late cycle. Only referencing
/// is shortened: each joint of the joint machines searches its switch at twice its speed,
/// within the joint's top speed (pn101 references its joints one after another: 84 s as
/// shipped); it backs off the switch before latching it, so how far the search overran does not
/// matter. The slow approaches that latch the reference positions keep their shipped speeds:
/// their precision is what [`check_positions`] holds the PLC to. The TRIJOINT references as
/// shipped (40 s): its second approach starts a set distance before where the coarse search saw
/// the switch, and a faster search, seen late on a busy machine, put that start past the switch
/// (an INIT timeout).
pub fn machine_test_config(dir: &Path, machine: &str) -> PathBuf {
    let mut config = match machine {
        "trijoint" => repo_config(),
        _ => read_json(&root().join(format!("machines/{machine}.json"))),
    };
    config["io_map"] = root()
        .join(format!("io-map/{machine}.json"))
        .to_str()
        .expect("utf-8")
        .into();
    for class in config["task_classes"].as_array_mut().expect("classes") {
        for program in class["programs"].as_array_mut().expect("programs") {
            for joint in params_list(program, "joints") {
                let top = joint["max_speed_mm_s"].as_f64().expect("max_speed_mm_s");
                let reference = &mut joint["reference"];
                let search = reference["search_speed_mm_s"].as_f64().expect("search speed");
                reference["search_speed_mm_s"] = (2.0 * search).min(top).into();
            }
        }
    }
    write_config(dir, &format!("{machine}.json"), &config)
}

/// The entries of the list `key` in `program`'s params, none where it has no such list: looked
/// up, not indexed (indexing would add `key` to every other program's params).
fn params_list<'a>(program: &'a mut serde_json::Value, key: &str) -> impl Iterator<Item = &'a mut serde_json::Value> {
    program
        .get_mut("params")
        .and_then(|p| p.get_mut(key))
        .and_then(serde_json::Value::as_array_mut)
        .into_iter()
        .flatten()
}

/// The O-X glide's configuration for real-time tests of the screen and its jobs, with `edit`
/// applied to the whole, written to `dir/ox-x.json`: they test the screen, not the scheduler's
/// timing, so a late cycle on a busy machine is logged rather than an ERROR (timing has its own
/// benchmarks). `quick`: referencing at twice the search speed and four times the latch speed
/// (READY after about 5 s instead of 11.65 s), for the tests that need READY, not referencing.
pub fn ox_config(dir: &Path, quick: bool, edit: impl FnOnce(&mut serde_json::Value)) -> PathBuf {
    let mut config = read_json(&root().join("machines/ox-x.json"));
    config["io_map"] = root().join("io-map/ox-x.json").to_str().expect("utf-8").into();
    for class in config["task_classes"].as_array_mut().expect("classes") {
        class["on_violation"] = "log".into();
        for program in class["programs"].as_array_mut().expect("programs") {
            if quick && program["program"] == "ox-x.main" {
                for joint in program["params"]["joints"].as_array_mut().expect("joints") {
                    joint["reference"]["search_speed_mm_s"] = 20.0.into();
                    joint["reference"]["latch_speed_mm_s"] = 2.0.into();
                }
            }
        }
    }
    edit(&mut config);
    write_config(dir, "ox-x.json", &config)
}

/// `pkm-plc run` against the Modbus TCP station at `address` for `seconds`, logging at info, its
/// summary to `dir/summary.json` (returned with the command). The tests that use it test bus
/// faults and their reasons, so a late cycle on a busy machine must not be the ERROR: the run
/// uses [`busy_machine_config`], written to `dir`.
pub fn bus_fault_run(address: &str, seconds: &str, dir: &Path) -> (std::process::Command, PathBuf) {
    let summary = dir.join("summary.json");
    let config = write_busy_machine_config(dir);
    let mut command = pkm_command();
    command
        .args(["run", "--bus", &format!("tcp:{address}"), "--duration", seconds])
        .args(["--config", config.to_str().expect("utf-8")])
        .args(["--summary", summary.to_str().expect("utf-8")])
        .env("RUST_LOG", "info");
    (command, summary)
}

/// Starts `command` (a run against a station) and returns once its cycles have started: they
/// start when the link has brought the first image, and the main program's INIT says so.
pub fn start_with_link_up(command: std::process::Command) -> Logged {
    Logged::start(command, "s: INIT", std::time::Duration::from_secs(30)).0
}

/// Writes [`realtime_config`] to `dir`; returns its path.
pub fn write_realtime_config(dir: &Path) -> PathBuf {
    write_config(dir, "realtime-config.json", &realtime_config())
}

/// The repository's configuration (as [`busy_machine_config`]) with the TRIJOINT's modules on a
/// generic station, written once per test binary: for the tests of io-sim's and the driver's
/// generic behaviours (its watchdog, its owner, faults of the standard exchange).
pub fn generic_busy_config() -> &'static str {
    static CONFIG: std::sync::OnceLock<(tempfile::TempDir, String)> = std::sync::OnceLock::new();
    &CONFIG
        .get_or_init(|| {
            let dir = tempfile::tempdir().expect("tempdir");
            let config = write_busy_machine_config(dir.path());
            on_generic_station(&config);
            let config = config.to_str().expect("utf-8").to_string();
            (dir, config)
        })
        .1
}

/// [`write_realtime_config`] with the TRIJOINT's modules on a generic station (the project's own
/// register layout from address 0, and the packed image) instead of the lab's X20BC0087: for
/// the tests of io-sim as a generic Modbus slave and of `--exchange image`.
pub fn write_generic_station_config(dir: &Path) -> PathBuf {
    let config = write_realtime_config(dir);
    on_generic_station(&config);
    config
}

/// Records `seconds` of virtual time of the repository's configuration with the scenario
/// `events` (a JSON array) into `dir/name`; returns the trace's path.
pub fn record_trace(dir: &Path, name: &str, seconds: u32, events: &str) -> PathBuf {
    record_machine_trace(dir, name, seconds, events, &[])
}

/// As [`record_trace`], with more arguments for `run` (`--machine pn101`).
pub fn record_machine_trace(dir: &Path, name: &str, seconds: u32, events: &str, more: &[&str]) -> PathBuf {
    let scenario = dir.join(format!("{name}.scenario.json"));
    std::fs::write(&scenario, format!(r#"{{"events": {events}}}"#)).expect("write scenario");
    let trace = dir.join(name);
    let seconds = seconds.to_string();
    let mut args = vec![
        "run",
        "--virtual",
        "--duration",
        &seconds,
        "--scenario",
        scenario.to_str().expect("utf-8"),
        "--trace",
        trace.to_str().expect("utf-8"),
    ];
    args.extend_from_slice(more);
    let o = pkm(&args);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    trace
}

/// The `pkm-plc` binary of this build as a command, run in the repository. A real-time run
/// serves no OPC UA unless a test asks for it (`PKM_PLC_OPCUA=none`, which `--opcua` overrides),
/// serves its screen on a free port of loopback, never the default 8080 … 8089 a PLC of the
/// user's may hold (`PKM_PLC_HMI=127.0.0.1:0`, which `--hmi` overrides), and any data it keeps
/// (the OPC UA certificate store) goes under `target/`, never into the user's home.
pub fn pkm_command() -> std::process::Command {
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_pkm-plc"));
    command
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("PKM_PLC_OPCUA", "none")
        .env("PKM_PLC_HMI", "127.0.0.1:0")
        .env("XDG_DATA_HOME", Path::new(env!("CARGO_TARGET_TMPDIR")).join("xdg-data"));
    command
}

/// Runs the `pkm-plc` binary in the repository with `RUST_LOG=warn` (see [`pkm_command`]).
pub fn pkm(args: &[&str]) -> std::process::Output {
    pkm_command()
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("the binary runs")
}

/// The environment variable that makes a missing prerequisite of an interoperability test (a
/// Chromium, Python's venv, pymodbus or asyncua from PyPI, LinuxCNC's `rs274`) fail the test
/// instead of skipping it. `.ci/run` sets it: CI installs them, and a test that did not run is
/// not a test that passed.
pub const REQUIRE_PREREQUISITES: &str = "PKM_REQUIRE_PREREQUISITES";

/// Tests of this binary skipped for a missing prerequisite (said again when the binary ends).
static SKIPPED: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// The test `name` cannot run here: `why` (what is missing and how to get it). Under
/// [`REQUIRE_PREREQUISITES`] the test fails with it. Otherwise the skip is written to the
/// terminal past libtest's capture — shown among the results whatever the test's outcome — and
/// counted, and the count is said once more when the test binary ends, after its summary.
pub fn skip(name: &str, why: &str) {
    if std::env::var_os(REQUIRE_PREREQUISITES).is_some() {
        panic!("{name}: {why}; this run requires it ({REQUIRE_PREREQUISITES} is set)");
    }
    SKIPPED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "SKIPPED {name}: {why}");
}

/// At the test binary's end, after libtest's summary: how many of its tests were skipped.
#[used]
#[unsafe(link_section = ".fini_array")]
static SAY_SKIPPED: extern "C" fn() = {
    extern "C" fn say() {
        let n = SKIPPED.load(std::sync::atomic::Ordering::Relaxed);
        if n > 0 {
            let text = format!(
                "{n} test(s) of this binary SKIPPED for a missing prerequisite (see the SKIPPED lines above; {REQUIRE_PREREQUISITES}=1 makes them fail)\n"
            );
            // SAFETY: a write of a buffer this function owns to the process's stderr; at exit
            // the Rust runtime's own stderr may already be gone, the descriptor is not.
            unsafe { libc::write(2, text.as_ptr().cast(), text.len()) };
        }
    }
    say
};

/// The Python packages the interoperability tests use: (pip requirement, module to import).
pub const PYTHON_PACKAGES: [(&str, &str); 2] = [("pymodbus==3.8.6", "pymodbus"), ("asyncua==2.1.0", "asyncua")];

/// A Python in a virtual environment under `target/` with every one of [`PYTHON_PACKAGES`]
/// installed (checked by importing them), made on first use — never the system's Python — once
/// per test binary, however many tests ask at once: one environment and one `pip install` for
/// both (each environment made cost 4 CPU-seconds). `Err`: why there is none (no
/// `python3-venv`, no network), for the test to say it skips.
pub fn python_interop() -> Result<PathBuf, String> {
    static MADE: std::sync::Mutex<Option<Result<PathBuf, String>>> = std::sync::Mutex::new(None);
    let mut made = MADE.lock().unwrap_or_else(|p| p.into_inner());
    made.get_or_insert_with(|| make_venv("interop-venv", &PYTHON_PACKAGES))
        .clone()
}

fn make_venv(name: &str, packages: &[(&str, &str)]) -> Result<PathBuf, String> {
    let venv = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let python = venv.join("bin/python");
    let imports = packages
        .iter()
        .map(|(_, m)| format!("import {m}"))
        .collect::<Vec<_>>()
        .join("; ");
    let has = |python: &PathBuf| {
        std::process::Command::new(python)
            .args(["-c", &imports])
            .stderr(std::process::Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    };
    if has(&python) {
        return Ok(python);
    }
    let made = std::process::Command::new("python3")
        .args(["-m", "venv", "--clear"])
        .arg(&venv)
        .output()
        .map_err(|e| format!("python3 does not run ({e})"))?;
    if !made.status.success() {
        return Err(format!(
            "python3 -m venv failed (Debian: apt-get install python3-venv): {}",
            String::from_utf8_lossy(&made.stderr).lines().last().unwrap_or("")
        ));
    }
    let requirements: Vec<&str> = packages.iter().map(|(r, _)| *r).collect();
    let pip = std::process::Command::new(&python)
        .args(["-m", "pip", "install", "--quiet", "--disable-pip-version-check"])
        .args(&requirements)
        .output()
        .map_err(|e| format!("the virtual environment's python does not run ({e})"))?;
    if !pip.status.success() || !has(&python) {
        return Err(format!(
            "pip install {} into {} failed: {}",
            requirements.join(" "),
            venv.display(),
            String::from_utf8_lossy(&pip.stderr).lines().last().unwrap_or("")
        ));
    }
    Ok(python)
}

/// The npm packages the Node.js interop clients use (exact versions: the same code on every run).
pub const NODE_PACKAGES: [&str; 2] = ["node-opcua-client@2.186.4", "node-opcua-certificate-manager@2.186.4"];

/// A `node` command that finds every one of [`NODE_PACKAGES`], installed with npm into a
/// directory under `target/` on first use (never globally), once per test binary. `Err`: why
/// there is none (no Node.js or npm, no registry), for the test to say it skips.
pub fn node_interop() -> Result<std::process::Command, String> {
    static MADE: std::sync::Mutex<Option<Result<PathBuf, String>>> = std::sync::Mutex::new(None);
    let mut made = MADE.lock().unwrap_or_else(|p| p.into_inner());
    let modules = made
        .get_or_insert_with(|| npm_modules("interop-node", &NODE_PACKAGES))
        .clone()?;
    let mut node = std::process::Command::new("node");
    node.env("NODE_PATH", modules);
    Ok(node)
}

/// Node-RED and its OPC UA nodes (exact versions), for the gateway test.
pub const NODE_RED_PACKAGES: [&str; 2] = ["node-red@4.1.15", "node-red-contrib-opcua@0.2.354"];

/// The `node_modules` directory that holds [`NODE_RED_PACKAGES`], installed with npm under
/// `target/` on first use (never globally). `Err`: why there is none, for the test to say it
/// skips.
pub fn node_red_interop() -> Result<PathBuf, String> {
    static MADE: std::sync::Mutex<Option<Result<PathBuf, String>>> = std::sync::Mutex::new(None);
    let mut made = MADE.lock().unwrap_or_else(|p| p.into_inner());
    made.get_or_insert_with(|| npm_modules("interop-node-red", &NODE_RED_PACKAGES))
        .clone()
}

/// `packages` installed with npm into `target/tmp/DIR` unless Node.js finds them there already:
/// its `node_modules` directory.
fn npm_modules(dir: &str, packages: &[&str]) -> Result<PathBuf, String> {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(dir);
    let modules = dir.join("node_modules");
    let names: Vec<&str> = packages
        .iter()
        .map(|p| p.rsplit_once('@').map_or(*p, |(name, _)| name))
        .collect();
    // Each package found, by its package.json or else its main module (resolved, not loaded:
    // Node-RED would start).
    let requires: String = names
        .iter()
        .map(|n| format!("try {{ require.resolve('{n}/package.json') }} catch (e) {{ require.resolve('{n}') }};"))
        .collect();
    let has = || {
        std::process::Command::new("node")
            .args(["-e", &requires])
            .env("NODE_PATH", &modules)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    };
    if has() {
        return Ok(modules);
    }
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    // A package.json of its own, so npm installs here and not in a parent's project.
    std::fs::write(
        dir.join("package.json"),
        r#"{"name": "pkm-plc-interop", "private": true}"#,
    )
    .map_err(|e| format!("{}: {e}", dir.display()))?;
    let npm = std::process::Command::new("npm")
        .args(["install", "--no-audit", "--no-fund", "--loglevel=error", "--prefix"])
        .arg(&dir)
        .args(packages)
        .output()
        .map_err(|e| format!("npm does not run (Debian: apt-get install nodejs npm): {e}"))?;
    if !npm.status.success() || !has() {
        return Err(format!(
            "npm install {} into {} failed: {}",
            packages.join(" "),
            dir.display(),
            String::from_utf8_lossy(&npm.stderr).lines().last().unwrap_or("")
        ));
    }
    Ok(modules)
}

/// Replays `trace` with the configuration arguments `config` (`--config FILE` or `--machine
/// NAME`): the replay must succeed and find every record identical.
pub fn assert_replays_identically(trace: &Path, config: &[&str]) {
    let mut args = vec!["replay", trace.to_str().expect("utf-8")];
    args.extend_from_slice(config);
    let o = pkm(&args);
    assert_eq!(o.status.code(), Some(0), "{}: {}", trace.display(), stderr(&o));
    assert!(stdout(&o).contains(": identical: "), "{}", stdout(&o));
}

/// A command's standard error as text.
pub fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A command's standard output as text.
pub fn stdout(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// A running `pkm-plc io-sim`, killed when dropped.
pub struct IoSim(pub std::process::Child);

/// A child process killed (and reaped) when dropped: a test that fails midway leaves no PLC
/// running (four such PLCs once ran on, at real-time priority, through the next hour's tests).
pub struct KillOnDrop(pub std::process::Child);

impl std::ops::Deref for KillOnDrop {
    type Target = std::process::Child;
    fn deref(&self) -> &std::process::Child {
        &self.0
    }
}

impl std::ops::DerefMut for KillOnDrop {
    fn deref_mut(&mut self) -> &mut std::process::Child {
        &mut self.0
    }
}

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        if matches!(self.0.try_wait(), Ok(None)) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

impl IoSim {
    /// Stops io-sim as an operator would (SIGTERM) and waits for it: a `--summary` it was
    /// given is written by then.
    pub fn stop(&mut self) -> std::process::ExitStatus {
        // SAFETY: kill sends a signal to the child this helper started; no memory is involved.
        unsafe { libc::kill(self.0.id() as i32, libc::SIGTERM) };
        self.0.wait().expect("io-sim ends")
    }
}

impl Drop for IoSim {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `pkm-plc io-sim --tcp ADDR` (port 0: a free one) with extra `args`; returns it and the
/// address it printed.
pub fn start_io_sim(address: &str, args: &[&str]) -> (IoSim, std::net::SocketAddr) {
    start_io_sim_logging(address, args, std::process::Stdio::null(), "warn")
}

/// As [`start_io_sim`], its log (at `level`) going to `log`.
pub fn start_io_sim_logging(
    address: &str,
    args: &[&str],
    log: impl Into<std::process::Stdio>,
    level: &str,
) -> (IoSim, std::net::SocketAddr) {
    use std::io::BufRead;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_pkm-plc"))
        .args(["io-sim", "--tcp", address])
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("RUST_LOG", level)
        .stdout(std::process::Stdio::piped())
        .stderr(log)
        .spawn()
        .expect("io-sim starts");
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut line)
        .expect("the address line");
    let address = line
        .trim()
        .parse()
        .unwrap_or_else(|e| panic!("io-sim printed {line:?}: {e}"));
    (IoSim(child), address)
}

/// A Modbus RTU frame to unit 1: unit, PDU, CRC-16/MODBUS (little endian).
pub fn rtu_frame(pdu: &[u8]) -> Vec<u8> {
    let mut frame = vec![1];
    frame.extend_from_slice(pdu);
    let crc = pkm_plc::services::sim::pdu::crc16(&frame);
    frame.extend_from_slice(&crc.to_le_bytes());
    frame
}

/// A running `pkm-plc` whose log (stderr) is kept for the whole run — a full pipe would block its
/// logging —, killed when dropped.
pub struct Logged {
    /// The process.
    pub child: std::process::Child,
    log: std::sync::Arc<std::sync::Mutex<String>>,
    reader: Option<std::thread::JoinHandle<()>>,
}

impl Logged {
    /// Spawns `command` (stdout discarded, stderr kept) and waits up to `wait` for a log line
    /// with `marker`; returns the run and the first word after the marker (an address, say).
    /// Panics with the log so far when no such line comes.
    pub fn start(
        mut command: std::process::Command,
        marker: &'static str,
        wait: std::time::Duration,
    ) -> (Logged, String) {
        use std::io::BufRead;
        let mut child = command
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("pkm-plc starts");
        let stderr = child.stderr.take().expect("stderr");
        let (tx, rx) = std::sync::mpsc::channel();
        let log = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
        let kept = std::sync::Arc::clone(&log);
        // The log's reader notes for the scenario that started the run (see `host`).
        let scenario = host::current();
        let reader = std::thread::spawn(move || {
            for line in std::io::BufReader::new(stderr).lines().map_while(Result::ok) {
                host::note_log_line(scenario, &line);
                if let Some(at) = line.split(marker).nth(1) {
                    let _ = tx.send(at.split_whitespace().next().unwrap_or("").to_string());
                }
                if let Ok(mut l) = kept.lock() {
                    l.push_str(&line);
                    l.push('\n');
                }
            }
        });
        let run = Logged {
            child,
            log,
            reader: Some(reader),
        };
        let found = rx
            .recv_timeout(wait)
            .unwrap_or_else(|_| panic!("no log line with \"{marker}\": {}", run.log()));
        (run, found)
    }

    /// Waits up to `within` for a log line with `text` after the first `from` bytes of the log;
    /// the position just after that line (`None`: not within), to wait on from there: a later
    /// wait sees every line after the one found, however late this wait looked (on a busy
    /// machine the next lines may be in the log already). The log is looked at every 20 ms: the
    /// wait follows the run's own output, not a guess of how long the run takes.
    pub fn wait_for(&self, from: usize, text: &str, within: std::time::Duration) -> Option<usize> {
        self.wait_for_unless(from, text, None, within)
    }

    /// As [`Logged::wait_for`], but gives up as soon as a line with `unless` comes first.
    fn wait_for_unless(
        &self,
        from: usize,
        text: &str,
        unless: Option<&str>,
        within: std::time::Duration,
    ) -> Option<usize> {
        let start = std::time::Instant::now();
        while start.elapsed() < within {
            let log = self.log();
            let rest = log.get(from..).unwrap_or("");
            let found = rest.find(text);
            let ended = unless.and_then(|unless| rest.find(unless));
            if let Some(at) = found.filter(|&at| ended.is_none_or(|end| at < end)) {
                let found = from + at;
                let end = log[found..].find('\n').map_or(log.len(), |n| found + n + 1);
                return Some(end);
            }
            if ended.is_some() {
                return None;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        None
    }

    /// Waits up to `within` for the run's main state to become `state` (the line it logs then)
    /// after the first `from` bytes of the log; the log's length then, to wait on from there.
    /// Real-time tests act from there, not at times guessed from the start — on a busy machine
    /// referencing ends later. An ERROR ends the wait at once: only an operator's
    /// acknowledgment leaves it.
    pub fn wait_for_state(&self, from: usize, state: &str, within: std::time::Duration) -> usize {
        let unless = (state != "ERROR").then_some(" s: ERROR (");
        self.wait_for_unless(from, &format!(" s: {state}"), unless, within)
            .unwrap_or_else(|| {
                let log = self.log();
                match unless.filter(|unless| log.get(from..).is_some_and(|rest| rest.contains(unless))) {
                    Some(_) => panic!("not {state}: an ERROR first:\n{log}"),
                    None => panic!("not {state} within {within:?}:\n{log}"),
                }
            })
    }

    /// Asks the run to end (SIGTERM) and waits for it: outputs safe, summary and trace written.
    pub fn terminate(&mut self) -> std::process::ExitStatus {
        // SAFETY: kill sends a signal to the child this helper started; no memory is involved.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        self.wait()
    }

    /// The log so far.
    pub fn log(&self) -> String {
        self.log.lock().map(|l| l.clone()).unwrap_or_default()
    }

    /// Waits for the run to end; its whole log is kept by then.
    pub fn wait(&mut self) -> std::process::ExitStatus {
        let status = self.child.wait().expect("the run ends");
        if let Some(reader) = self.reader.take() {
            let _ = reader.join();
        }
        status
    }
}

impl Drop for Logged {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Each joint's variables in a trace, by index into its variables: the position the PLC reads
/// from the station's counter (`JOINTk_POSITION`, a fast output) and the commanded position the
/// main task hands the fast one (`JOINTk_SETPOINT`; the TRIJOINT's `setpoint_left_mm`,
/// `setpoint_right_mm`).
fn joint_variables(variables: &[(String, pkm_plc::image::VarType)]) -> Vec<(usize, usize)> {
    let index = |name: &str| variables.iter().position(|(n, _)| n == name);
    (1..)
        .map_while(|k: usize| {
            let position = index(&format!("JOINT{k}_POSITION"))?;
            let commanded = index(&format!("JOINT{k}_SETPOINT"))
                .or_else(|| index(["setpoint_left_mm", "setpoint_right_mm"].get(k - 1)?))?;
            Some((position, commanded))
        })
        .collect()
}

/// The farthest the station's counter may stand from the commanded position once the machine
/// stands still after a program (mm): the steppers stand within a step, the DC drives' PI
/// regulators within a few counts (measured: at most 0.0025 mm over TCP and RTU).
pub const AT_REST_MM: f64 = 0.01;

/// The farthest a joint may truly stand from where the PLC reads it (mm): the reference
/// position is latched at the slow approach's speed (0.5 mm/s on the joint machines) from a
/// switch sampled every cycle, so to a few thousandths of a millimetre.
pub const REFERENCED_MM: f64 = 0.01;

/// What `what`'s run did, from its trace and the station's report (`io-sim --summary`, or the
/// in-process station's, as JSON): at the end of its program, once the machine stood still (the
/// last fast cycle before the next motion), the station's counters stand within
/// [`AT_REST_MM`] of the commanded positions; at the end of the run each joint truly is where
/// the PLC read it last (within [`REFERENCED_MM`]), and no stepper lost a step. Returns a line
/// for the log.
pub fn check_positions(what: &str, trace: &Path, station: &serde_json::Value) -> String {
    use pkm_plc::services::trace::read::TraceReader;
    let mut reader = TraceReader::open(trace).unwrap_or_else(|e| panic!("{what}: {e}"));
    let joints = joint_variables(reader.variables());
    let n = joints.len();
    assert!(n > 0, "{what}: no joint in the trace");
    let class = |name: &str| reader.header().task_classes.iter().position(|c| c.name == name);
    let (fast, main) = (
        class("fast").expect("a fast class"),
        class("main").expect("a main class"),
    );
    // Each class's values as its cycles saw them: a record holds only what changed.
    let mut values = vec![vec![f64::NAN; reader.variables().len()]; reader.header().task_classes.len()];
    // The joints (read, commanded) at a fast cycle.
    let at = |values: &[f64]| -> Vec<(f64, f64)> { joints.iter().map(|&(p, c)| (values[p], values[c])).collect() };
    // The program's end: the first main cycle in READY after AUTO; the machine stands until the
    // next main cycle in another state (the jog). Its last fast cycle before that is `stood`.
    #[derive(PartialEq)]
    enum Phase {
        BeforeAuto,
        Auto,
        Ended,
        Moved,
    }
    let (mut phase, mut stood, mut last) = (Phase::BeforeAuto, None, None);
    while let Some(r) = reader.next_record().unwrap_or_else(|e| panic!("{what}: {e}")) {
        for (k, v) in r.inputs.iter().chain(&r.outputs) {
            if let Value::Real(x) = v {
                values[r.class][*k] = *x;
            }
        }
        if r.class == fast {
            last = Some(at(&values[fast]));
            if phase == Phase::Ended {
                stood = last.clone();
            }
        }
        if let (true, Some(state)) = (r.class == main, r.state.as_deref()) {
            phase = match (phase, state) {
                (Phase::BeforeAuto, "AUTO") => Phase::Auto,
                (Phase::Auto, "READY") => Phase::Ended,
                (Phase::Ended, s) if s != "READY" => Phase::Moved,
                (p, _) => p,
            };
        }
    }
    let stood = stood.unwrap_or_else(|| panic!("{what}: no program's end in the trace"));
    let mut worst_end: f64 = 0.0;
    for (k, (position, commanded)) in (1..).zip(&stood) {
        assert!(
            (position - commanded).abs() <= AT_REST_MM,
            "{what}: at the program's end joint {k} stands at {position} mm, commanded {commanded} mm"
        );
        worst_end = worst_end.max((position - commanded).abs());
    }
    // The run's end: the PLC's last reading against the machine's truth.
    let last = last.unwrap_or_else(|| panic!("{what}: no fast cycle"));
    let truth = station["joints"]
        .as_array()
        .unwrap_or_else(|| panic!("{what}: no joints in the station's report {station}"));
    assert_eq!(truth.len(), n, "{what}: joints in the station's report {station}");
    let read: Vec<f64> = last.iter().map(|&(read, _)| read).collect();
    let real: Vec<f64> = truth
        .iter()
        .map(|j| j["position_mm"].as_f64().expect("position_mm"))
        .collect();
    let worst_truth = read.iter().zip(&real).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    assert!(
        worst_truth <= REFERENCED_MM,
        "{what}: the joints are at {real:?} mm, the PLC read {read:?} mm last: {station}"
    );
    for (k, joint) in (1..).zip(truth) {
        assert_eq!(
            joint["lost_steps"].as_f64(),
            Some(0.0),
            "{what}: joint {k} lost steps: {station}"
        );
    }
    format!(
        "counters within {worst_end:.4} mm of the commanded positions at the program's end; \
         joints within {worst_truth:.4} mm of the PLC's last reading, no step lost"
    )
}

/// One Modbus TCP request PDU (to unit 1) on a raw connection; returns the response PDU.
pub fn modbus_transact(s: &mut std::net::TcpStream, transaction: u16, pdu: &[u8]) -> Vec<u8> {
    use std::io::{Read, Write};
    let mut frame = transaction.to_be_bytes().to_vec();
    frame.extend([0, 0]);
    frame.extend(((pdu.len() + 1) as u16).to_be_bytes());
    frame.push(1);
    frame.extend(pdu);
    s.write_all(&frame).expect("send");
    let mut header = [0u8; 7];
    s.read_exact(&mut header).expect("response header");
    assert_eq!(header[..2], transaction.to_be_bytes(), "transaction identifier echoed");
    let len = usize::from(u16::from_be_bytes([header[4], header[5]])) - 1;
    let mut response = vec![0u8; len];
    s.read_exact(&mut response).expect("response PDU");
    response
}

/// A raw Modbus TCP connection to `address`, its reads waiting at most 10 s.
pub fn modbus_connect(address: std::net::SocketAddr) -> std::net::TcpStream {
    let s = std::net::TcpStream::connect(address).expect("connect");
    s.set_read_timeout(Some(std::time::Duration::from_secs(10)))
        .expect("timeout");
    s
}
