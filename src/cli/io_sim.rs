//! `io-sim`: the I/O map's modules served as a Modbus TCP or RTU station, backed by the
//! simulated machine.

use std::time::Duration;

use tracing::{info, warn};

use super::args::IoSimArgs;
use super::{Failure, OutputFile, load_setup};

pub fn run(args: IoSimArgs) -> Result<(), Failure> {
    use std::io::Write;
    let setup = load_setup(&args.config)?;
    let bus = setup.sim_bus(args.scenario.as_deref())?;
    // A serial line's station is the generic one; over TCP, the one the I/O map names.
    let mut station = match args.serial {
        Some(_) => pkm_plc::services::sim::modbus::Station::new(bus),
        None => pkm_plc::services::sim::modbus::Station::of_map(bus, args.node),
    };
    let [coils, discrete, input, holding] = station.registers().sizes();
    let kind = if station.is_bus_controller() {
        format!(
            "an X20BC0087 (node {}) with {} modules",
            args.node,
            station.registers().modules.len()
        )
    } else {
        "a generic station".to_string()
    };
    let options = pkm_plc::services::sim::server::ServerOptions {
        watchdog: (args.watchdog_ms > 0).then(|| Duration::from_millis(args.watchdog_ms)),
        max_connections: usize::from(args.max_connections),
        idle_timeout: Duration::from_secs(args.idle_timeout_s),
    };
    let watchdog = match options.watchdog {
        Some(w) => format!("output watchdog {} ms", w.as_millis()),
        None => "output watchdog OFF".to_string(),
    };
    let summary = args.summary.as_deref().map(OutputFile::create).transpose()?;
    // One thread answers every client and advances the plant: at real-time priority where the
    // process may, so that a busy PC delays a request no more than a real station would.
    let priority = match args.realtime_priority {
        0 => "normal scheduling".to_string(),
        p => match pkm_plc::runtime::timing::set_realtime_priority(p) {
            Ok(()) => format!("SCHED_FIFO priority {p}"),
            Err(e) => format!("normal scheduling (SCHED_FIFO priority {p} refused: {e})"),
        },
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Failure::run(format!("cannot start the tokio runtime: {e}")))?;
    let report = runtime.block_on(async move {
        let mut signals = pkm_plc::runtime::signals::Terminating::register();
        let stop = async move {
            let name = signals.recv().await;
            info!("io-sim: {name}: stopping");
        };
        if let Some((path, baud)) = &args.serial {
            let stream = tokio_serial::SerialStream::open(&tokio_serial::new(path.as_str(), *baud))
                .map_err(|e| Failure::run(format!("io-sim: cannot open {path}: {e}")))?;
            info!(
                "io-sim: {} on {path} at {baud} baud as Modbus RTU, {watchdog}, {priority}; Ctrl-C stops",
                setup.origin()
            );
            return pkm_plc::services::sim::server::serve_rtu(stream, station, options, stop)
                .await
                .map_err(|e| Failure::run(format!("io-sim: {e}")));
        }
        let tcp = args
            .tcp
            .ok_or_else(|| Failure::usage("io-sim needs --tcp or --serial"))?;
        let listener = tokio::net::TcpListener::bind(tcp)
            .await
            .map_err(|e| Failure::run(format!("io-sim: cannot listen on {tcp}: {e}")))?;
        let address = listener.local_addr().map_err(|e| Failure::run(e.to_string()))?;
        station.set_address(address);
        println!("{address}");
        let _ = std::io::stdout().flush();
        if !address.ip().is_loopback() {
            warn!(
                "io-sim: listening on {address}, not on loopback: Modbus has no authentication, so anyone who \
                 reaches this address can write the outputs (the drives). Use 127.0.0.1 unless a trusted, \
                 separate network needs it."
            );
        }
        info!(
            "io-sim: {} on {address} as Modbus TCP, {kind}: {coils} coils, {discrete} discrete inputs, {input} input \
             registers, {holding} holding registers; {watchdog}, at most {} clients, {priority}; Ctrl-C stops",
            setup.origin(),
            options.max_connections
        );
        pkm_plc::services::sim::server::serve_tcp(listener, station, options, stop)
            .await
            .map_err(|e| Failure::run(format!("io-sim: {e}")))
    })?;
    for line in report.lines() {
        info!("io-sim: {line}");
    }
    if let Some(file) = summary {
        let json = serde_json::to_string_pretty(&report).map_err(|e| Failure::run(e.to_string()))?;
        let path = file.path.clone();
        file.write(&json)?;
        info!("io-sim: summary written to {}", path.display());
    }
    Ok(())
}
