//! `run`: the soft-PLC, in real time until a signal or for a duration, or in virtual time. The
//! arguments become the composition's build options and a [`RunRequest`]; the run itself is
//! [`pkm_plc::compose::serve::run`]'s. Here: the screen's and OPC UA's options, the program
//! library, the joystick, and the summary written at the end.

use std::path::PathBuf;
use std::time::Duration;

use tracing::info;

use super::args::{HmiAddr, RunArgs, parse_hmi};
use super::{Failure, NcFiles, OutputFile, build_with_nc_files};
use pkm_plc::compose::serve::{OpcUaRequest, Ran, RunRequest};
use pkm_plc::compose::{JoystickChoice, Options};
use pkm_plc::runtime::config::TimeSourceKind;
use pkm_plc::services::io::hid::JoystickSpec;

/// Runs the PLC as `args` ask, then logs its summary (and writes it with `--summary`).
pub fn run(args: RunArgs) -> Result<(), Failure> {
    if args.virtual_time && args.pace.is_none() && args.duration.is_none() {
        return Err(Failure::usage(
            "--virtual needs --duration (the simulated seconds it runs), or --pace X (a simulation paced at X times real time, with the screen, until stopped)",
        ));
    }
    if args.pace.is_some() && !matches!(args.bus, pkm_plc::compose::BusChoice::Sim) {
        return Err(Failure::usage(
            "--pace simulates the machine: it runs on --bus sim only (a real station would see its cycles paced, not timed)",
        ));
    }
    let screen = screen_options(&args)?;
    let opcua = super::opcua::options(
        args.opcua.as_deref(),
        args.opcua_users.as_ref(),
        args.opcua_pki.as_ref(),
        args.opcua_max_sessions,
        unserved(&args),
    )
    .map_err(Failure::usage)?;
    // Programs are loaded, and commands come, from the screen or over OPC UA.
    let served = screen.is_some() || opcua.is_some();
    // In virtual time a joystick path is a capture file, played on the simulated clock;
    // `auto` (a live device) is off.
    let joystick = match (&args.joystick, args.virtual_time) {
        (JoystickSpec::Path(p), true) => JoystickChoice::Capture(p.clone()),
        (_, true) => JoystickChoice::Live(JoystickSpec::None),
        (spec, false) => JoystickChoice::Live(spec.clone()),
    };
    let programs = program_library(&args, served)?;
    let options = Options {
        bus: args.bus.clone(),
        link: pkm_plc::services::io::modbus::ModbusOptions {
            exchange: args.exchange.into(),
            max_input_age: Duration::from_millis(args.max_input_age_ms),
            max_exchange: Duration::from_millis(args.max_exchange_ms),
            ..Default::default()
        },
        scenario: args.scenario.clone(),
        joystick,
        program: args.program.clone(),
        programs,
        hmi: served,
    };
    let files = NcFiles {
        tool_table: args.tool_table.clone(),
        var_file: args.var_file.clone(),
    };
    let built = build_with_nc_files(&args.config, options, &files)?;
    let summary_file = args.summary.as_deref().map(OutputFile::create).transpose()?;
    let request = RunRequest {
        virtual_time: args.virtual_time,
        pace: args.pace,
        duration_s: args.duration,
        time_source: args.time_source.map(TimeSourceKind::from),
        screen,
        opcua: opcua.map(|(options, next_ports)| OpcUaRequest {
            options,
            next_ports,
            explicit: args.opcua.is_some(),
        }),
        trace: args.trace.clone(),
    };
    let Ran { summary, failure } = pkm_plc::compose::serve::run(built, request)?;
    for line in summary.lines() {
        info!("{line}");
    }
    if let Some(file) = summary_file {
        let path = file.path.clone();
        file.write(&summary.to_json())?;
        info!("summary written to {}", path.display());
    }
    // A trace that could not be written fails the run, but only after the summary.
    failure
}

/// The environment variable whose address the screen is served at when `--hmi` is not given.
const HMI_ENV: &str = "PKM_PLC_HMI";

/// Whether the run serves nothing: virtual time as fast as it goes (a paced simulation is
/// served as a real-time run is).
fn unserved(args: &RunArgs) -> bool {
    args.virtual_time && args.pace.is_none()
}

/// The screen `args` ask for: `None` in unpaced virtual time or with `--hmi none`.
fn screen_options(args: &RunArgs) -> Result<Option<pkm_plc::services::hmi::HmiOptions>, Failure> {
    let unserved = unserved(args);
    // The environment's address stands in for --hmi in real time (a virtual run serves none,
    // whatever the environment says).
    let hmi = match (args.hmi, std::env::var(HMI_ENV)) {
        (None, Ok(text)) if !unserved => {
            Some(parse_hmi(&text).map_err(|e| Failure::usage(format!("{HMI_ENV}={text}: {e}")))?)
        }
        (hmi, _) => hmi,
    };
    let next_ports = if hmi.is_none() {
        pkm_plc::services::hmi::DEFAULT_NEXT_PORTS
    } else {
        0
    };
    let addr = match (hmi, unserved) {
        (Some(HmiAddr::Off), _) | (None, true) => return Ok(None),
        (Some(HmiAddr::At(_)), true) => {
            return Err(Failure::usage(
                "--hmi serves the screen in real time or in a paced simulation (--virtual --pace X); a --virtual run as fast as it goes has none",
            ));
        }
        (Some(HmiAddr::At(a)), false) => a,
        (None, false) => pkm_plc::services::hmi::DEFAULT_ADDR
            .parse()
            .map_err(|e| Failure::usage(format!("{}: {e}", pkm_plc::services::hmi::DEFAULT_ADDR)))?,
    };
    let token = match (&args.hmi_token, &args.hmi_token_file) {
        (Some(t), _) => Some(t.clone()),
        (None, Some(path)) => {
            let text = pkm_plc::runtime::files::read_text(path, 4096)
                .map_err(|e| Failure::usage(format!("--hmi-token-file {}: {e}", path.display())))?;
            Some(text.lines().next().unwrap_or("").trim().to_string())
        }
        (None, None) => None,
    };
    let options = pkm_plc::services::hmi::HmiOptions {
        addr,
        token,
        allowed_origins: args
            .hmi_allow_origin
            .iter()
            .map(|o| o.trim_end_matches('/').to_ascii_lowercase())
            .collect(),
        max_clients: args.hmi_max_clients,
        next_ports,
    };
    options.check().map_err(Failure::usage)?;
    Ok(Some(options))
}

/// The directory of programs the screen offers: `--programs DIR`, or `programs` where it exists
/// (with a screen); `none` or no screen: none.
fn program_library(args: &RunArgs, screen: bool) -> Result<Option<PathBuf>, Failure> {
    match &args.programs {
        Some(dir) if dir.as_os_str() == "none" => Ok(None),
        Some(dir) if !screen => Err(Failure::usage(format!(
            "--programs {}: programs are loaded from the operator's screen or over OPC UA, which are served in real time or in a paced simulation only (and not with both --hmi none and --opcua none)",
            dir.display()
        ))),
        Some(dir) => Ok(Some(dir.clone())),
        None => Ok(Some(PathBuf::from("programs")).filter(|d| screen && d.is_dir())),
    }
}
