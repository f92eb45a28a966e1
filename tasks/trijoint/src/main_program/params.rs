//! The main program's parameters (`params` of its entry in config.json) and their checks.

use pkm_api::image::Declare;
use pkm_kinematics::trijoint::TrijointParams;
use serde::Deserialize;

/// Parameters of the main program.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MainParams {
    /// After an accepted STOP press the button is ignored this long (ms).
    pub stop_lockout_ms: u64,
    /// PWM period written to the motor bridges (µs).
    pub pwm_period_us: u16,
    /// Speed of the coarse switch search and of moves in INIT (mm/s).
    pub init_speed_mm_s: f64,
    /// Speed of the second approach to a switch (mm/s).
    pub approach_speed_mm_s: f64,
    /// Speed of the final approach (mm/s): at most one encoder count per 10 ms cycle, so that the
    /// switch position is known to one count (7000 counts/mm: 0.0143 mm/s).
    pub creep_speed_mm_s: f64,
    /// The second approach starts this far before the coarse switch position (mm).
    pub approach_distance_mm: f64,
    /// The final approach starts this far before the second approach's switch position (mm).
    pub creep_distance_mm: f64,
    /// A switch not found within this time is an INIT timeout (s).
    pub search_timeout_s: f64,
    /// Carriage positions after INIT, from the lower switches (mm); default: the middle of the
    /// configured travel (the kinematics' `h1_travel`, `h2_travel`), where programs start.
    pub start_position_mm: Option<[f64; 2]>,
    /// Software limits lie this far inside the switches (mm).
    pub soft_limit_margin_mm: f64,
    /// Speed of the spindle point M at full joystick deflection (mm/s).
    pub max_speed_mm_s: f64,
    /// No carriage set-point moves faster than this while jogging (mm/s): near the ends of the
    /// travel a modest speed of M asks the carriages for more, and a carriage that cannot
    /// follow lags, then overshoots. The jog slows M down instead.
    pub max_joint_speed_mm_s: f64,
    /// Deceleration with which a jogging carriage set-point brakes towards its software limit
    /// (mm/s²), so that the carriage stops inside the limit instead of overshooting a set-point
    /// that stopped dead.
    pub brake_decel_mm_s2: f64,
    /// Joystick deflections below this count as released.
    pub dead_zone: f64,
    /// M is never commanded where the singularity measure is below this.
    pub singularity_threshold: f64,
}

impl Default for MainParams {
    fn default() -> Self {
        MainParams {
            stop_lockout_ms: 500,
            pwm_period_us: 50,
            init_speed_mm_s: 15.0,
            approach_speed_mm_s: 1.0,
            creep_speed_mm_s: 0.012,
            approach_distance_mm: 0.5,
            creep_distance_mm: 0.03,
            search_timeout_s: 30.0,
            start_position_mm: None,
            soft_limit_margin_mm: 2.0,
            max_speed_mm_s: 20.0,
            max_joint_speed_mm_s: 40.0,
            brake_decel_mm_s2: 100.0,
            dead_zone: 0.05,
            singularity_threshold: 0.3,
        }
    }
}

impl MainParams {
    /// Where the carriages stand after INIT (mm from each lower switch), and where programs are
    /// planned to start: `start_position_mm`, else the middle of the configured travel of
    /// `geometry`. One answer for both, whatever travel a referencing measures: a program
    /// starts only where it was planned from.
    pub fn start_position(&self, geometry: &TrijointParams) -> [f64; 2] {
        let travel = [
            geometry.h1_travel[1] - geometry.h1_travel[0],
            geometry.h2_travel[1] - geometry.h2_travel[0],
        ];
        self.start_position_mm.unwrap_or([travel[0] / 2.0, travel[1] / 2.0])
    }
}

/// The longest cycle the main program may run in (µs).
pub(super) const MAX_MAIN_CYCLE_US: u32 = 100_000;

/// How close to the border of the allowed region a jog step that crosses it stops (mm, along
/// the step): 1 nm, far below the encoders' resolution, in about 21 halvings of a 2 mm step.
pub(super) const BORDER_TOLERANCE_MM: f64 = 1e-6;

/// Every parameter within its range of [`pkm_api::ranges`] (the searches ever slower, each
/// approach shorter than the one before, the start inside the software limits): a value
/// outside is refused by `check`, naming the key.
pub(super) fn check_ranges(p: &MainParams, geometry: &TrijointParams, decl: &mut Declare<'_>) {
    use pkm_api::ranges;
    let key = |k: &str| format!("params.{k}");
    decl.within(
        &key("stop_lockout_ms"),
        p.stop_lockout_ms as f64,
        &ranges::STOP_LOCKOUT_MS,
    );
    decl.within(
        &key("pwm_period_us"),
        f64::from(p.pwm_period_us),
        &ranges::PWM_PERIOD_US,
    );
    decl.within(
        &key("singularity_threshold"),
        p.singularity_threshold,
        &ranges::SINGULARITY_THRESHOLD,
    );
    decl.within(&key("dead_zone"), p.dead_zone, &ranges::DEAD_ZONE);
    let shorter = (geometry.h1_travel[1] - geometry.h1_travel[0]).min(geometry.h2_travel[1] - geometry.h2_travel[0]);
    let margin = decl.within(
        &key("soft_limit_margin_mm"),
        p.soft_limit_margin_mm,
        &ranges::SOFT_LIMIT_MARGIN_MM.up_to((shorter / 4.0).max(ranges::SOFT_LIMIT_MARGIN_MM.min)),
    );
    decl.within(&key("max_speed_mm_s"), p.max_speed_mm_s, &ranges::SPEED_MM_S);
    decl.within(
        &key("max_joint_speed_mm_s"),
        p.max_joint_speed_mm_s,
        &ranges::SPEED_MM_S,
    );
    decl.within(&key("brake_decel_mm_s2"), p.brake_decel_mm_s2, &ranges::ACCEL_MM_S2);
    decl.within(&key("search_timeout_s"), p.search_timeout_s, &ranges::TIMEOUT_S);
    // The searches ever slower, each approach within the one before.
    decl.within(&key("init_speed_mm_s"), p.init_speed_mm_s, &ranges::SPEED_MM_S);
    decl.within(
        &key("approach_speed_mm_s"),
        p.approach_speed_mm_s,
        &ranges::SPEED_MM_S.up_to_within(p.init_speed_mm_s),
    );
    decl.within(
        &key("creep_speed_mm_s"),
        p.creep_speed_mm_s,
        &ranges::SLOW_SPEED_MM_S.up_to_within(p.approach_speed_mm_s),
    );
    decl.within(
        &key("approach_distance_mm"),
        p.approach_distance_mm,
        &ranges::SEARCH_DISTANCE_MM,
    );
    decl.within(
        &key("creep_distance_mm"),
        p.creep_distance_mm,
        &ranges::SEARCH_DISTANCE_MM.up_to_within(p.approach_distance_mm),
    );
    // The start inside the software limits, counted from each lower switch.
    if let (Some(start), true) = (p.start_position_mm, margin) {
        for (i, travel) in [geometry.h1_travel, geometry.h2_travel].iter().enumerate() {
            let length = travel[1] - travel[0];
            let range = ranges::POSITION_MM
                .from(p.soft_limit_margin_mm)
                .up_to((length - p.soft_limit_margin_mm).max(p.soft_limit_margin_mm));
            decl.within(&format!("{}[{i}]", key("start_position_mm")), start[i], &range);
        }
    }
}
