//! `vellum bench` and `vellum figures`: the library's benchmarks and figure sheets, reported as
//! text or JSON.

use crate::args::{BenchCommand, Cli, FiguresCommand};
use crate::commands::{context, print_report, report_validation};
use anyhow::Result;

pub(crate) fn bench(cli: &Cli, which: &BenchCommand) -> Result<()> {
    match which {
        BenchCommand::Render { .. } | BenchCommand::Styles { .. } | BenchCommand::Table1 { .. } => {
            frames_and_table1(cli, which)
        }
        BenchCommand::Lines { .. } | BenchCommand::Occlusion { .. } => {
            lines_and_occlusion(cli, which)
        }
        BenchCommand::Scale {
            json,
            sizes,
            image,
            dir,
            keep,
        } => super::scale::scale(sizes, *image, dir, *keep, *json),
        BenchCommand::Mpi {
            json,
            size,
            chunk,
            ranks,
            images,
            dir,
            keep,
        } => super::mpi_bench::mpi((*size, *chunk), ranks, images, (dir, *keep, *json)),
    }
}

/// `bench render`, `bench styles` and `bench table1`.
fn frames_and_table1(cli: &Cli, which: &BenchCommand) -> Result<()> {
    match which {
        BenchCommand::Render {
            json,
            repeat,
            sizes,
            orbit_frames,
            peer,
        } => {
            let ctx = context(cli)?;
            let opts = vellum_tools::bench::render::Options {
                repeat: (*repeat).max(1),
                sizes: sizes.clone(),
                orbit_frames: (*orbit_frames).max(1),
                raycast: false,
            };
            if let Some(other) = peer.as_deref().filter(|p| *p != "vtk") {
                anyhow::bail!("--peer {other:?} is unknown; expected vtk");
            }
            let mut table = vellum_tools::bench::render::run(&ctx, &opts)?;
            if peer.is_some() {
                table.peer = Some(vellum_tools::bench::render::vtk_peer(
                    &ctx,
                    &opts.sizes,
                    opts.orbit_frames,
                )?);
            }
            report_validation(&ctx);
            print_report(*json, &table, || {
                table.to_text() + &table.peer.as_ref().map(|p| p.to_text()).unwrap_or_default()
            })
        }
        BenchCommand::Styles {
            json,
            repeat,
            sizes,
            renderer,
        } => {
            let ctx = context(cli)?;
            let opts = vellum_tools::bench::render::Options {
                repeat: (*repeat).max(1),
                sizes: sizes.clone(),
                orbit_frames: 0,
                raycast: renderer == "raycast",
            };
            let table = vellum_tools::bench::render::run_styles(&ctx, &opts)?;
            report_validation(&ctx);
            print_report(*json, &table, || table.to_text())
        }
        BenchCommand::Table1 {
            json,
            repeat,
            no_scipy,
            cases,
            sustained,
        } => {
            let ctx = context(cli)?;
            let opts = vellum_tools::bench::table1::Options {
                repeat: (*repeat).max(1),
                scipy: !no_scipy,
                cases: cases.clone(),
                sustained: *sustained,
            };
            let table = vellum_tools::bench::table1::run(&ctx, &opts)?;
            report_validation(&ctx);
            print_report(*json, &table, || table.to_text())
        }
        _ => Ok(()),
    }
}

/// `bench lines` and `bench occlusion`.
fn lines_and_occlusion(cli: &Cli, which: &BenchCommand) -> Result<()> {
    match which {
        BenchCommand::Lines {
            json,
            input,
            iso,
            resample,
        } => {
            let input = match (input, iso) {
                (Some(i), Some(v)) => Some((i.clone(), *v)),
                (None, None) => None,
                _ => anyhow::bail!("bench lines takes an input and --iso V together"),
            };
            if let Some(n) = resample {
                anyhow::ensure!(
                    (2..=1024).contains(n),
                    "--resample {n} is invalid; expected 2..=1024 voxels per side"
                );
            }
            let ctx = context(cli)?;
            let table = vellum_tools::bench::lines::run(
                &ctx,
                &vellum_tools::bench::lines::Options {
                    input,
                    resample: *resample,
                },
            )?;
            report_validation(&ctx);
            print_report(*json, &table, || table.to_text())
        }
        BenchCommand::Occlusion {
            json,
            input,
            radii,
            methods,
            max_seconds,
            peer,
        } => {
            use vellum::passes::occlusion::{check_radius_stride, Method};
            if let Some(other) = peer.as_deref().filter(|p| *p != "scipy") {
                anyhow::bail!("--peer {other:?} is unknown; expected scipy");
            }
            for &r in radii {
                check_radius_stride(r, 1)?;
            }
            let methods = methods
                .iter()
                .map(|m| match Method::parse(m)? {
                    Method::Auto => Err(anyhow::anyhow!(
                        "--methods takes runs, fft-gpu and fft-cpu; auto picks among them"
                    )),
                    m => Ok(m),
                })
                .collect::<Result<Vec<_>>>()?;
            anyhow::ensure!(
                max_seconds.is_finite() && *max_seconds > 0.0,
                "--max-seconds {max_seconds} is invalid; expected a positive number"
            );
            let ctx = context(cli)?;
            let opts = vellum_tools::bench::occlusion::Options {
                input: input.clone(),
                radii: radii.clone(),
                methods,
                max_seconds: *max_seconds,
                scipy: peer.is_some(),
            };
            let table = vellum_tools::bench::occlusion::run(&ctx, &opts)?;
            report_validation(&ctx);
            print_report(*json, &table, || table.to_text())
        }
        _ => Ok(()),
    }
}

pub(crate) fn figures(cli: &Cli, which: &FiguresCommand) -> Result<()> {
    match which {
        FiguresCommand::Importance { out_dir, size } => {
            let ctx = context(cli)?;
            let files = vellum_tools::figures::importance(&ctx, out_dir, *size)?;
            report_validation(&ctx);
            for f in files {
                println!("wrote {}", f.display());
            }
            Ok(())
        }
    }
}
