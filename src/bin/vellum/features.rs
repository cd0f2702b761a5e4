//! `vellum migrate` (FM1–FM5: ROI, migration, feature map) and `vellum features` (print a map).
//! Parsing and file handling only; the work is in `vellum::volume::feature`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context as _, Result};
use clap::Args;
use serde_json::json;
use vellum::volume::feature::{
    self, parse_color, parse_seeds, parse_window, Connectivity, Feature, FeatureMap, MigrateParams,
    MigrationReport, Roi,
};

#[derive(Args)]
pub struct MigrateArgs {
    /// Input: file, DICOM folder or phantom spec. When appending to a feature map, the previous
    /// feature volume.
    input: String,
    /// ROI from a mask volume aligned voxel for voxel with the input (nonzero = ROI).
    #[arg(long, value_name = "MASK", required_unless_present_any = ["seed", "labels"], conflicts_with_all = ["seed", "window", "labels"])]
    mask: Option<String>,
    /// Features from a label volume on the input's grid (a file or store of whole numbers):
    /// each segment (every id but 0, or those of --ids) migrated in turn as a feature of its
    /// own, named "LABEL ID" and coloured as the label volume colours it.
    #[arg(long, value_name = "LABELS", conflicts_with_all = ["seed", "window", "color"])]
    labels: Option<String>,
    /// With --labels: the ids to migrate, in this order.
    #[arg(
        long,
        value_name = "ID,ID...",
        requires = "labels",
        value_delimiter = ','
    )]
    ids: Option<Vec<u32>>,
    /// ROI by seeded region growing from these voxels.
    #[arg(
        long,
        value_name = "X,Y,Z[;X,Y,Z...]",
        requires = "window",
        allow_hyphen_values = true
    )]
    seed: Option<String>,
    /// Intensity window of the region growing, inclusive, in data units.
    #[arg(
        long,
        value_name = "LO:HI",
        requires = "seed",
        allow_hyphen_values = true
    )]
    window: Option<String>,
    /// Connectivity of the region growing.
    #[arg(long, default_value = "6", value_parser = ["6", "26"])]
    connectivity: String,
    /// The feature's label (unique in the map).
    #[arg(long)]
    label: String,
    /// Parent group in the map, e.g. "bones" or "head/bones" (created when missing).
    #[arg(long)]
    parent: Option<String>,
    /// The gap ε between the data and the private interval, in data units (default: 5% of the
    /// input range).
    #[arg(long, allow_negative_numbers = true)]
    epsilon: Option<f64>,
    /// Let the new feature's fuzzy boundary keep eq. 10's values inside earlier features' private
    /// intervals (counted and reported) instead of moving them just outside.
    #[arg(long)]
    allow_overlap: bool,
    /// Free text stored with the feature.
    #[arg(long, default_value = "")]
    description: String,
    /// Default colour as R,G,B in 0..1 (default: the next colour of the palette).
    #[arg(long, value_name = "R,G,B", allow_hyphen_values = true)]
    color: Option<String>,
    /// Feature map to append to when it exists, else to create (default: OUT with the extension
    /// .features.json, always new).
    #[arg(long, value_name = "FEATURES.json")]
    features: Option<PathBuf>,
    /// Output feature volume (.nrrd, .nii or .nii.gz).
    #[arg(long)]
    out: PathBuf,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
pub struct SegmentArgs {
    /// Input: file, DICOM folder, store or phantom spec.
    input: String,
    /// A segment by seeded region growing, as SEEDS@LO:HI: seed voxels X,Y,Z[;X,Y,Z...] and
    /// the intensity window, inclusive, in data units. Repeatable: the n-th is segment n, and a
    /// voxel two regions reach keeps the first's id.
    #[arg(
        long = "region",
        value_name = "X,Y,Z[;X,Y,Z...]@LO:HI",
        required = true,
        allow_hyphen_values = true
    )]
    regions: Vec<String>,
    /// Connectivity of the region growing.
    #[arg(long, default_value = "6", value_parser = ["6", "26"])]
    connectivity: String,
    /// Output label volume (.nrrd, .nii or .nii.gz): uint8 ids, or uint16 beyond 255 regions.
    #[arg(long)]
    out: PathBuf,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

impl SegmentArgs {
    /// The files this command writes (for the binary's duplicate check).
    pub fn outputs(&self) -> Vec<&Path> {
        vec![self.out.as_path()]
    }
}

/// `vellum segment`: a label volume grown from seeds, one segment per `--region`, for
/// `render --labels`, `view --labels` and `migrate --labels`.
pub fn segment(args: &SegmentArgs) -> Result<()> {
    let start = Instant::now();
    let volume = vellum::input::load(&args.input, None)?;
    let connectivity = Connectivity::parse(&args.connectivity)?;
    let rois = args
        .regions
        .iter()
        .enumerate()
        .map(|(n, r)| {
            let (seeds, window) = r.rsplit_once('@').ok_or_else(|| {
                anyhow::anyhow!(
                    "--region {r:?} is invalid; expected seeds and a window as X,Y,Z[;X,Y,Z...]@LO:HI"
                )
            })?;
            let roi = Roi::grow(&volume, &parse_seeds(seeds)?, parse_window(window)?, connectivity)
                .with_context(|| format!("--region {} ({r})", n + 1))?;
            Ok(roi)
        })
        .collect::<Result<Vec<_>>>()?;
    let (labels, counts) = feature::label_volume(&volume, &rois)?;
    vellum::volume::io::write(&args.out, &labels)?;
    let ms = start.elapsed().as_secs_f64() * 1e3;
    if args.json {
        let out = json!({
            "input": args.input,
            "out": args.out,
            "voxel": labels.voxel_type().name(),
            "voxels_per_id": counts,
            "ms": ms,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    for (n, c) in counts.iter().enumerate() {
        println!("segment {}: {c} voxels ({})", n + 1, args.regions[n]);
    }
    println!(
        "wrote {} ({} ids, {}) in {ms:.0} ms",
        args.out.display(),
        counts.len(),
        labels.voxel_type().name()
    );
    Ok(())
}

#[derive(Args)]
pub struct FeaturesArgs {
    /// A feature map written by `vellum migrate`.
    features: PathBuf,
    /// Print the map as JSON instead of a tree.
    #[arg(long)]
    json: bool,
}

impl MigrateArgs {
    /// The files this command writes (for the binary's duplicate check).
    pub fn outputs(&self) -> Vec<&Path> {
        let mut v = vec![self.out.as_path()];
        v.extend(self.features.as_deref());
        v
    }
}

/// The map path (explicit or beside the output) and whether an existing one is appended to.
fn map_path(args: &MigrateArgs) -> (PathBuf, bool) {
    match &args.features {
        Some(p) => (p.clone(), p.exists()),
        None => (args.out.with_extension("features.json"), false),
    }
}

/// How the map refers to the feature volume: its file name when both sit in one folder.
fn volume_ref(out: &Path, map: &Path) -> String {
    let dir = |p: &Path| p.parent().map(Path::to_path_buf).unwrap_or_default();
    if dir(out) == dir(map) {
        if let Some(name) = out.file_name() {
            return name.to_string_lossy().into_owned();
        }
    }
    std::path::absolute(out)
        .unwrap_or_else(|_| out.to_path_buf())
        .display()
        .to_string()
}

pub fn migrate(args: &MigrateArgs) -> Result<()> {
    if let Some(labels) = &args.labels {
        return migrate_labels(args, labels);
    }
    let start = Instant::now();
    let (map_path, append) = map_path(args);
    let existing = if append {
        Some(FeatureMap::load(&map_path)?)
    } else {
        None
    };
    if let Some(map) = &existing {
        if map.feature(&args.label).is_some() {
            anyhow::bail!(
                "{}: a feature labelled '{}' exists already; expected a new label",
                map_path.display(),
                args.label
            );
        }
    }
    let color = args.color.as_deref().map(parse_color).transpose()?;

    let volume = vellum::input::load(&args.input, None)?;
    let roi = match (&args.mask, &args.seed, &args.window) {
        (Some(mask), _, _) => {
            let mask = vellum::input::load(mask, None)?;
            Roi::from_mask(&mask, &volume).with_context(|| format!("--mask {}", mask_name(args)))?
        }
        (None, Some(seeds), Some(window)) => Roi::grow(
            &volume,
            &parse_seeds(seeds)?,
            parse_window(window)?,
            Connectivity::parse(&args.connectivity)?,
        )?,
        _ => {
            anyhow::bail!("no ROI given; expected --mask MASK or --seed X,Y,Z with --window LO:HI")
        }
    };
    let loaded_ms = start.elapsed().as_secs_f64() * 1e3;

    let params = params_of(args, existing.as_ref());
    let migration = feature::migrate(&volume, &roi, &params)?;
    let report = &migration.report;

    let mut map = existing.unwrap_or_else(|| FeatureMap::new(report.in_range));
    map.volume = Some(volume_ref(&args.out, &map_path));
    let feature = Feature {
        label: args.label.clone(),
        description: args.description.clone(),
        interval: report.interval,
        color: color.unwrap_or_else(|| map.next_color()),
        source_range: Some(report.roi_range),
    };
    map.append(feature.clone(), args.parent.as_deref())
        .with_context(|| map_path.display().to_string())?;

    let t = Instant::now();
    vellum::volume::io::write(&args.out, &migration.volume)?;
    map.save(&map_path)?;
    let written_ms = t.elapsed().as_secs_f64() * 1e3;
    if append {
        for o in report.overlaps.iter().filter(|o| o.voxels > o.moved) {
            let owner = map
                .features()
                .iter()
                .find(|(_, f)| f.interval == o.interval)
                .map(|(_, f)| f.label.clone())
                .unwrap_or_default();
            log::warn!(
                "{} boundary voxels of '{}' lie inside the private interval [{}, {}] of '{owner}'{}",
                o.voxels - o.moved,
                args.label,
                num(o.interval[0]),
                num(o.interval[1]),
                if args.allow_overlap { " (--allow-overlap)" } else { " (no free value nearby)" }
            );
        }
    }

    if args.json {
        let out = json!({
            "input": args.input,
            "out": args.out,
            "features": map_path,
            "appended": append,
            "feature": feature,
            "report": report,
            "load_ms": loaded_ms,
            "write_ms": written_ms,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print_report(args, &feature, report, loaded_ms, written_ms);
        println!(
            "wrote {} and {} ({} the map)",
            args.out.display(),
            map_path.display(),
            if append { "appended to" } else { "created" }
        );
    }
    Ok(())
}

/// `migrate --labels`: every chosen segment of the label volume a feature of its own, in one
/// feature volume and one map (new, or appended to).
fn migrate_labels(args: &MigrateArgs, labels_path: &str) -> Result<()> {
    let (map_path, append) = map_path(args);
    let existing = append.then(|| FeatureMap::load(&map_path)).transpose()?;
    let volume = vellum::input::load(&args.input, None)?;
    let labels = vellum::volume::labels::Labels::open(Path::new(labels_path), None)
        .with_context(|| format!("--labels {labels_path}"))?;
    let ids: Vec<u32> = match &args.ids {
        Some(ids) => ids.clone(),
        None => labels.ids.iter().copied().filter(|&i| i != 0).collect(),
    };
    anyhow::ensure!(
        !ids.is_empty(),
        "--labels {labels_path} holds no segment (only id 0); expected a segmentation"
    );
    let name = |id: u32| format!("{} {id}", args.label);
    if let Some(taken) = existing
        .as_ref()
        .and_then(|m| ids.iter().find(|&&id| m.feature(&name(id)).is_some()))
    {
        anyhow::bail!(
            "{}: a feature labelled '{}' exists already; expected a new --label",
            map_path.display(),
            name(*taken)
        );
    }
    let params = params_of(args, existing.as_ref());
    let (out, reports) = feature::migrate_segments(&volume, &labels, &ids, &params)
        .with_context(|| format!("--labels {labels_path}"))?;
    let first_range = reports.first().map(|r| r.1.in_range).unwrap_or([0.0, 1.0]);
    let mut map = existing.unwrap_or_else(|| FeatureMap::new(first_range));
    map.volume = Some(volume_ref(&args.out, &map_path));
    let mut features = Vec::with_capacity(reports.len());
    for (id, r) in &reports {
        let c = labels.colour(*id);
        let feature = Feature {
            label: name(*id),
            description: args.description.clone(),
            interval: r.interval,
            color: [c[0], c[1], c[2]].map(|v| v as f32 / 255.0),
            source_range: Some(r.roi_range),
        };
        map.append(feature.clone(), args.parent.as_deref())
            .with_context(|| map_path.display().to_string())?;
        features.push(feature);
    }
    vellum::volume::io::write(&args.out, &out)?;
    map.save(&map_path)?;
    if args.json {
        let list: Vec<_> = features
            .iter()
            .zip(&reports)
            .map(|(f, (id, r))| json!({ "id": id, "feature": f, "report": r }))
            .collect();
        let out = json!({ "input": args.input, "labels": labels_path, "out": args.out,
            "features": map_path, "appended": append, "segments": list });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    for (f, (_, r)) in features.iter().zip(&reports) {
        println!(
            "feature '{}': {} voxels, [{}, {}] → private interval [{}, {}]",
            f.label,
            r.roi_voxels,
            num(r.roi_range[0]),
            num(r.roi_range[1]),
            num(r.interval[0]),
            num(r.interval[1])
        );
    }
    let n = features.len();
    println!(
        "wrote {} and {} ({n} segment{} as features)",
        args.out.display(),
        map_path.display(),
        if n == 1 { "" } else { "s" }
    );
    Ok(())
}

/// The migration's parameters from the flags, with the intervals of the features already in
/// the map `existing` kept private.
fn params_of(args: &MigrateArgs, existing: Option<&FeatureMap>) -> MigrateParams {
    MigrateParams {
        epsilon: args.epsilon,
        protected: existing
            .map(|m| m.features().iter().map(|(_, f)| f.interval).collect())
            .unwrap_or_default(),
        allow_overlap: args.allow_overlap,
        ..Default::default()
    }
}

fn mask_name(args: &MigrateArgs) -> &str {
    args.mask.as_deref().unwrap_or_default()
}

fn print_report(
    args: &MigrateArgs,
    feature: &Feature,
    r: &MigrationReport,
    loaded_ms: f64,
    written_ms: f64,
) {
    let c = &r.categories;
    let k = &r.reconstruction;
    let t = &r.timings;
    println!(
        "feature '{}': {} ROI voxels of {} ({} → {})",
        feature.label,
        r.roi_voxels,
        args.input,
        r.input_type.name(),
        r.output_type.name()
    );
    println!(
        "  categories: 1 fuzzy boundary {}, 2 thin ROI {}, 3 ROI interior {}, 4 outside {}",
        c.fuzzy_boundary, c.thin_roi, c.roi_interior, c.outside
    );
    println!(
        "  input range [{}, {}], ROI range [{}, {}] → private interval [{}, {}] (ε = {}, Δ = {})",
        num(r.in_range[0]),
        num(r.in_range[1]),
        num(r.roi_range[0]),
        num(r.roi_range[1]),
        num(r.interval[0]),
        num(r.interval[1]),
        num(r.epsilon),
        num(r.delta)
    );
    println!(
        "  category 1: eq. 10 {}, only ROI found {}, only outside found {}, beyond δ_i {}, beyond δ_o {}, by mask {}",
        k.flipped, k.inside_only, k.outside_only, k.beyond_inside, k.beyond_outside, k.by_mask
    );
    for o in &r.overlaps {
        if o.voxels > 0 {
            println!(
                "  earlier interval [{}, {}]: {} boundary voxels fell inside it, {} moved out",
                num(o.interval[0]),
                num(o.interval[1]),
                o.voxels,
                o.moved
            );
        }
    }
    println!(
        "  times: categorise {:.1} ms, migrate {:.1} ms, reconstruct {:.1} ms, total {:.1} ms (load {:.1} ms, write {:.1} ms)",
        t.categorise_ms, t.migrate_ms, t.reconstruct_ms, t.total_ms, loaded_ms, written_ms
    );
}

/// A data value with at most 6 decimals and no trailing zeros (f64 sums such as 0.75 + 0.0375
/// print as 0.7875, not 0.7875000000000001).
fn num(v: f64) -> String {
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.into()
    }
}

pub fn print_tree(args: &FeaturesArgs) -> Result<()> {
    let map = FeatureMap::load(&args.features)?;
    if args.json {
        println!("{}", map.to_json());
    } else {
        print!("{map}");
    }
    Ok(())
}
