//! The operator screen's inputs in virtual time (no server: its command sink written directly,
//! as the server writes it): the screen's jog of one pose coordinate moves that coordinate alone,
//! its STOP is an ERROR like the panel's.

use crate::common;

use common::{get, machine_config, transitions};
use pkm_joints::vars;
use pkm_plc::compose::{self, Options, Setup};

#[test]
fn the_screens_jog_of_one_axis_moves_that_axis_alone_and_its_stop_is_the_panels() {
    let setup = Setup::new(machine_config("hexapod", |_| {})).expect("a machine");
    let built = compose::build(
        setup,
        Options {
            hmi: true,
            ..Options::default()
        },
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let (mut plc, sink) = (built.plc, built.hmi.expect("the screen's commands"));
    let mut at_ready: Option<[f64; 6]> = None;
    let mut after_jog: Option<[f64; 6]> = None;
    let seen = transitions(&mut plc, 16_000, |plc, t| {
        let tool: [f64; 6] = std::array::from_fn(|c| get(plc, vars::TOOL[c]));
        match t {
            // READY at 7.65 s: +z (the third pose coordinate) held for two seconds.
            9_000 => {
                at_ready = Some(tool);
                sink.update(|c| {
                    c.jog = [0.6, 0.0];
                    c.jog_axis = 3;
                });
            }
            11_000 => sink.update(|c| c.jog = [0.0; 2]),
            13_000 => {
                after_jog = Some(tool);
                sink.update(|c| c.presses[pkm_plc::hmi::commands::press::STOP] += 1);
            }
            _ => {}
        }
    });
    let (before, after) = (at_ready.expect("READY"), after_jog.expect("jogged"));
    assert!(after[2] - before[2] > 5.0, "z moved: {before:?} → {after:?}");
    for c in [0, 1, 3, 4, 5] {
        assert!(
            (after[c] - before[c]).abs() < 0.01,
            "coordinate {c} stayed: {before:?} → {after:?}"
        );
    }
    let names: Vec<&str> = seen.iter().map(|(_, s, _)| s.as_str()).collect();
    assert_eq!(
        names,
        ["REBOOT", "INIT", "READY", "MOTION", "READY", "ERROR"],
        "{seen:?}"
    );
    assert_eq!(seen[5].2.as_deref(), Some("STOP"));
    assert!(seen[5].0 - 13_000 <= 50, "within a main cycle: {seen:?}");
}

#[test]
fn the_screen_draws_the_mechanisms_at_the_measured_joints() {
    use pkm_plc::hmi::mechanism::Mechanism;
    use pkm_plc::image::Value;
    let setup = Setup::new(common::loaded(&common::repo_config())).expect("the TRIJOINT");
    let plc = setup.plc(setup.declaring_bus().expect("a bus")).expect("a PLC");
    let mut mechanism = Mechanism::of(&setup, &plc).expect("the TRIJOINT's kinematics draws");
    let mut image = plc.global_image().to_vec();
    for name in ["position_left_mm", "position_right_mm"] {
        let i = plc.vars().index_of(name).expect("a position");
        image[usize::from(i)] = Value::Real(125.0);
    }
    let links = mechanism.links(&image).expect("a pose at mid-travel");
    assert_eq!(links.len(), 6, "two guides, the rod, the arm's triangle");
    // Outside the travel: no pose, nothing drawn.
    let i = plc.vars().index_of("position_left_mm").expect("a position");
    image[usize::from(i)] = Value::Real(1e6);
    assert!(mechanism.links(&image).is_none());
    // The hexapod's: six struts and the outlines of base and platform, at its home lengths.
    let hexapod = Setup::new(machine_config("hexapod", |_| {})).expect("the hexapod");
    let plc = hexapod.plc(hexapod.declaring_bus().expect("a bus")).expect("a PLC");
    let mut mechanism = Mechanism::of(&hexapod, &plc).expect("the hexapod's kinematics draws");
    let mut image = plc.global_image().to_vec();
    for j in 0..6 {
        let i = plc.vars().index_of(vars::JOINT_POSITION[j].name()).expect("a position");
        image[usize::from(i)] = Value::Real(755.57);
    }
    assert_eq!(mechanism.links(&image).map(<[_]>::len), Some(18));
}
