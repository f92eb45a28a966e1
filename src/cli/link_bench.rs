//! `pkm-plc link-bench`: the Modbus RTU exchange measured at a real baud rate without serial
//! hardware. The soft-PLC's bus driver and the I/O simulator's station talk through an emulated
//! RS-485 line ([`pkm_plc::services::io::line`]) that carries each frame no faster than the baud rate allows
//! and keeps the silent interval between frames, so the figure is what a USB-RS485 link at that
//! rate gives, less the adapters' own latency.

use std::time::Duration;

use serde::Serialize;

use super::args::LinkBenchArgs;
use super::enums::Exchange;
use super::{Failure, OutputFile, load_setup};
use pkm_plc::compose::Setup;
use pkm_plc::image::VarTable;
use pkm_plc::runtime::config::ConfigError;
use pkm_plc::services::io::line::LineTiming;
use pkm_plc::services::io::map::IoMap;
use pkm_plc::services::io::modbus::{ExchangeMode, ModbusBus, ModbusOptions, Transport, WireLoad};
use pkm_plc::services::io::registers::RegisterMap;
use pkm_plc::services::sim::modbus::Station;
use pkm_plc::services::sim::on_line::StationOnLine;
use tracing::info;

/// What to measure.
#[derive(Clone, Debug)]
pub struct LinkBenchOptions {
    /// The line's baud rate.
    pub baud: u32,
    /// Seconds per exchange mode.
    pub seconds: f64,
    /// The exchange modes to measure, one row each.
    pub modes: Vec<ExchangeMode>,
}

/// One measured exchange mode.
#[derive(Clone, Debug, Serialize)]
pub struct LinkBenchRow {
    /// `tables` or `image`.
    pub exchange: String,
    /// The line's baud rate.
    pub baud: u32,
    /// Request/response transactions per exchange.
    pub transactions: u32,
    /// Bytes on the wire per exchange, both directions.
    pub bytes: u32,
    /// Computed time on the line per exchange: the characters plus, per transaction, the
    /// silent intervals that end the request and the response (ms).
    pub computed_ms: f64,
    /// Exchanges completed.
    pub exchanges: u64,
    /// Measured exchange time, from the first request to the last response (ms): min, mean,
    /// max. Back-to-back exchanges include the silent interval before their first request.
    pub min_ms: f64,
    /// See `min_ms`.
    pub mean_ms: f64,
    /// See `min_ms`.
    pub max_ms: f64,
    /// Complete input images per second.
    pub per_second: f64,
    /// Requests that timed out.
    pub timeouts: u64,
    /// Exception responses.
    pub exceptions: u64,
}

/// Why the benchmark could not run.
#[derive(Debug, thiserror::Error)]
pub enum LinkBenchError {
    /// The configuration is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The configuration names no I/O map.
    #[error("{0}: the configuration names no I/O map")]
    NoIoMap(String),
    /// A socket pair, thread or runtime could not be created.
    #[error("cannot set up the emulated line: {0}")]
    Setup(String),
}

/// Runs one row per exchange mode, calling `progress` before each.
pub fn run(
    setup: &Setup,
    options: &LinkBenchOptions,
    mut progress: impl FnMut(&str),
) -> Result<Vec<LinkBenchRow>, LinkBenchError> {
    let map = setup
        .io_map()?
        .ok_or_else(|| LinkBenchError::NoIoMap(setup.origin().to_string()))?;
    let timing = LineTiming::modbus_rtu(options.baud);
    // A serial line's station is a generic one, whatever the map names.
    let sizes = RegisterMap::laid_out(&map, pkm_plc::services::io::map::StationKind::Generic).sizes();
    let mut rows = Vec::new();
    for &mode in &options.modes {
        progress(&format!("{} at {} baud", mode.name(), options.baud));
        let station = Station::new(setup.sim_bus(None)?);
        rows.push(measure(map.clone(), station, mode, options, timing, sizes)?);
    }
    Ok(rows)
}

/// One row: station ↔ line ↔ driver for `options.seconds`.
fn measure(
    map: IoMap,
    station: Station,
    mode: ExchangeMode,
    options: &LinkBenchOptions,
    timing: LineTiming,
    sizes: [u16; 4],
) -> Result<LinkBenchRow, LinkBenchError> {
    let setup = |e: &dyn std::fmt::Display| LinkBenchError::Setup(e.to_string());
    let (station, plc_end) = StationOnLine::start(station, timing, Default::default()).map_err(|e| setup(&e))?;
    let bus_options = ModbusOptions {
        exchange: mode,
        // As a run's exchange thread (one below the cyclic thread's default 80) where the
        // process may: the measurement is the line's, not the scheduler's.
        priority: 79,
        ..Default::default()
    };
    let mut bus = ModbusBus::new(map, Transport::Stream(Some(plc_end)), bus_options).map_err(|e| setup(&e))?;
    let mut table = VarTable::new();
    pkm_plc::runtime::bus::Bus::declare(&mut bus, &mut table);
    pkm_plc::runtime::bus::Bus::start(&mut bus).map_err(|e| setup(&e))?;
    std::thread::sleep(Duration::from_secs_f64(options.seconds));
    pkm_plc::runtime::bus::Bus::write_safe(&mut bus, &table.initial_image());
    drop(station);

    let stats = bus.stats();
    let get = |a: &std::sync::atomic::AtomicU64| a.load(std::sync::atomic::Ordering::Relaxed);
    let exchanges = get(&stats.exchanges);
    let load = WireLoad::of(bus.exchange(), sizes);
    let ms = |ns: u64| ns as f64 / 1e6;
    Ok(LinkBenchRow {
        exchange: bus.exchange().name().to_string(),
        baud: options.baud,
        transactions: load.transactions,
        bytes: load.bytes,
        computed_ms: ms(load.on_line(&timing)),
        exchanges,
        min_ms: if exchanges > 0 {
            ms(get(&stats.exchange_ns_min))
        } else {
            0.0
        },
        mean_ms: ms(get(&stats.exchange_ns_total)) / exchanges.max(1) as f64,
        max_ms: ms(get(&stats.exchange_ns_max)),
        per_second: exchanges as f64 / options.seconds,
        timeouts: get(&stats.timeouts),
        exceptions: get(&stats.exceptions),
    })
}

/// The rows as a table for people.
pub fn table(rows: &[LinkBenchRow]) -> String {
    let mut out = format!(
        "{:<8} {:>7} {:>6} {:>6} {:>12} {:>10} {:>8} {:>8} {:>8} {:>9} {:>9}\n",
        "exchange",
        "baud",
        "trans.",
        "bytes",
        "computed ms",
        "exchanges",
        "min ms",
        "mean ms",
        "max ms",
        "images/s",
        "timeouts"
    );
    for r in rows {
        out.push_str(&format!(
            "{:<8} {:>7} {:>6} {:>6} {:>12.2} {:>10} {:>8.2} {:>8.2} {:>8.2} {:>9.1} {:>9}\n",
            r.exchange,
            r.baud,
            r.transactions,
            r.bytes,
            r.computed_ms,
            r.exchanges,
            r.min_ms,
            r.mean_ms,
            r.max_ms,
            r.per_second,
            r.timeouts
        ));
    }
    out
}

/// The `link-bench` subcommand: runs it as `args` ask and prints its report.
pub fn command(args: LinkBenchArgs) -> Result<(), Failure> {
    if args.exchange.contains(&Exchange::Auto) {
        return Err(Failure::usage("--exchange: name the modes to measure (tables, image)"));
    }
    let setup = load_setup(&args.config)?;
    let options = LinkBenchOptions {
        baud: args.baud,
        seconds: args.seconds,
        modes: args.exchange.into_iter().map(ExchangeMode::from).collect(),
    };
    let json_file = args.json.as_deref().map(OutputFile::create).transpose()?;
    let rows = run(&setup, &options, |row| info!("measuring {row}")).map_err(|e| match e {
        LinkBenchError::Setup(_) => Failure::run(e.to_string()),
        _ => Failure::usage(e.to_string()),
    })?;
    print!("{}", table(&rows));
    if let Some(file) = json_file {
        let json = serde_json::to_string_pretty(&rows).map_err(|e| Failure::run(e.to_string()))?;
        file.write(&json)?;
    }
    Ok(())
}
