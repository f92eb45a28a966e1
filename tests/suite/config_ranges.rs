//! Every number a machine's configuration gives has a range, and a value outside it is
//! refused by `check` with its path. Each machine's configuration (the TRIJOINT's with every
//! program parameter spelt out) is tried with extreme values at every numeric key.

use pkm_plc::compose::{Options, Setup};
use pkm_plc::runtime::config;

/// The TRIJOINT's configuration with every parameter of its programs spelt out at its default,
/// so that each is tried.
fn trijoint() -> serde_json::Value {
    let mut c = crate::common::repo_config();
    let params = [
        serde_json::json!({"counts_per_mm": 7000.0, "max_counts_per_cycle": 12000}),
        serde_json::json!({"kp": 0.25, "ki": 1.0, "velocity_ff": 0.0125, "accel_ff": 0.000625, "output_limit": 1.0, "max_following_error_mm": 5.0}),
        serde_json::json!({
            "stop_lockout_ms": 500, "pwm_period_us": 50, "init_speed_mm_s": 15.0, "approach_speed_mm_s": 1.0,
            "creep_speed_mm_s": 0.012, "approach_distance_mm": 0.5, "creep_distance_mm": 0.03, "search_timeout_s": 30.0,
            "start_position_mm": [125.0, 125.0], "soft_limit_margin_mm": 2.0, "max_speed_mm_s": 20.0,
            "max_joint_speed_mm_s": 40.0, "brake_decel_mm_s2": 100.0, "dead_zone": 0.05, "singularity_threshold": 0.3
        }),
    ];
    let programs = [(0, 0), (0, 1), (1, 0)];
    for ((class, program), p) in programs.iter().zip(params) {
        c["task_classes"][class]["programs"][program]["params"] = p;
    }
    c["timing"]["spin_us"] = 0.into();
    c["joystick"] = serde_json::json!({
        "x_axis": 0, "y_axis": 1, "invert_x": false, "invert_y": true, "dead_zone": 0.08,
        "axis_range": [-32768, 32767], "stop_button": 288, "deadman_button": 289, "buttons": [290, 291, 292, 293]
    });
    let drive = serde_json::json!({
        "v_max_mm_s": 80.0, "tau_s": 0.05, "counts_per_mm": 7000.0, "lower_switch_mm": 0.0, "upper_switch_mm": 250.0,
        "hard_stop_min_mm": -3.0, "hard_stop_max_mm": 253.0, "start_mm": 125.0
    });
    c["plant"] = serde_json::json!({"step_us": 1000, "mechanism": true, "left": drive.clone(), "right": drive});
    c["nc"] = serde_json::json!({"work_offsets": {"G55": [20.0, 0.0]}, "axis_speed": [50.0, 50.0], "axis_accel": [500.0, 500.0]});
    c
}

/// Every numeric leaf of `v`, as a JSON pointer and a path as messages give it.
fn numbers(v: &serde_json::Value, pointer: String, path: String, out: &mut Vec<(String, String)>) {
    match v {
        serde_json::Value::Number(_) => out.push((pointer, path)),
        serde_json::Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                numbers(x, format!("{pointer}/{i}"), format!("{path}[{i}]"), out);
            }
        }
        serde_json::Value::Object(o) => {
            for (k, x) in o {
                let path = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                numbers(x, format!("{pointer}/{k}"), path, out);
            }
        }
        _ => {}
    }
}

/// The configuration `json` of a machine as `check` takes it: Ok, or the error's text.
fn check(json: &serde_json::Value, dir: &std::path::Path) -> Result<(), String> {
    let mut loaded = config::parse(&json.to_string(), "cfg.json").map_err(|e| e.to_string())?;
    loaded.dir = Some(dir.to_path_buf());
    let setup = Setup::new(loaded).map_err(|e| e.to_string())?;
    pkm_plc::compose::build(setup, Options::default())
        .map(|_| ())
        .map_err(|e| e.to_string())
}

/// Whether the refusal `e` names `path`: the key itself, the list it is an element of (`a[1][0]`
/// is named by `a[1]` or `a`, whose message shows its elements), or the object it is a key of
/// with the key in the message (an order of positions: `at plant.left: … upper_switch_mm …`).
fn names(e: &str, path: &str) -> bool {
    let at = |p: &str| e.contains(&format!("at {p}:")) || e.contains(&format!("{p}:"));
    let mut p = path;
    loop {
        if at(p) {
            return true;
        }
        match p.strip_suffix(']').and_then(|q| q.rsplit_once('[')) {
            Some((parent, _)) => p = parent,
            None => break,
        }
    }
    match p.rsplit_once('.') {
        Some((parent, key)) => at(parent) && e.contains(key),
        None => false,
    }
}

/// Where a zero is a value the machine can have: a coordinate, an offset, a switch at the
/// origin, a gain or feed-forward left out, a dead zone, no spin.
fn zero_is_a_value(path: &str) -> bool {
    let last = path.rsplit('.').next().unwrap_or(path);
    let key = last.split('[').next().unwrap_or(last);
    matches!(
        key,
        "m_perp"
            | "spin_us"
            | "dead_zone"
            | "ki"
            | "velocity_ff"
            | "accel_ff"
            | "start_mm"
            | "switch_mm"
            | "reference_switch_mm"
            | "home"
            | "base"
            | "platform"
            | "xr"
            | "xr1"
            | "xr2"
            | "dx3"
            | "dy3"
            | "dz3"
            | "zz3"
            | "travel"
            | "h1_travel"
            | "h2_travel"
            | "lower_switch_mm"
            | "x_axis"
            | "y_axis"
            | "work_offsets"
            | "realtime_priority"
            | "start_position_mm"
            | "hard_stops_mm"
            | "limit_switches_mm"
            | "world_limits"
            | "strut_travel"
            | "hard_stop_min_mm"
            | "angular_speed_deg_s"
            | "G54"
            | "G55"
            | "G56"
            | "G57"
            | "G58"
            | "G59"
            | "axis_range"
            | "buttons"
            | "stop_button"
            | "deadman_button"
    )
}

#[test]
fn every_number_of_every_machine_has_a_range_and_an_extreme_value_is_refused_with_its_path() {
    let root = crate::common::root();
    let machines: Vec<(&str, serde_json::Value, std::path::PathBuf)> =
        std::iter::once(("trijoint", trijoint(), root.to_path_buf()))
            .chain(["pn101", "ox-x", "ox-o", "hexapod"].iter().map(|m| {
                (
                    *m,
                    crate::common::read_json(&root.join("machines").join(format!("{m}.json"))),
                    root.join("machines"),
                )
            }))
            .collect();
    let (mut tried, mut keys) = (0, 0);
    let mut accepted = Vec::new();
    let mut unnamed = Vec::new();
    for (machine, json, dir) in &machines {
        assert_eq!(check(json, dir), Ok(()), "{machine} as shipped");
        let mut leaves = Vec::new();
        numbers(json, String::new(), String::new(), &mut leaves);
        keys += leaves.len();
        for (pointer, path) in &leaves {
            let mut extremes = vec![
                serde_json::json!(1e308),
                serde_json::json!(-1e308),
                serde_json::json!(9223372036854775807u64),
            ];
            if !zero_is_a_value(path) {
                extremes.push(serde_json::json!(0));
            }
            for extreme in extremes {
                let mut changed = json.clone();
                *changed.pointer_mut(pointer).expect("the leaf") = extreme.clone();
                tried += 1;
                match check(&changed, dir) {
                    Ok(()) => accepted.push(format!("{machine}: {path} = {extreme}")),
                    Err(e) if !names(&e, path) => unnamed.push(format!("{machine}: {path} = {extreme}: {e}")),
                    Err(_) => {}
                }
            }
        }
    }
    eprintln!(
        "{tried} extreme values tried on {keys} numeric keys of 5 machines, {} accepted, {} refused without the key's path",
        accepted.len(),
        unnamed.len()
    );
    assert!(
        accepted.is_empty(),
        "{} accepted:\n{}",
        accepted.len(),
        accepted.join("\n")
    );
    assert!(
        unnamed.is_empty(),
        "{} refused without naming the key:\n{}",
        unnamed.len(),
        unnamed.join("\n")
    );
}

/// Values valid each on its own that do not hold together are refused with their
/// path: world limits that leave out the reference pose, a main program's reference switch that
/// is not the simulated machine's.
#[test]
fn values_that_do_not_hold_together_are_refused_with_their_paths() {
    let root = crate::common::root();
    let machine = |name: &str, edit: &dyn Fn(&mut serde_json::Value)| {
        let mut json = crate::common::read_json(&root.join("machines").join(format!("{name}.json")));
        let main = json["task_classes"]
            .as_array_mut()
            .expect("classes")
            .iter_mut()
            .flat_map(|c| c["programs"].as_array_mut().expect("programs").iter_mut())
            .find(|p| p["program"] == format!("{name}.main"))
            .expect("the main program");
        edit(&mut main["params"]);
        check(&json, &root.join("machines"))
    };
    assert_eq!(
        machine("ox-x", &|p| p["world_limits"][0] = serde_json::json!([-150.0, -1.0])),
        Err("cfg.json: at task_classes[1].programs[0].params.world_limits[0]: must hold the reference pose, x = 0 (the machine frame's origin, where referencing leaves the tool), got [-150, -1]".into())
    );
    assert_eq!(
        machine("pn101", &|p| p["joints"][0]["reference"]["direction"] = (-1.0).into()),
        Err("cfg.json: at task_classes[1].programs[0].params.joints[0].reference.direction: joint 1's reference switch is on beyond it in the + direction in the simulated machine (plant.joints[0].reference_direction), got -1: the search would go the other way".into())
    );
    for wrong in [0.0, -1.0] {
        assert_eq!(
            machine("pn101", &|p| p["joints"][1]["reference"]["switch_mm"] = wrong.into()),
            Err(format!(
                "cfg.json: at task_classes[1].programs[0].params.joints[1].reference.switch_mm: joint 2's reference switch is at 55 mm in the simulated machine (plant.joints[1].reference_switch_mm), got {wrong}: both describe the same switch"
            ))
        );
    }
    // The hexapod's home is a pose, its origin too: a world limit beside it is refused the same.
    let refused = machine("hexapod", &|p| p["world_limits"][5] = serde_json::json!([1.0, 20.0]));
    assert!(
        refused
            .as_ref()
            .is_err_and(|e| e.contains("params.world_limits[5]: must hold the reference pose, c = 0")),
        "{refused:?}"
    );
}
