//! The `vellum` command line. It parses arguments, calls the library and writes results; the work
//! itself lives in the library. `args` defines the flags, `scene_args` turns the scene flags into
//! a scene, `commands/` holds one module per group of subcommands.

mod args;
mod commands;
mod features;
mod flags;
mod scene_args;

use args::{flags_for_keys, parse_cli};
use commands::run;
use std::process::ExitCode;

/// The system allocator, counting live bytes: the viewer's bench reports what vellum's own code
/// keeps (`memory::live_heap_bytes`), apart from what the driver and validation layer keep.
#[global_allocator]
static ALLOCATOR: vellum::memory::Counting = vellum::memory::Counting;

#[cfg(unix)]
unsafe extern "C" {
    fn signal(signum: i32, handler: usize) -> usize;
}

fn main() -> ExitCode {
    // Rust ignores SIGPIPE, which turns `vellum info x | head` into a panic in println!. Restore
    // the default so the CLI ends quietly like other Unix tools (13 = SIGPIPE, 0 = SIG_DFL).
    #[cfg(unix)]
    // SAFETY: setting a signal disposition to its default before any threads start.
    unsafe {
        signal(13, 0);
    }
    let cli = parse_cli();
    let level = match cli.verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or(level))
        .format_timestamp(None)
        .init();
    // Ctrl-C or SIGTERM removes the command's temporary files; nothing partial stays behind.
    // The writers are told first and stop at their next chunk, removing their folders
    // themselves; what is left after a few seconds is removed here, then the process ends.
    if let Err(e) = ctrlc::set_handler(|| {
        vellum::error::interrupt();
        vellum::output::wait_for_writers(std::time::Duration::from_secs(5));
        vellum::output::remove_pending_and_exit(130);
    }) {
        log::warn!("no Ctrl-C handler: {e}");
    }
    vellum::volume::io::http_store::configure(cli.remote());
    // Every output of the command, or none (see output.rs).
    vellum::output::begin();
    let team = start_team();
    let result = match &team {
        Ok(team) => run(&cli, &**team).and_then(|()| Ok(vellum::output::commit()?)),
        Err(e) => Err(anyhow::anyhow!("{e:#}")),
    };
    let root = team.as_ref().map_or(true, |t| t.is_root());
    let code = match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(_) if vellum::error::interrupted() => {
            // The handler says nothing more and ends the process with 130 once the writers
            // are done; this thread got there first.
            vellum::output::remove_pending_and_exit(130);
        }
        Err(e) => {
            vellum::output::abort();
            // In a job, every rank ends with the same agreed sentence; rank 0 says it.
            if root {
                let message = flags_for_keys(&format!("{e:#}"));
                eprintln!("error: {}", vellum::error::one_line(&message));
            }
            ExitCode::FAILURE
        }
    };
    // No rank exits before rank 0 has spoken.
    if let Ok(team) = &team {
        team.barrier();
    }
    code
}

/// The ranks this process works with: the MPI job it was launched into, or itself alone.
#[cfg(feature = "mpi")]
fn start_team() -> anyhow::Result<Box<dyn vellum::team::Team>> {
    if vellum::team::launched_ranks().is_none() {
        return Ok(Box::new(vellum::team::Solo));
    }
    Ok(match vellum_tools::cluster::start()? {
        Some(team) => Box::new(team),
        None => Box::new(vellum::team::Solo),
    })
}

/// Without the `mpi` feature a process runs alone, and refuses to be one of many ranks (each
/// would do the whole job and write the same outputs).
#[cfg(not(feature = "mpi"))]
fn start_team() -> anyhow::Result<Box<dyn vellum::team::Team>> {
    match vellum::team::launched_ranks() {
        Some(n) if n != 1 => anyhow::bail!(
            "vellum was started as one of {} ranks of a parallel job but was built without MPI; build it with `cargo build --release --features mpi`",
            if n == 0 { "several".to_string() } else { n.to_string() }
        ),
        _ => Ok(Box::new(vellum::team::Solo)),
    }
}
