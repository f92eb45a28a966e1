//! The command line: one module per subcommand, each turning its arguments into the
//! composition's options and reporting the outcome (what to print, the exit code); [`args`]
//! defines them all. The PLC's logic lives in the library; nothing here runs a cycle.

pub mod args;
pub mod bench;
pub mod check;
pub mod enums;
pub mod io_sim;
pub mod kin;
pub mod kin_svg;
pub mod link_bench;
pub mod nc;
pub mod opcua;
pub mod registers;
pub mod replay;
pub mod run;
pub mod station;
pub mod trace;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use tracing_subscriber::EnvFilter;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;

use args::ConfigArg;
pub use pkm_plc::compose::Failure;
use pkm_plc::compose::{self, Built, Options, Setup};
use pkm_plc::runtime::config::{self, ConfigError, LoadedConfig};
use pkm_plc::runtime::status;

/// Logs to standard error (above the status line), or to the journal under systemd, within
/// the log's budget.
pub fn init_logging() {
    // The OPC UA crates say at info what the server's own line says once (endpoints, every
    // connection): their warnings and errors only, unless RUST_LOG asks for more.
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| {
        EnvFilter::new(
            "info,opcua_server=warn,opcua_core=warn,opcua_crypto=warn,opcua_types=warn,opcua_nodes=warn,opcua_xml=warn",
        )
    });
    // Every line, the libraries' too, within the log's budget: a peer's flood cannot fill the
    // disk (pkm_plc::runtime::log_limit).
    let budget = pkm_plc::runtime::log_limit::LogBudget::new();
    // Under systemd the journal keeps the time and reads each line's level from its prefix.
    let journal = pkm_plc::runtime::service::logging_to_journal().then(|| {
        tracing_subscriber::fmt::layer()
            .with_writer(status::LogWriter)
            .with_ansi(false)
            .event_format(pkm_plc::runtime::service::JournalFormat)
    });
    let format = (!pkm_plc::runtime::service::logging_to_journal()).then(|| {
        tracing_subscriber::fmt::layer()
            .with_writer(status::LogWriter)
            .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
            .with_target(false)
    });
    tracing_subscriber::registry()
        .with(filter)
        .with(pkm_plc::runtime::log_limit::BudgetLayer(Arc::clone(&budget)))
        .with(journal)
        .with(format)
        .init();
    budget.spawn_summaries();
}

/// Loads the configuration named on the command line, or the default one.
pub fn load_config(arg: &ConfigArg) -> Result<LoadedConfig, ConfigError> {
    if let Some(loaded) = arg
        .machine
        .as_deref()
        .and_then(pkm_plc::compose::machines::configuration)
    {
        return loaded;
    }
    let path = arg.config.clone().or_else(config::default_path);
    config::load(path.as_deref())
}

/// Loads the configuration named on the command line (or the default one) and resolves its
/// machine.
pub fn load_setup(arg: &ConfigArg) -> Result<Setup, ConfigError> {
    Setup::new(load_config(arg)?)
}

/// Builds a PLC through the composition root.
pub fn build(arg: &ConfigArg, options: Options) -> Result<Built, Failure> {
    build_with_nc_files(arg, options, &NcFiles::default())
}

/// [`build`] with the NC programs' files: the tool table and the parameter file the command line
/// names (else the configuration's).
pub fn build_with_nc_files(arg: &ConfigArg, options: Options, files: &NcFiles) -> Result<Built, Failure> {
    let setup = files.apply(load_setup(arg)?)?;
    compose::build(setup, options).map_err(|e| Failure::usage(e.0))
}

/// The NC programs' files a command line names: the tool table, the parameter file.
#[derive(Clone, Debug, Default)]
pub struct NcFiles {
    /// `--tool-table FILE`.
    pub tool_table: Option<PathBuf>,
    /// `--var-file FILE`.
    pub var_file: Option<PathBuf>,
}

impl NcFiles {
    /// `setup` with these files (else the configuration's).
    pub fn apply(&self, setup: compose::Setup) -> Result<compose::Setup, Failure> {
        setup
            .with_tool_table(self.tool_table.as_deref())?
            .with_param_file(self.var_file.as_deref())
    }
}

/// An output file opened before the work that fills it, so that a path that cannot be written
/// fails at once instead of after a run or a measurement.
pub struct OutputFile {
    /// Where it is.
    pub path: PathBuf,
    file: std::fs::File,
}

impl OutputFile {
    /// Creates (or empties) the file at `path`: a usage error if that is not possible.
    pub fn create(path: &Path) -> Result<OutputFile, Failure> {
        let file = std::fs::File::create(path)
            .map_err(|e| Failure::usage(format!("{}: cannot write: {e}", path.display())))?;
        Ok(OutputFile {
            path: path.to_path_buf(),
            file,
        })
    }

    /// Writes `text` and a newline, and closes the file.
    pub fn write(mut self, text: &str) -> Result<(), Failure> {
        use std::io::Write;
        self.file
            .write_all(format!("{text}\n").as_bytes())
            .and_then(|()| self.file.sync_data())
            .map_err(|e| Failure::run(format!("{}: cannot write: {e}", self.path.display())))
    }
}
