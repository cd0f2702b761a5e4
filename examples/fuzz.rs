//! `make fuzz`: the long fuzz run over every reader (see `vellum::fuzz`).
//!
//! cargo run --release --example fuzz -- [--inputs N] [--seed S] [--only a,b] [--bound-ms MS]
//!                                        [--work DIR] [--json]

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use vellum_tools::fuzz::{self, FuzzOptions};

fn value<T: std::str::FromStr>(args: &[String], flag: &str, default: T) -> Result<T, String> {
    match args.iter().position(|a| a == flag) {
        None => Ok(default),
        Some(i) => args
            .get(i + 1)
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| format!("{flag} needs a value")),
    }
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let project = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let parsed = (|| -> Result<FuzzOptions, String> {
        Ok(FuzzOptions {
            inputs: value(&args, "--inputs", 1_000_000)?,
            seed: value(&args, "--seed", 1)?,
            time_bound: Duration::from_millis(value(&args, "--bound-ms", 5000)?),
            work_dir: value(&args, "--work", std::env::temp_dir().join("vellum-fuzz"))?,
            only: value(&args, "--only", String::new())?
                .split(',')
                .filter(|s| !s.is_empty())
                .map(String::from)
                .collect(),
        })
    })();
    let options = match parsed {
        Ok(o) => o,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let data = std::env::var_os("VELLUM_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| project.join("../shared/data"));
    let start = Instant::now();
    let result = fuzz::targets(&data, &project, &options.work_dir.join("seeds"))
        .and_then(|targets| fuzz::run(&targets, &options));
    let reports = match result {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
    };
    let peak = fuzz::peak_memory_mib().unwrap_or(f64::NAN);
    if args.iter().any(|a| a == "--json") {
        let out = serde_json::json!({
            "seed": options.seed,
            "bound_ms": options.time_bound.as_millis() as u64,
            "peak_memory_mib": peak,
            "seconds": start.elapsed().as_secs_f64(),
            "targets": reports,
        });
        println!("{}", serde_json::to_string_pretty(&out).unwrap_or_default());
    } else {
        println!(
            "{:<20} {:>9} {:>9} {:>9} {:>7} {:>8} {:>9} {:>8}",
            "target", "inputs", "accepted", "refused", "crashes", "unclear", "mean µs", "max ms"
        );
        for r in &reports {
            println!(
                "{:<20} {:>9} {:>9} {:>9} {:>7} {:>8} {:>9.1} {:>8.1}",
                r.target,
                r.inputs,
                r.accepted,
                r.refused,
                r.crashes,
                r.unclear,
                r.mean_us,
                r.max_ms
            );
            for m in &r.crash_messages {
                println!("    crash: {m}");
            }
            for m in &r.unclear_messages {
                println!("    not one line: {m:?}");
            }
        }
        println!(
            "no hangs past {} ms (the watchdog would have stopped the run); peak memory {peak:.0} MiB; {:.0} s; seed {}",
            options.time_bound.as_millis(),
            start.elapsed().as_secs_f64(),
            options.seed
        );
    }
    if reports.iter().any(|r| r.crashes > 0 || r.unclear > 0) {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}
