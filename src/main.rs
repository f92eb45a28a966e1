//! The `pkm-plc` command line: parses the arguments and hands each subcommand to its module
//! under `cli/`.
//!
//! Exit codes: 0 success; 1 the run failed (timer, thread, file output); 2 usage or configuration
//! error (nothing was started).

use std::process::ExitCode;

use clap::Parser;

use cli::Failure;
use cli::args::{Cli, Command};
use pkm_plc::runtime::status;

mod cli;

fn main() -> ExitCode {
    let cli = Cli::parse();
    cli::init_logging();
    let result = match cli.command {
        Command::Run(args) => cli::run::run(*args),
        Command::Check(args) => cli::check::run(args),
        Command::Bench(args) => cli::bench::command(args),
        Command::Replay(args) => cli::replay::run(args),
        Command::Trace(args) => cli::trace::run(args),
        Command::Registers(args) => cli::registers::run(args),
        Command::IoSim(args) => cli::io_sim::run(args),
        Command::LinkBench(args) => cli::link_bench::command(args),
        Command::Station(args) => cli::station::command(args),
        Command::Kin(args) => cli::kin::run(args),
        Command::Nc(args) => cli::nc::run(args).map_err(Failure::from),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            status::finish();
            eprintln!("error: {}", f.message);
            ExitCode::from(f.code)
        }
    }
}
