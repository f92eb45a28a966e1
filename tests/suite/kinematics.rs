//! Kinematics of the four machines: round trips, Jacobians, errors instead of NaN, hexapod
//! convergence, and the TRIJOINT's conditioning (docs/kinematics.md).

use pkm_kinematics::hexapod::Hexapod;
use pkm_kinematics::{KinError, Kinematics, KinematicsConfig, MAX_DOF, Machine};
use proptest::prelude::*;

fn kin(machine: Machine) -> Box<dyn Kinematics> {
    KinematicsConfig::default().build(machine)
}

/// Joint vectors spread over the whole travel: `u` in [0, 1]^6 scaled to each joint's limits.
fn joints_at(k: &dyn Kinematics, u: &[f64; 6]) -> [f64; 6] {
    let mut q = [0.0; 6];
    for (i, [lo, hi]) in k.joint_limits().iter().enumerate() {
        q[i] = lo + (hi - lo) * u[i];
    }
    q
}

fn unit6() -> impl Strategy<Value = [f64; 6]> {
    prop::array::uniform6(0.0f64..=1.0)
}

/// IK(FK(q)) = q and FK(IK(x)) = x to 1e-9 wherever FK succeeds.
fn round_trip(machine: Machine, u: [f64; 6]) -> Result<bool, TestCaseError> {
    let k = kin(machine);
    let n = k.dof();
    let q = joints_at(k.as_ref(), &u);
    let mut x = [0.0; 6];
    if let Err(e) = k.forward(&q[..n], None, &mut x[..n]) {
        prop_assert!(!matches!(e, KinError::NotFinite(_)), "{e}");
        return Ok(false);
    }
    prop_assert!(x[..n].iter().all(|v| v.is_finite()));
    let mut q2 = [0.0; 6];
    k.inverse(&x[..n], &mut q2[..n])
        .map_err(|e| TestCaseError::fail(format!("IK(FK({q:?})) failed: {e}")))?;
    for i in 0..n {
        prop_assert!(
            (q2[i] - q[i]).abs() <= 1e-9,
            "{machine:?}: IK(FK(q)) joint {i}: {} vs {}",
            q2[i],
            q[i]
        );
    }
    let mut x2 = [0.0; 6];
    k.forward(&q2[..n], Some(&x[..n]), &mut x2[..n])
        .map_err(|e| TestCaseError::fail(e.to_string()))?;
    for i in 0..n {
        prop_assert!(
            (x2[i] - x[i]).abs() <= 1e-9,
            "{machine:?}: FK(IK(x)) coordinate {i}: {} vs {}",
            x2[i],
            x[i]
        );
    }
    Ok(true)
}

proptest! {
    // 2000 samples that assemble each; a sample that does not is rejected and drawn again, and
    // more than 4000 rejections fail the test (a mechanism that hardly ever assembles would
    // otherwise pass without a single round trip).
    #![proptest_config(ProptestConfig { cases: 2000, max_global_rejects: 4000, ..ProptestConfig::default() })]

    #[test]
    fn trijoint_round_trip(u in unit6()) { prop_assume!(round_trip(Machine::Trijoint, u)?); }
    #[test]
    fn pn101_round_trip(u in unit6()) { prop_assume!(round_trip(Machine::Pn101, u)?); }
    #[test]
    fn ox_x_round_trip(u in unit6()) { prop_assume!(round_trip(Machine::OxX, u)?); }
    #[test]
    fn ox_o_round_trip(u in unit6()) { prop_assume!(round_trip(Machine::OxO, u)?); }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 500, ..ProptestConfig::default() })]

    /// The hexapod over poses ±50 mm / ±10° around home (strut space is mostly unassemblable, so
    /// sampling joints uniformly would test little).
    #[test]
    fn hexapod_round_trip(u in unit6()) {
        let k = kin(Machine::Hexapod);
        let mut pose = [0.0, 0.0, 508.0, 0.0, 0.0, 0.0];
        for i in 0..6 {
            pose[i] += (u[i] * 2.0 - 1.0) * if i < 3 { 50.0 } else { 10.0 };
        }
        let mut q = [0.0; 6];
        k.inverse(&pose, &mut q).map_err(|e| TestCaseError::fail(e.to_string()))?;
        round_trip_hexapod(k.as_ref(), &pose, &q)?;
    }

    #[test]
    fn jacobians_match_central_differences(machine_index in 0usize..5, u in unit6()) {
        let machine = Machine::ALL[machine_index];
        let k = kin(machine);
        let n = k.dof();
        // A pose well inside the workspace: the joints 5 % inside their travel.
        let pose = if machine == Machine::Hexapod {
            let mut p = [0.0, 0.0, 508.0, 0.0, 0.0, 0.0];
            for i in 0..6 { p[i] += (u[i] * 2.0 - 1.0) * if i < 3 { 50.0 } else { 10.0 }; }
            p
        } else {
            let mut shrunk = u;
            for v in shrunk.iter_mut() { *v = 0.05 + 0.9 * *v; }
            let q = joints_at(k.as_ref(), &shrunk);
            let mut x = [0.0; 6];
            if k.forward(&q[..n], None, &mut x[..n]).is_err() { return Ok(()); }
            x
        };
        if k.singularity_measure(&pose[..n]).map_or(true, |m| m < 0.05) { return Ok(()); }
        let mut q = [0.0; 6];
        if k.inverse(&pose[..n], &mut q[..n]).is_err() { return Ok(()); }
        let mut jinv = [0.0; MAX_DOF * MAX_DOF];
        let mut j = [0.0; MAX_DOF * MAX_DOF];
        k.inverse_jacobian(&pose[..n], &mut jinv).map_err(|e| TestCaseError::fail(e.to_string()))?;
        k.jacobian(&pose[..n], &mut j).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let h = 1e-4;
        // ∂q/∂x by central differences of IK.
        for c in 0..n {
            let (mut xp, mut xm) = (pose, pose);
            xp[c] += h;
            xm[c] -= h;
            let (mut qp, mut qm) = ([0.0; 6], [0.0; 6]);
            if k.inverse(&xp[..n], &mut qp[..n]).is_err() || k.inverse(&xm[..n], &mut qm[..n]).is_err() { return Ok(()); }
            for r in 0..n {
                let fd = (qp[r] - qm[r]) / (2.0 * h);
                let an = jinv[r * MAX_DOF + c];
                prop_assert!((fd - an).abs() <= 1e-5 * (1.0 + an.abs()), "{machine:?} dq{r}/dx{c}: analytic {an}, differences {fd}");
            }
        }
        // ∂x/∂q by central differences of FK.
        for c in 0..n {
            let (mut qp, mut qm) = (q, q);
            qp[c] += h;
            qm[c] -= h;
            let (mut xp, mut xm) = ([0.0; 6], [0.0; 6]);
            if k.forward(&qp[..n], Some(&pose[..n]), &mut xp[..n]).is_err() || k.forward(&qm[..n], Some(&pose[..n]), &mut xm[..n]).is_err() { return Ok(()); }
            for r in 0..n {
                let fd = (xp[r] - xm[r]) / (2.0 * h);
                let an = j[r * MAX_DOF + c];
                prop_assert!((fd - an).abs() <= 1e-5 * (1.0 + an.abs()), "{machine:?} dx{r}/dq{c}: analytic {an}, differences {fd}");
            }
        }
    }

    /// Far outside the workspace and the travel: errors, never NaN, never a panic.
    #[test]
    fn outside_the_workspace_gives_errors_not_nan(machine_index in 0usize..5, v in prop::array::uniform6(-5000.0f64..5000.0)) {
        let k = kin(Machine::ALL[machine_index]);
        let n = k.dof();
        let mut out = [0.0; 6];
        if k.inverse(&v[..n], &mut out[..n]).is_ok() {
            prop_assert!(out[..n].iter().all(|x| x.is_finite()));
        }
        let mut out = [0.0; 6];
        if k.forward(&v[..n], None, &mut out[..n]).is_ok() {
            prop_assert!(out[..n].iter().all(|x| x.is_finite()));
        }
        if let Ok(m) = k.singularity_measure(&v[..n]) {
            prop_assert!(m.is_finite() && (0.0..=1.0).contains(&m));
        }
    }
}

fn round_trip_hexapod(k: &dyn Kinematics, pose: &[f64; 6], q: &[f64; 6]) -> Result<(), TestCaseError> {
    let mut x = [0.0; 6];
    k.forward(q, None, &mut x)
        .map_err(|e| TestCaseError::fail(format!("FK from home: {e}")))?;
    for i in 0..6 {
        prop_assert!(
            (x[i] - pose[i]).abs() <= 1e-9,
            "FK(IK(x)) coordinate {i}: {} vs {}",
            x[i],
            pose[i]
        );
    }
    let mut q2 = [0.0; 6];
    k.inverse(&x, &mut q2).map_err(|e| TestCaseError::fail(e.to_string()))?;
    for i in 0..6 {
        prop_assert!(
            (q2[i] - q[i]).abs() <= 1e-9,
            "IK(FK(q)) strut {i}: {} vs {}",
            q2[i],
            q[i]
        );
    }
    Ok(())
}

#[test]
fn every_machine_round_trips_over_most_of_its_travel() {
    // A deterministic grid: the round trip holds at every assemblable sample, and most samples of
    // the default travel are assemblable (so the property tests above are not vacuous).
    for machine in [Machine::Trijoint, Machine::Pn101, Machine::OxX, Machine::OxO] {
        let mut ok = 0;
        let mut total = 0;
        for i in 0..=20 {
            for j in 0..=20 {
                for l in 0..=4 {
                    let u = [i as f64 / 20.0, j as f64 / 20.0, l as f64 / 4.0, 0.0, 0.0, 0.0];
                    total += 1;
                    if round_trip(machine, u).unwrap_or_else(|e| panic!("{machine:?} {u:?}: {e}")) {
                        ok += 1;
                    }
                }
            }
        }
        eprintln!("{machine:?}: {ok} of {total} grid samples assemble");
        assert!(
            ok * 2 > total,
            "{machine:?}: only {ok} of {total} grid samples assemble"
        );
    }
}

#[test]
fn nan_inputs_are_errors() {
    for machine in Machine::ALL {
        let k = kin(machine);
        let n = k.dof();
        let bad = [f64::NAN; 6];
        let mut out = [0.0; 6];
        assert_eq!(
            k.inverse(&bad[..n], &mut out[..n]),
            Err(KinError::NotFinite("the pose")),
            "{machine:?}"
        );
        assert_eq!(
            k.forward(&bad[..n], None, &mut out[..n]),
            Err(KinError::NotFinite("the joints")),
            "{machine:?}"
        );
    }
}

#[test]
fn specific_errors_say_what_failed() {
    let t = kin(Machine::Trijoint);
    let mut q = [0.0; 2];
    assert_eq!(
        t.inverse(&[100.0, 500.0], &mut q).unwrap_err().to_string(),
        "joint 2 = 384.673380 mm is outside its travel 0 … 250 mm"
    );
    assert_eq!(
        t.inverse(&[5000.0, 0.0], &mut q).unwrap_err().to_string(),
        "pose unreachable: the arm cannot reach M: guide 2 does not meet the circle of radius |AM| around M"
    );
    let mut x = [0.0; 2];
    assert_eq!(
        t.forward(&[-1.0, 0.0], None, &mut x).unwrap_err(),
        KinError::JointOutOfRange {
            joint: 1,
            value: -1.0,
            min: 0.0,
            max: 250.0
        }
    );
    let h = kin(Machine::Hexapod);
    let mut x = [0.0; 6];
    assert_eq!(
        h.forward(&[650.0; 6], None, &mut x).unwrap_err().to_string(),
        "forward kinematics diverged: summed strut-length error 633.4 mm exceeds 500 mm"
    );
}

#[test]
fn trijoint_is_well_conditioned_over_the_whole_travel_box() {
    // docs/kinematics.md (TRIJOINT): the singular-value ratio stays above 0.5 over the travel box.
    let k = kin(Machine::Trijoint);
    let mut worst = f64::INFINITY;
    for i in 0..=50 {
        for j in 0..=50 {
            let q = [250.0 * i as f64 / 50.0, 250.0 * j as f64 / 50.0];
            let mut x = [0.0; 2];
            k.forward(&q, None, &mut x).expect("the whole travel box assembles");
            worst = worst.min(k.singularity_measure(&x).expect("measure"));
        }
    }
    assert!(worst > 0.5, "smallest singular-value ratio {worst}");
}

#[test]
fn hexapod_fk_converges_from_home_in_few_iterations() {
    let config = KinematicsConfig::default();
    let hex = Hexapod::new(&config.hexapod);
    let mut rng = 0x2545_F491_4F6C_DD1Du64;
    let mut uniform = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let mut histogram = [0usize; 16];
    for _ in 0..5000 {
        let mut pose = config.hexapod.home;
        for (k, p) in pose.iter_mut().enumerate() {
            *p += uniform() * if k < 3 { 50.0 } else { 10.0 };
        }
        let mut q = [0.0; 6];
        hex.inverse(&pose, &mut q).expect("IK inside ±50 mm / ±10°");
        let mut x = [0.0; 6];
        let iterations = hex.forward_counted(&q, None, &mut x).expect("FK converges from home");
        histogram[iterations.min(15)] += 1;
        for i in 0..6 {
            assert!((x[i] - pose[i]).abs() <= 1e-9, "{pose:?} → {x:?}");
        }
    }
    assert_eq!(
        histogram[7..].iter().sum::<usize>(),
        0,
        "more than 6 Newton steps needed: {histogram:?}"
    );
}

/// The machine frames of docs/machines.md: pn101 and the O-X glide at home with every joint at its
/// reference (FK(0, …)), the hexapod at its home pose.
fn frame(machine: Machine) -> pkm_kinematics::frame::MachineFrame {
    use pkm_kinematics::frame::{Home, MachineFrame};
    let config = KinematicsConfig::default();
    let home = config.hexapod.home;
    let at = match machine {
        Machine::Hexapod => Home::Pose(&home),
        _ => Home::Joints(&[0.0; 6]),
    };
    MachineFrame::new(config.build(machine), at).expect("home is a pose of the machine")
}

const FRAMED: [Machine; 4] = [Machine::Pn101, Machine::OxX, Machine::OxO, Machine::Hexapod];

#[test]
fn home_is_the_origin_of_the_machine_frame() {
    for machine in FRAMED {
        let f = frame(machine);
        let n = f.dof();
        let mut pose = [1.0; 6];
        f.forward(f.home_joints(), None, &mut pose[..n]).expect("FK at home");
        assert!(pose[..n].iter().all(|c| c.abs() < 1e-9), "{machine:?}: {pose:?}");
        let mut q = [1.0; 6];
        f.inverse(&[0.0; 6][..n], &mut q[..n]).expect("IK at the origin");
        for (a, b) in q[..n].iter().zip(f.home_joints()) {
            assert!((a - b).abs() < 1e-9, "{machine:?}: {q:?} against {:?}", f.home_joints());
        }
        assert!(f.singularity_measure(&[0.0; 6][..n]).expect("measure") > 0.0);
    }
    // pn101 and the O-X glide reference every joint at 0; the hexapod's home struts lie inside
    // their travel.
    assert_eq!(frame(Machine::Pn101).home_joints(), [0.0; 3]);
    let hexapod = frame(Machine::Hexapod);
    let limits = hexapod.kinematics().joint_limits();
    assert!(
        hexapod
            .home_joints()
            .iter()
            .zip(limits)
            .all(|(l, [lo, hi])| (lo..=hi).contains(&l))
    );
}

proptest! {
    /// In the machine frame, FK then IK gives the joints back to 1e-9 mm wherever FK succeeds,
    /// and the frame is the mechanism frame shifted by the home position.
    #[test]
    fn the_machine_frame_round_trips(u in unit6(), which in 0usize..4) {
        let machine = FRAMED[which];
        let f = frame(machine);
        let n = f.dof();
        let q = joints_at(f.kinematics(), &u);
        let mut pose = [0.0; 6];
        if f.forward(&q[..n], None, &mut pose[..n]).is_ok() {
            let mut back = [0.0; 6];
            f.inverse(&pose[..n], &mut back[..n]).map_err(|e| TestCaseError::fail(e.to_string()))?;
            for i in 0..n {
                prop_assert!((back[i] - q[i]).abs() < 1e-9, "{machine:?} joint {i}: {} vs {}", back[i], q[i]);
            }
            let mut mechanism = [0.0; 6];
            f.kinematics().forward(&q[..n], None, &mut mechanism[..n]).map_err(|e| TestCaseError::fail(e.to_string()))?;
            for (i, key) in f.kinematics().pose_keys().iter().enumerate() {
                let shift = if matches!(*key, "x" | "y" | "z") { f.home_pose()[i] } else { 0.0 };
                prop_assert!((pose[i] + shift - mechanism[i]).abs() < 1e-9);
            }
        }
    }
}
