//! `vellum showcase`: runs the manifest's commands (each a child process of this binary, with
//! `--json` for its timings) and writes the page (`vellum::showcase`).

use crate::args::ShowcaseArgs;
use anyhow::{bail, Context as _, Result};
use std::process::{Command, Stdio};
use std::time::Instant;
use vellum_tools::showcase::{html, Manifest, Outcome, Run, Vars};

pub(crate) fn showcase(a: &ShowcaseArgs) -> Result<()> {
    let text = std::fs::read_to_string(&a.manifest).with_context(|| {
        format!(
            "the showcase manifest {} cannot be read; run from the repository's root or give --manifest FILE",
            a.manifest.display()
        )
    })?;
    let manifest = Manifest::from_json_str(&text)?;
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("the output folder {} cannot be made", a.out.display()))?;
    let (out, iso) = (a.out.to_string_lossy(), a.iso.to_string());
    let vars = Vars {
        input: &a.input,
        iso: &iso,
        out: &out,
    };
    let count = manifest
        .sections
        .iter()
        .map(|s| s.runs.len())
        .sum::<usize>();
    let bar = vellum::progress::bar(count as u64, "showcase");
    let mut device = None;
    let mut outcomes = Vec::new();
    for section in &manifest.sections {
        let mut done = Vec::new();
        for run in &section.runs {
            bar.set_message(section.id.clone());
            let (outcome, dev) = execute(run, &vars, &a.out)?;
            bar.suspend(|| println!("{:>5.1} s  {}", outcome.seconds, outcome.command));
            device = device.or(dev);
            done.push(outcome);
            bar.inc(1);
        }
        outcomes.push(done);
    }
    bar.finish_and_clear();
    let device = device.unwrap_or_else(|| "an unnamed device".into());
    let page = html(&manifest, &outcomes, &device);
    let index = a.out.join("index.html");
    vellum::output::write_atomic(&index, |w| {
        use std::io::Write;
        w.write_all(page.as_bytes())
    })?;
    let images: usize = manifest
        .sections
        .iter()
        .flat_map(|s| &s.runs)
        .map(|r| r.images.len())
        .sum();
    println!(
        "wrote {}: {images} images from {count} commands, each with its command and timings; open it in a browser",
        index.display()
    );
    Ok(())
}

/// Runs one command of the manifest and checks that it wrote what the manifest says; returns its
/// outcome and the device its report names.
fn execute(run: &Run, vars: &Vars, out: &std::path::Path) -> Result<(Outcome, Option<String>)> {
    let args = run.expand(vars);
    for stale in &run.replaces {
        let p = out.join(stale);
        let removed = match p.is_dir() {
            true => std::fs::remove_dir_all(&p),
            false => std::fs::remove_file(&p),
        };
        match removed {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                bail!(
                    "{} cannot be removed before it is made again ({e})",
                    p.display()
                )
            }
            _ => {}
        }
    }
    let shown = format!(
        "vellum {}",
        args.iter().map(|a| quote(a)).collect::<Vec<_>>().join(" ")
    );
    let mut command = Command::new(std::env::current_exe()?);
    command.args(&args).stdin(Stdio::null());
    if run.json {
        command.arg("--json");
    }
    let started = Instant::now();
    let o = command
        .output()
        .with_context(|| format!("`{shown}` could not be started"))?;
    let seconds = started.elapsed().as_secs_f64();
    if String::from_utf8_lossy(&o.stderr).contains("the Vulkan validation layer reported") {
        bail!("`{shown}`: the Vulkan validation layer reported errors or warnings; rerun it with -vv to see them");
    }
    if !o.status.success() {
        let last = vellum::error::last_line(&o.stderr);
        bail!(
            "the showcase stopped at `{shown}`: {}",
            last.trim_start_matches("error: ")
        );
    }
    for file in run.outputs() {
        if !out.join(file).is_file() {
            bail!("`{shown}` succeeded but did not write {file}, which the manifest names");
        }
    }
    // A command without --json prints text: no report, no passes.
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or_default();
    let device = report["device"].as_str().map(str::to_string);
    let passes = Outcome::passes_in(&report);
    Ok((
        Outcome {
            command: shown,
            passes,
            seconds,
        },
        device,
    ))
}

/// `a` as a shell word: unchanged when it is plain, else in single quotes.
fn quote(a: &str) -> String {
    let plain = |c: char| c.is_ascii_alphanumeric() || "-_./:,=+@%".contains(c);
    if !a.is_empty() && a.chars().all(plain) {
        a.to_string()
    } else {
        format!("'{}'", a.replace('\'', r"'\''"))
    }
}
