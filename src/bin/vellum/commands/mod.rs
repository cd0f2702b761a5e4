//! One module per group of subcommands; [`run`] dispatches the parsed command line.

mod bench;
mod chunked;
mod convert;
mod importance;
mod info;
mod mpi_bench;
mod occlusion;
mod render;
mod scale;
mod showcase;
mod styles;
mod view;

use convert::convert;
use importance::importance;
use info::{devices, info, roundtrip};
use occlusion::{occlusion, occlusion_select, occlusion_sensitivity};
use render::{lines, render};
use styles::{saliency, styles};
use view::view;

use crate::args::*;
use anyhow::Result;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use vellum::gpu::{Context, ContextDesc};
use vellum::team::Team;

/// `r` when every rank of `team` succeeded, else the agreed sentence on every rank (see
/// `Team::agree`): a step each rank takes before the others go on.
pub(crate) fn together<T>(team: &dyn Team, r: Result<T>) -> Result<T> {
    if team.size() == 1 {
        return r;
    }
    let r = r.map_err(|e| vellum::Error::Invalid(format!("{e:#}")));
    Ok(team.together(r)?)
}

/// A digest of this process's command line and of what it opened (`what`): every rank of a job
/// must compute the same (`Team::same_inputs`).
pub(crate) fn inputs_key(what: &impl std::hash::Hash) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    std::env::args_os().collect::<Vec<_>>().hash(&mut h);
    what.hash(&mut h);
    h.finish()
}

pub(crate) fn context(cli: &Cli) -> Result<Arc<Context>> {
    Ok(Context::new(&ContextDesc {
        validation: None,
        device: cli.device.clone(),
    })?)
}

/// Says on stderr if the validation layer complained (the messages themselves are at -vv).
pub(crate) fn report_validation(ctx: &Context) {
    ctx.report_validation();
}

/// The output files a command will write, as given.
pub(crate) fn output_paths(command: &Command) -> Vec<&Path> {
    pub(crate) fn all<'a>(v: &[&'a Option<PathBuf>]) -> Vec<&'a Path> {
        v.iter().filter_map(|p| p.as_deref()).collect()
    }
    match command {
        Command::Convert { output, .. } => vec![output.as_path()],
        Command::Importance { out, slices, .. } => all(&[out, slices]),
        Command::Normals { out, .. } => vec![out.as_path()],
        Command::Render(a) => all(&[&a.out, &a.exr, &a.save_scene]),
        Command::Lines(a) => all(&[&a.render.out, &a.render.exr, &a.svg]),
        Command::Occlusion(a) => all(&[&a.out, &a.spectrum, &a.spectrum_data]),
        Command::OcclusionSensitivity(a) => {
            let mut v = all(&[&a.csv]);
            v.push(a.out.as_path());
            v
        }
        Command::Migrate(a) => a.outputs(),
        Command::Segment(a) => a.outputs(),
        Command::Saliency { out, .. } => all(&[out]),
        Command::Styles(a) => vec![a.out.as_path()],
        _ => vec![],
    }
}

/// Pass times as a JSON object, name → ms (a pass recorded twice keeps its last time).
pub(crate) fn passes_json<'a>(
    passes: impl IntoIterator<Item = &'a vellum::gpu::PassTime>,
) -> serde_json::Map<String, serde_json::Value> {
    passes
        .into_iter()
        .map(|p| (p.name.clone(), serde_json::json!(p.ms)))
        .collect()
}

/// Refuses two outputs of one command at the same path, before any work is done.
pub(crate) fn check_distinct_outputs(command: &Command) -> Result<()> {
    let paths = output_paths(command);
    for (i, a) in paths.iter().enumerate() {
        let key = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
        if paths[..i].iter().any(|b| key(b) == key(a)) {
            anyhow::bail!(
                "{} is given for two outputs of one command; expected a separate path for each",
                a.display()
            );
        }
    }
    Ok(())
}

/// Runs the command. In an MPI job (`team` of more than one rank) the chunked passes share the
/// work; every other command runs on rank 0 alone.
pub(crate) fn run(cli: &Cli, team: &dyn Team) -> Result<()> {
    ContextDesc::check_environment()?;
    check_distinct_outputs(&cli.command)?;
    let shared = matches!(
        cli.command,
        Command::Importance { .. }
            | Command::Occlusion(_)
            | Command::Normals { .. }
            | Command::Render(_)
    );
    if team.size() > 1 && !shared {
        if !team.is_root() {
            return Ok(());
        }
        log::warn!(
            "this command runs on rank 0 alone; the ranks of a job share importance, occlusion and normals chunk by chunk, and render"
        );
    }
    // Commands without bars of their own show a spinner on a terminal (rank 0 only).
    let _spinner = match &cli.command {
        Command::Devices { .. }
        | Command::Info { .. }
        | Command::Convert { .. }
        | Command::Normals { .. }
        | Command::Bench { .. }
        | Command::View(_)
        | Command::Features(_)
        | Command::Showcase(_) => None,
        _ if !team.is_root() => None,
        _ => Some(vellum::progress::Spinner::new("vellum: working")),
    };
    match &cli.command {
        Command::Devices { json } => devices(cli, *json),
        Command::Info { input, json } => info(input, *json),
        Command::Convert {
            input,
            output,
            chunk,
            levels,
            add_channel,
            json,
        } => convert(
            input,
            output,
            (*chunk, levels.as_deref()),
            add_channel,
            *json,
        ),
        Command::Roundtrip { input, json } => roundtrip(cli, input, *json),
        Command::Importance {
            input,
            radius,
            out,
            slices,
            chunking,
            json,
        } => importance(
            (cli, team),
            input,
            *radius,
            (out.as_deref(), slices.as_deref()),
            chunking,
            *json,
        ),
        Command::Normals {
            input,
            out,
            chunking,
            json,
        } => importance::normals((cli, team), input, out, chunking, *json),
        Command::Render(args) => render((cli, team), args),
        Command::Lines(args) => lines(cli, args),
        Command::Occlusion(a) => occlusion((cli, team), a),
        Command::OcclusionSelect {
            input,
            interval,
            radius,
            stride,
            method,
            json,
        } => occlusion_select(cli, input, interval, *radius, *stride, method, *json),
        Command::OcclusionSensitivity(a) => occlusion_sensitivity(cli, a),
        Command::Styles(args) => styles(cli, args),
        Command::View(args) => view(cli, args),
        Command::Showcase(args) => showcase::showcase(args),
        Command::Saliency {
            image,
            mask,
            out,
            json,
        } => saliency(image, mask.as_deref(), out.as_deref(), *json),
        Command::Migrate(args) => crate::features::migrate(args),
        Command::Segment(args) => crate::features::segment(args),
        Command::Features(args) => crate::features::print_tree(args),
        Command::Bench { which } => bench::bench(cli, which),
        Command::Figures { which } => bench::figures(cli, which),
    }
}

/// Prints `value` as pretty JSON, or the text `text` makes.
pub(crate) fn print_report<T: serde::Serialize>(
    json: bool,
    value: &T,
    text: impl FnOnce() -> String,
) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(value)?);
    } else {
        print!("{}", text());
    }
    Ok(())
}
