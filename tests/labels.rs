//! Label volumes (issue 42): segments beside an intensity volume, drawn by the ray caster in
//! their colours, hidden by id, and chosen as the focus level by id. Checked against the CPU's
//! projections of the same label volume: three balls that never overlap along an axis, seen
//! orthographically along one, cover shares of the image that their voxel discs give.

mod common;

use common::Gpu;
use std::path::Path;
use vellum::classify::labels::LabelSpec;
use vellum::render::bricked::StillOptions;
use vellum::render::overrides::{CameraAngles, SceneOverrides};
use vellum::render::pick::{pick_label, PickInput};
use vellum::render::scene::{InputSpec, Scene};
use vellum::render::session::{Session, SessionOptions};
use vellum::render::targets::FrameImage;
use vellum::render::view::View;
use vellum::volume::labels::colour_of;
use vellum::volume::lines::Segment;
use vellum::volume::{Volume, VoxelData};

const N: usize = 48;
/// Id, centre and radius of each ball: apart by more than their radii in every axis's
/// projection.
const BALLS: [(u8, [f32; 3], f32); 3] = [
    (2, [12.0, 12.0, 36.0], 7.0),
    (5, [36.0, 14.0, 12.0], 6.0),
    (9, [24.0, 36.0, 24.0], 8.0),
];

/// The balls' intensity (1 inside, 0 outside) and their label volume.
fn balls() -> (Volume, Volume) {
    let mut labels = vec![0u8; N * N * N];
    for z in 0..N {
        for y in 0..N {
            for x in 0..N {
                let p = [x as f32 + 0.5, y as f32 + 0.5, z as f32 + 0.5];
                for (id, c, r) in BALLS {
                    let d2: f32 = (0..3).map(|a| (p[a] - c[a]).powi(2)).sum();
                    if d2 <= r * r {
                        labels[x + N * (y + N * z)] = id;
                    }
                }
            }
        }
    }
    let intensity = labels.iter().map(|&l| (l > 0) as u8 as f32).collect();
    let v = |d| Volume::new([N; 3], [1.0; 3], d).unwrap();
    (v(VoxelData::F32(intensity)), v(VoxelData::U8(labels)))
}

/// Per ball, the pixels of its disc along the axis `axis` looks down.
fn disc_areas(labels: &Volume, axis: usize) -> Vec<usize> {
    let VoxelData::U8(l) = &labels.data else {
        unreachable!()
    };
    let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
    BALLS
        .iter()
        .map(|&(id, ..)| {
            let mut seen = vec![false; N * N];
            for z in 0..N {
                for y in 0..N {
                    for x in 0..N {
                        if l[x + N * (y + N * z)] == id {
                            let p = [x, y, z];
                            seen[p[a] + N * p[b]] = true;
                        }
                    }
                }
            }
            seen.iter().filter(|&&s| s).count()
        })
        .collect()
}

/// One orthographic frame along z of the balls with `spec`'s segments, 192² pixels (4 per
/// voxel), through the session as the front ends open it; and the view it was drawn with.
fn frame_and_view(gpu: &Gpu, spec: LabelSpec, style: Option<&str>) -> (FrameImage, View) {
    frame_through(gpu, spec, style, (&SessionOptions::default(), 192))
}

/// [`frame_and_view`] at `size`² pixels, the session opened with `opts` (through the brick cache
/// when its budget is below the volume's).
fn frame_through(
    gpu: &Gpu,
    spec: LabelSpec,
    style: Option<&str>,
    (opts, size): (&SessionOptions, u32),
) -> (FrameImage, View) {
    let (intensity, _) = balls();
    let overrides = SceneOverrides {
        camera: Some(CameraAngles {
            azimuth: 0.0,
            elevation: 90.0,
            distance: None,
        }),
        ortho: true,
        size: Some([size, size]),
        style: vellum::render::overrides::StyleOverrides {
            style: style.map(str::to_string),
            ..Default::default()
        },
        ..Default::default()
    };
    let mut scene = overrides
        .apply(Scene::new(InputSpec::new(String::from("an array"))))
        .unwrap();
    scene.labels = Some(spec);
    let mut session = Session::open(&gpu.ctx, &scene, Some(intensity), opts).unwrap();
    let (view, note) = session.view(scene.view(false).unwrap());
    assert!(note.unwrap().contains("ray caster"));
    let opts = StillOptions::default();
    (session.still(&view, opts).unwrap().0, view)
}

/// Through the brick cache, each brick carries its slot's segment indices: the frames are the
/// frames in core (within 1/255 a channel), hidden segments and focus segments included; and a
/// coarse level's voxel takes the segment most of it holds, so a frame of level 1 (24² pixels, two
/// voxels a pixel) shows the balls' colours as the frames in core do (at least 90 % of the
/// covered pixels; the specular highlight whitens a few), not blends of two.
#[test]
fn segments_through_the_brick_cache_are_the_segments_in_core() {
    let gpu = Gpu::new();
    let dir = tempfile::tempdir().unwrap();
    // 48³ takes 1.1 MiB in core: 0.9 MiB holds two slots (the coarsest brick and one more).
    let bricked = |lod| SessionOptions {
        gpu_budget_mib: Some(0.9),
        lod,
        ..Default::default()
    };
    use vellum::render::session::Lod;
    for (hide, focus) in [(vec![], vec![]), (vec![5], vec![]), (vec![], vec![9])] {
        let core = frame(&gpu, spec(dir.path(), &hide, &focus), None);
        let (paged, _) = frame_through(
            &gpu,
            spec(dir.path(), &hide, &focus),
            None,
            (&bricked(Lod::Finest), 192),
        );
        let mut worst = 0.0f32;
        let mut sum = 0.0f64;
        for (a, b) in core.composite.iter().zip(&paged.composite) {
            for c in 0..4 {
                worst = worst.max((a[c] - b[c]).abs());
                sum += (a[c] - b[c]).abs() as f64;
            }
        }
        let mean = sum / (4 * core.composite.len()) as f64;
        assert!(
            worst <= 1.0 / 255.0 && mean <= 0.1 / 255.0,
            "hide {hide:?} focus {focus:?}: worst {worst}, mean {mean}"
        );
        assert!(!covered(&paged).is_empty());
    }
    let coarse_spec = spec(dir.path(), &[0], &[]);
    let (coarse, _) = frame_through(&gpu, coarse_spec, None, (&bricked(Lod::Auto), 24));
    let shown = covered(&coarse);
    let balls: Vec<u8> = shown
        .iter()
        .filter_map(|&i| ball_of(coarse.composite[i]))
        .collect();
    let named = balls.len();
    for (id, ..) in BALLS {
        assert!(balls.contains(&id), "ball {id} is missing at level 1");
    }
    assert!(
        named * 10 >= shown.len() * 9 && shown.len() > 50,
        "{named} of {} covered pixels show a ball's colour",
        shown.len()
    );
}

fn frame(gpu: &Gpu, spec: LabelSpec, style: Option<&str>) -> FrameImage {
    frame_and_view(gpu, spec, style).0
}

fn spec(dir: &Path, hide: &[u32], focus: &[u32]) -> LabelSpec {
    let path = dir.join("labels.nrrd");
    if !path.exists() {
        vellum::volume::io::write(&path, &balls().1).unwrap();
    }
    LabelSpec {
        path: path.to_string_lossy().into_owned(),
        hide: hide.to_vec(),
        focus: focus.to_vec(),
        colours: Vec::new(),
    }
}

/// The pixels of a frame's composite that are mostly covered.
fn covered(f: &FrameImage) -> Vec<usize> {
    (0..f.composite.len())
        .filter(|&i| f.composite[i][3] >= 0.5)
        .collect()
}

/// Which ball's colour a premultiplied pixel shows (by its chromaticity), if any is within 0.12.
fn ball_of(p: [f32; 4]) -> Option<u8> {
    if p[3] < 0.5 {
        return None;
    }
    let unit = |c: [f32; 3]| {
        let m = c[0].max(c[1]).max(c[2]).max(1e-6);
        c.map(|v| v / m)
    };
    let seen = unit([p[0], p[1], p[2]]);
    BALLS.iter().map(|b| b.0).find(|&id| {
        let c = colour_of(id as u32).map(|v| v as f32 / 255.0);
        let want = unit([c[0], c[1], c[2]]);
        (0..3).all(|i| (seen[i] - want[i]).abs() < 0.12)
    })
}

#[test]
fn segments_take_their_colours_and_cover_their_discs() {
    let gpu = Gpu::new();
    let dir = tempfile::tempdir().unwrap();
    // Id 0 hidden: the segments alone (the intensity here is the balls' mask, so what no
    // segment holds would only be the half-voxel shell that linear filtering puts around them).
    let (all, view) = frame_and_view(&gpu, spec(dir.path(), &[0], &[]), None);
    let lit = covered(&all);
    // Every lit pixel shows one ball's colour (diffuse light scales it; the specular highlight
    // whitens a few).
    let mut per = [0usize; 3];
    for &i in &lit {
        if let Some(id) = ball_of(all.composite[i]) {
            per[BALLS.iter().position(|b| b.0 == id).unwrap()] += 1;
        }
    }
    let coloured: usize = per.iter().sum();

    assert!(
        coloured as f64 >= 0.9 * lit.len() as f64,
        "{coloured} of {} lit pixels in a ball's colour",
        lit.len()
    );
    // Each ball's share of the image is its disc's share (4 × 4 pixels a voxel), along z.
    let discs = disc_areas(&balls().1, 2);
    let total: usize = discs.iter().sum();
    for (k, &d) in discs.iter().enumerate() {
        let want = d as f64 / total as f64;
        let got = per[k] as f64 / coloured as f64;
        assert!(
            (got - want).abs() < 0.03,
            "ball {k}: {got:.3} of the pixels, its disc {want:.3}"
        );
    }
    picks_agree_with_the_frame(&all, &view, &spec(dir.path(), &[0], &[]));
    // Hidden segments add nothing: only ball 2 is left, and it covers what it covered.
    let one = frame(&gpu, spec(dir.path(), &[0, 5, 9], &[]), None);
    let lit_one = covered(&one);
    assert!(lit_one
        .iter()
        .all(|&i| ball_of(all.composite[i]) == Some(2) || ball_of(all.composite[i]).is_none()));
    let got = lit_one.len() as f64 / lit.len() as f64;
    let want = discs[0] as f64 / total as f64;
    assert!(
        (got - want).abs() < 0.03,
        "ball 2 alone: {got:.3}, its disc {want:.3}"
    );
    // Id 0 drawn (the default): that shell shows in the transfer function's grey, around the
    // segments, which still show their colours.
    let with_0 = frame(&gpu, spec(dir.path(), &[], &[]), None);
    let grey = |p: &[f32; 4]| {
        p[3] >= 0.5 && p[0].max(p[1]).max(p[2]) - p[0].min(p[1]).min(p[2]) < 0.05 * p[3]
    };
    let greys = with_0.composite.iter().filter(|p| grey(p)).count();
    assert!(greys > 0 && all.composite.iter().filter(|p| grey(p)).count() == 0);
    let shown: std::collections::BTreeSet<u8> = with_0
        .composite
        .iter()
        .filter_map(|&p| ball_of(p))
        .collect();
    assert_eq!(shown.into_iter().collect::<Vec<_>>(), [2, 5, 9]);
}

/// The viewer's pick (a CPU walk of the pixel's ray) names the ball whose colour the GPU drew
/// at that pixel, and nothing where the frame is empty: checked on every 7th pixel.
fn picks_agree_with_the_frame(f: &FrameImage, view: &View, spec: &LabelSpec) {
    let (intensity, labels) = balls();
    let labels = vellum::volume::labels::Labels::of_volume(&labels, "balls").unwrap();
    let tf = vellum::classify::window::auto(&intensity, [0.0, 1.0]).unwrap();
    let input = PickInput {
        volume: &intensity,
        range: [0.0, 1.0],
        tf: &tf,
        labels: &labels,
        spec,
        background: true,
    };
    let (mut agree, mut coloured, mut empty_wrong) = (0, 0, 0);
    for i in (0..f.composite.len()).step_by(7) {
        let pixel = [(i % 192) as f32, (i / 192) as f32];
        let picked = pick_label(&input, view, pixel);
        match ball_of(f.composite[i]) {
            Some(id) => {
                coloured += 1;
                agree += (picked == Some(id as u32)) as usize;
            }
            None if f.composite[i][3] < 0.01 => empty_wrong += picked.is_some() as usize,
            None => {}
        }
    }
    assert!(coloured > 200, "{coloured} coloured pixels checked");
    assert!(
        agree as f64 >= 0.98 * coloured as f64 && empty_wrong == 0,
        "the pick agrees with the frame at {agree} of {coloured} coloured pixels, and names a segment at {empty_wrong} empty ones"
    );
}

#[test]
fn focus_labels_make_those_segments_the_focus_level() {
    let gpu = Gpu::new();
    let dir = tempfile::tempdir().unwrap();
    let f = frame(&gpu, spec(dir.path(), &[0], &[5]), Some("14"));
    let layers = f.layers.expect("two levels");
    let focus = layers.focus_depth.iter().filter(|d| d.is_finite()).count();
    let context = layers.context.iter().filter(|p| p[3] >= 0.5).count();
    let discs = disc_areas(&balls().1, 2);
    let want = discs[1] as f64 / discs.iter().sum::<usize>() as f64;
    let got = focus as f64 / (focus + context) as f64;

    assert!(
        (got - want).abs() < 0.03,
        "focus {got:.3} of the covered pixels, ball 5's disc {want:.3}"
    );
    // Style 14 keeps the focus's colour and greys the context.
    let saturated = |p: &[f32; 4]| {
        p[3] > 0.5 && p[0].max(p[1]).max(p[2]) - p[0].min(p[1]).min(p[2]) > 0.2 * p[3]
    };
    let vivid = f.composite.iter().filter(|p| saturated(p)).count();
    assert!(
        (vivid as f64 - focus as f64).abs() < 0.1 * focus as f64,
        "{vivid} vivid pixels, {focus} of focus"
    );
}

/// Segment `i`'s field on the host, as the GPU makes it: at each voxel, the share of the 3×3×3
/// voxels around it (clamped at the faces) that hold the segment.
fn field(labels: &vellum::volume::labels::Labels, i: u16) -> Vec<f32> {
    let [nx, ny, nz] = labels.dims;
    let at = |x: usize, y: usize, z: usize| labels.index[x + nx * (y + ny * z)] == i;
    let near = |c: usize, n: usize| [c.saturating_sub(1), c, (c + 1).min(n - 1)];
    let mut out = Vec::with_capacity(nx * ny * nz);
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let mut inside = 0u32;
                for zz in near(z, nz) {
                    for yy in near(y, ny) {
                        for xx in near(x, nx) {
                            inside += u32::from(at(xx, yy, zz));
                        }
                    }
                }
                out.push(inside as f32 / 27.0);
            }
        }
    }
    out
}

/// Whether every segment of `got` has its endpoints within 0.05 voxel of some segment's of
/// `want` (the GPU's floats against the CPU's), both sets the same size.
fn same_segments(got: &[Segment], want: &[Segment]) -> bool {
    let near =
        |p: [f32; 4], q: [f32; 4]| (0..3).map(|a| (p[a] - q[a]).powi(2)).sum::<f32>() < 0.0025;
    got.len() == want.len()
        && got.iter().all(|g| {
            want.iter()
                .any(|w| (near(g.a, w.a) && near(g.b, w.b)) || (near(g.a, w.b) && near(g.b, w.a)))
        })
}

/// Each segment's own lines (issue 42). Extracted on the GPU as a frame of a style with lines
/// over a label volume extracts them, the three balls' silhouettes and suggestive contours equal
/// the CPU reference, the lines of each segment's field (its share of each 3×3×3 box) at 0.5,
/// within 0.05 voxel; leaving a segment out leaves out exactly its lines. A frame in style 4 (silhouettes)
/// over the label volume with ball 5 hidden draws lines on the rims of the two others and
/// nowhere else (the intensity's lines would outline all three).
#[test]
fn each_segment_has_its_own_lines() {
    use vellum::passes::lines::LineExtractor;
    use vellum::volume::lines::{extract, Eye, LineParams};
    let gpu = Gpu::new();
    let labels = vellum::volume::labels::Labels::of_volume(&balls().1, "balls").unwrap();
    let mut lines = LineExtractor::new(&gpu.ctx).unwrap();
    let mut pipelines = vellum::gpu::PipelineCache::new(&gpu.ctx);
    let eye = Eye::Direction([0.3, 0.5, 0.81]);
    let p = LineParams {
        iso: 0.5,
        suggestive: true,
        ..LineParams::default()
    };
    let cpu = |i: u16| extract(&field(&labels, i), labels.dims, [1.0; 3], eye, &p);
    let all: Vec<u16> = (1..labels.ids.len() as u16).collect();
    for indices in [all.clone(), vec![1, 3]] {
        let got = lines
            .extract_segments(
                &mut pipelines,
                &labels,
                (&indices, [1.0; 3]),
                eye,
                &p,
                1 << 20,
            )
            .unwrap();
        let want: Vec<Segment> = indices.iter().flat_map(|&i| cpu(i)).collect();
        assert!(
            indices.iter().all(|&i| !cpu(i).is_empty()),
            "every ball has lines"
        );
        assert!(
            same_segments(&got.segments, &want),
            "segments {indices:?}: {} on the GPU, {} on the CPU",
            got.segments.len(),
            want.len()
        );
    }
    // A frame: every line lies on a shown ball's boundary (within 1.5 voxels of its sphere).
    let dir = tempfile::tempdir().unwrap();
    let f = frame(&gpu, spec(dir.path(), &[5], &[2, 9]), Some("4"));
    let (segments, found) = f.segments.expect("a frame of style 4 reads its lines back");
    assert!(found > 0 && found == segments.len() as u64);
    let mut per_ball = [0usize; 3];
    for s in &segments {
        let m: [f32; 3] = std::array::from_fn(|a| 0.5 * (s.a[a] + s.b[a]) + 0.5);
        let on = BALLS.iter().position(|(_, c, r)| {
            let d = (0..3).map(|a| (m[a] - c[a]).powi(2)).sum::<f32>().sqrt();
            (d - r).abs() < 1.5
        });
        let Some(b) = on else {
            panic!("a line at {m:?} lies on no ball's boundary");
        };
        per_ball[b] += 1;
    }
    assert!(
        per_ball[0] > 0 && per_ball[1] == 0 && per_ball[2] > 0,
        "lines per ball (5 hidden): {per_ball:?}"
    );
}

#[test]
fn label_mistakes_are_one_sentence() {
    let dir = tempfile::tempdir().unwrap();
    let (intensity, labels) = balls();
    let img = dir.path().join("i.nrrd");
    let lab = dir.path().join("l.nrrd");
    vellum::volume::io::write(&img, &intensity).unwrap();
    vellum::volume::io::write(&lab, &labels).unwrap();
    let (i, l) = (img.to_str().unwrap(), lab.to_str().unwrap());
    let small = dir.path().join("small.nrrd");
    vellum::volume::io::write(
        &small,
        &Volume::new([8; 3], [1.0; 3], VoxelData::U8(vec![1; 512])).unwrap(),
    )
    .unwrap();
    let frac = dir.path().join("frac.nrrd");
    vellum::volume::io::write(
        &frac,
        &Volume::new([N; 3], [1.0; 3], VoxelData::F32(vec![0.5; N * N * N])).unwrap(),
    )
    .unwrap();
    let out = dir.path().join("o.png");
    let o = out.to_str().unwrap();
    let cases: [(Vec<&str>, &[&str]); 5] = [
        (
            vec!["--focus-labels", "5"],
            &["--focus-labels", "add --labels PATH|NAME"],
        ),
        (
            vec!["--labels", l, "--focus-labels", "4"],
            &["label 4 is not in", "it holds 0, 2, 5, 9"],
        ),
        (
            vec!["--labels", small.to_str().unwrap()],
            &["8 x 8 x 8", "48 x 48 x 48", "on the input's grid"],
        ),
        (vec!["--labels", frac.to_str().unwrap()], &["whole numbers"]),
        (
            vec!["--labels", l, "--focus-labels", "5", "--iso", "0.5"],
            &["both choose the focus level"],
        ),
    ];
    for (flags, phrases) in cases {
        let mut args = vec!["render", i, "--size", "32x32", "--out", o];
        args.extend(flags);
        common::fails_with_all(&common::vellum(&args), phrases);
        assert!(!out.exists());
    }
    let bad = common::vellum(&[
        "render",
        i,
        "--labels",
        l,
        "--label-colour",
        "5=#12345",
        "--out",
        o,
    ]);
    common::fails_with_all(&bad, &["5=#12345", "ID=#RRGGBB"]);
}

/// The ids of `colour_of` (or `extra`'s colours) that a PNG shows, by chromaticity, with the
/// pixels of each.
fn ids_shown(png: &Path, ids: &[u32], extra: &[(u32, [u8; 3])]) -> Vec<(u32, usize)> {
    let rgb = image::open(png).unwrap().to_rgb8();
    let colour = |id: u32| match extra.iter().find(|e| e.0 == id) {
        Some(e) => e.1,
        None => {
            let c = colour_of(id);
            [c[0], c[1], c[2]]
        }
    };
    let unit = |c: [f32; 3]| {
        let m = c[0].max(c[1]).max(c[2]).max(1e-6);
        c.map(|v| v / m)
    };
    let mut shown = Vec::new();
    for &id in ids {
        let want = unit(colour(id).map(|v| v as f32));
        let n = rgb
            .pixels()
            .filter(|p| p.0.iter().any(|&c| c > 60))
            .filter(|p| {
                let seen = unit(p.0.map(|v| v as f32));
                (0..3).all(|i| (seen[i] - want[i]).abs() < 0.06)
            })
            .count();
        if n >= 4 {
            shown.push((id, n));
        }
    }
    shown
}

#[test]
fn labels_written_by_python_ome_zarr_are_read_with_their_colours() {
    if !common::python_with("ome_zarr, zarr, numpy") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for version in ["0.4", "0.5"] {
        let store = dir.path().join(format!("python-{version}.zarr"));
        common::support_script(
            "write_ome_zarr_labels.py",
            &[store.as_os_str(), version.as_ref()],
        );
        // The label image of the store's `labels` group, by name: uint32 ids, one beyond 255.
        let labels = vellum::volume::labels::Labels::open(Path::new("seg"), Some(&store)).unwrap();
        assert_eq!(labels.ids, [0, 7, 300], "NGFF {version}");
        let raw = std::fs::read(format!("{}.labels.raw", store.display())).unwrap();
        let want: Vec<u32> = raw
            .chunks_exact(4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        let got: Vec<u32> = labels
            .index
            .iter()
            .map(|&i| labels.ids[i as usize])
            .collect();
        assert_eq!(got, want, "NGFF {version}: every voxel's id");
        assert_eq!(labels.colour(7), [255, 0, 0, 255], "the image-label colour");
        // Drawn: 7 in the file's red, 300 in its own colour; hidden, 7 is gone.
        let png = dir.path().join(format!("{version}.png"));
        let p = png.to_str().unwrap();
        let s = store.to_str().unwrap();
        let base = [
            "render", s, "--labels", "seg", "--size", "96x96", "--camera", "0,90", "--ortho",
            "--out", p,
        ];
        let o = common::vellum(&base);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let shown = ids_shown(&png, &[7, 300], &[(7, [255, 0, 0])]);
        assert_eq!(
            shown.iter().map(|s| s.0).collect::<Vec<_>>(),
            [7, 300],
            "NGFF {version}: {shown:?}"
        );
        let mut hide = base.to_vec();
        hide.extend(["--hide-labels", "7", "--label-colour", "300=#0000ff"]);
        let o = common::vellum(&hide);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let shown = ids_shown(&png, &[7, 300], &[(7, [255, 0, 0]), (300, [0, 0, 255])]);
        assert_eq!(
            shown.iter().map(|s| s.0).collect::<Vec<_>>(),
            [300],
            "NGFF {version}: {shown:?}"
        );
    }
}

/// `vellum ARGS`, which must succeed writing `png`: its pixels with a channel above 40.
fn lit_pixels(args: &[&str], png: &Path) -> Vec<[u8; 3]> {
    let o = common::vellum(args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rgb = image::open(png).unwrap().to_rgb8();
    rgb.pixels()
        .map(|p| p.0)
        .filter(|p| p.iter().any(|&c| c > 40))
        .collect()
}

#[test]
fn the_frog_tissue_labels_show_their_organs_in_their_colours() {
    let Some(data) = common::shared_data() else {
        return;
    };
    let frog = data.join("formats/metaimage/frogtissue.mhd");
    let labels = vellum::volume::labels::Labels::open(&frog, None).unwrap();
    assert!(labels.ids.len() > 10, "{:?}", labels.ids);
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("frog.png");
    let f = frog.to_str().unwrap();
    let scene = dir.path().join("frog.json");
    let (p, sc) = (png.to_str().unwrap(), scene.to_str().unwrap());
    let args = [
        "render", f, "--labels", f, "--size", "256x256", "--camera", "30,20",
    ];
    let o = common::vellum(&[&args[..], &["--out", p, "--save-scene", sc]].concat());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ids: Vec<u32> = labels.ids[1..].to_vec();
    let shown = ids_shown(&png, &ids, &[]);
    assert!(shown.len() >= 6, "organs in their own colours: {shown:?}");
    // Through the brick cache at level 0 (its 16 slots hold a twentieth of the volume), the same
    // picture: each brick carries its slot's segment indices. (In core a label volume keeps
    // stored gradients; the pool's are made at each sample, the same up to single pixels where a
    // gradient is nearly flat, tests/gradients.rs.)
    let paged = dir.path().join("paged.png");
    let budget = ["--gpu-budget", "3", "--lod", "finest", "--out"];
    let o = common::vellum(&[&args[..], &budget, &[paged.to_str().unwrap()]].concat());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("brick cache"), "{stderr}");
    let (a, b) = (
        image::open(&png).unwrap().to_rgb8(),
        image::open(&paged).unwrap().to_rgb8(),
    );
    let diffs: Vec<u8> = a
        .pixels()
        .zip(b.pixels())
        .flat_map(|(p, q)| (0..3).map(move |c| p.0[c].abs_diff(q.0[c])))
        .collect();
    let mean = diffs.iter().map(|&d| d as f64).sum::<f64>() / diffs.len() as f64;
    let off = diffs.iter().filter(|&&d| d > 1).count();
    println!("through the brick cache: mean {mean:.4}/255, {off} channels more than 1/255 off");
    assert!(
        mean <= 0.05 && off * 1000 <= diffs.len(),
        "through the brick cache: a mean of {mean}/255, {off} channels more than 1/255 off"
    );
    // Nearest sampling blends no labels: without the white specular highlight, at most 1 % of
    // the lit pixels (the segments' edges among them) take a colour of no label.
    let mut json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&scene).unwrap()).unwrap();
    json["lighting"]["specular"] = 0.0.into();
    std::fs::write(&scene, json.to_string()).unwrap();
    let lit = lit_pixels(&["render", "--scene", sc, "--out", p], &png);
    let unit = |c: [f32; 3]| {
        let m = c[0].max(c[1]).max(c[2]).max(1e-6);
        c.map(|v| v / m)
    };
    let colours: Vec<[f32; 3]> = ids
        .iter()
        .map(|&id| {
            unit(
                colour_of(id)[..3]
                    .try_into()
                    .map(|c: [u8; 3]| c.map(f32::from))
                    .unwrap(),
            )
        })
        .collect();
    let foreign = lit
        .iter()
        .filter(|p| {
            let seen = unit(p.map(f32::from));
            !colours
                .iter()
                .any(|c| (0..3).all(|i| (seen[i] - c[i]).abs() < 0.06))
        })
        .count();
    let share = foreign as f64 / lit.len() as f64;
    assert!(
        lit.len() > 3000 && share <= 0.01,
        "{foreign} of {} lit pixels in no label's colour",
        lit.len()
    );
}

#[test]
fn the_seg3d_skull_mask_colours_its_head_beside_the_intensities() {
    let Some(data) = common::shared_data() else {
        return;
    };
    let d = data.join("volumes/mri_head_seg3d");
    let head = d.join("mri_head_seg3d.nhdr");
    let mask = d.join("mri_head_seg3d_skull_mask.nhdr");
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("head.png");
    let (h, m, p) = (
        head.to_str().unwrap(),
        mask.to_str().unwrap(),
        png.to_str().unwrap(),
    );
    let render = |extra: &[&str]| {
        let mut args = vec![
            "render", h, "--labels", m, "--size", "160x160", "--camera", "120,10", "--out", p,
        ];
        args.extend(extra);
        let lit = lit_pixels(&args, &png);
        let grey = lit
            .iter()
            .filter(|p| p.iter().max().unwrap() - p.iter().min().unwrap() < 12)
            .count();
        (lit.len(), grey, ids_shown(&png, &[1], &[]))
    };
    // The head in its transfer function's grey, in front of the segment.
    let (lit, grey, _) = render(&[]);
    assert!(grey as f64 > 0.5 * lit as f64, "{grey} grey of {lit}");
    // What no segment holds hidden: the segment alone, all in its colour.
    let (lit, grey, shown) = render(&["--hide-labels", "0"]);
    assert!(lit > 2000 && grey < lit / 20, "{grey} grey of {lit}");
    assert!(shown[0].1 as f64 > 0.8 * lit as f64, "{shown:?} of {lit}");
}

/// The feature-map path seeded by a label volume (issue 42): `migrate --labels` moves each
/// ball to a private interval of its own, above the data and apart from the others, with most
/// of its voxels inside it; the map names each after its id in the label volume's colour, and
/// a frame classified by the map shows the three balls in those colours.
#[test]
fn each_segment_migrates_to_a_feature_of_its_own() {
    let dir = tempfile::tempdir().unwrap();
    let (intensity, labels) = balls();
    let (img, lab, out) = (
        dir.path().join("i.nrrd"),
        dir.path().join("l.nrrd"),
        dir.path().join("f.nrrd"),
    );
    vellum::volume::io::write(&img, &intensity).unwrap();
    vellum::volume::io::write(&lab, &labels).unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let o = common::vellum(&[
        "migrate",
        &s(&img),
        "--labels",
        &s(&lab),
        "--label",
        "ball",
        "--out",
        &s(&out),
        "--json",
    ]);
    let report = common::ok_json(&o);
    let segments = report["segments"].as_array().unwrap();
    let interval = |k: usize| -> [f64; 2] {
        let i = &segments[k]["feature"]["interval"];
        [i[0].as_f64().unwrap(), i[1].as_f64().unwrap()]
    };
    let ids: Vec<u64> = segments.iter().map(|s| s["id"].as_u64().unwrap()).collect();
    assert_eq!(ids, [2, 5, 9]);
    for k in 0..3 {
        assert!(interval(k)[0] > 1.0, "above the data: {:?}", interval(k));
        if k > 0 {
            assert!(
                interval(k)[0] > interval(k - 1)[1],
                "apart: {:?}",
                interval(k)
            );
        }
    }
    let feature = vellum::input::load(&s(&out), None).unwrap();
    let VoxelData::U8(l) = &labels.data else {
        unreachable!()
    };
    for (k, &(id, ..)) in BALLS.iter().enumerate() {
        let [lo, hi] = interval(k);
        let (mut n, mut inside) = (0, 0);
        for (i, _) in l.iter().enumerate().filter(|(_, &v)| v == id) {
            n += 1;
            let v = feature.data.get_f64(i);
            inside += usize::from(v >= lo && v <= hi);
        }
        assert!(
            inside as f64 >= 0.9 * n as f64,
            "ball {id}: {inside} of {n} voxels in its interval"
        );
    }
    let map = dir.path().join("f.features.json");
    let m = vellum::volume::feature::FeatureMap::load(&map).unwrap();
    let names: Vec<String> = m.features().iter().map(|(_, f)| f.label.clone()).collect();
    assert_eq!(names, ["ball 2", "ball 5", "ball 9"]);
    let png = dir.path().join("f.png");
    let r = common::vellum(&[
        "render",
        &s(&out),
        "--features",
        &s(&map),
        "--camera",
        "0,90",
        "--ortho",
        "--size",
        "96x96",
        "--out",
        &s(&png),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let rgb = image::open(&png).unwrap().to_rgb8();
    let shown: std::collections::BTreeSet<u8> = rgb
        .pixels()
        .filter_map(|p| {
            ball_of(
                [p[0], p[1], p[2]]
                    .map(|c| c as f32 / 255.0)
                    .into_iter()
                    .chain([1.0])
                    .collect::<Vec<_>>()
                    .try_into()
                    .unwrap(),
            )
        })
        .collect();
    assert_eq!(shown.into_iter().collect::<Vec<_>>(), [2, 5, 9]);
}

/// `vellum segment` on the shipped chest CT: the heart and aorta, then the bone, grown from
/// seeds; the label volume holds each region's voxels under its id (the library's region
/// growing, run here independently of the command), keeps the CT's grid and placement, and
/// `render --labels` draws it. Mistakes are one sentence and write nothing.
#[test]
fn segment_grows_a_label_volume_that_render_draws() {
    use vellum::volume::feature::{Connectivity, Roi};
    let dir = tempfile::tempdir().unwrap();
    let ct = "data/ct_chest/ct_chest.nhdr";
    let heart = "113,150,50@105:145";
    let bone = "106,134,47;50,97,16@80:255";
    let out = dir.path().join("chest_labels.nrrd");
    let o = common::vellum(&[
        "segment",
        ct,
        "--region",
        heart,
        "--region",
        bone,
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v = vellum::input::load(ct, None).unwrap();
    let labels = vellum::input::load(out.to_str().unwrap(), None).unwrap();
    assert_eq!(labels.dims, v.dims);
    assert_eq!(labels.spacing, v.spacing);
    assert_eq!(labels.geometry, v.geometry);
    assert_eq!(labels.voxel_type(), vellum::volume::VoxelType::U8);
    let grow =
        |seeds: &[[usize; 3]], w: [f64; 2]| Roi::grow(&v, seeds, w, Connectivity::Six).unwrap();
    let h = grow(&[[113, 150, 50]], [105.0, 145.0]);
    let b = grow(&[[106, 134, 47], [50, 97, 16]], [80.0, 255.0]);
    let mut counts = [0usize; 3];
    for i in 0..v.len() {
        let want = if h.contains(i) {
            1
        } else if b.contains(i) {
            2
        } else {
            0
        };
        let got = labels.data.get_f64(i) as usize;
        assert_eq!(got, want, "voxel {i}");
        counts[got] += 1;
    }
    assert!(counts[1] > 50_000 && counts[2] > counts[1], "{counts:?}");
    let png = dir.path().join("labels.png");
    let args = [
        "render",
        ct,
        "--labels",
        out.to_str().unwrap(),
        "--hide-labels",
        "0",
        "--size",
        "96x96",
        "--out",
        png.to_str().unwrap(),
    ];
    let lit = lit_pixels(&args, &png);
    assert!(lit.len() > 500, "{} lit pixels", lit.len());

    let bad = |region: &str, want: &str| {
        let path = dir.path().join("bad.nrrd");
        let o = common::vellum(&[
            "segment",
            ct,
            "--region",
            region,
            "--out",
            path.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(want), "{region}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(!path.exists(), "{region} wrote a label volume");
    };
    bad("113,150,50", "expected seeds and a window");
    bad("0,0,0@105:145", "outside the window");
    bad("113,150,500@105:145", "outside the 256x256x133 volume");
}

/// A hidden segment leaves nothing where it was (issue 42). The balls' intensity is 1 inside and
/// 0 outside, so linear filtering blends a hidden ball's voxels into the id-0 voxels around it,
/// which are drawn: before, that drew a one-voxel shell where ball 5 was. With ball 5 hidden and
/// id 0 drawn, no pixel of ball 5's disc (as the frame of the segments alone shows it) is lit,
/// and the other balls' pixels are those of the frame with nothing hidden.
#[test]
fn a_hidden_segment_leaves_no_shell() {
    let gpu = Gpu::new();
    let dir = tempfile::tempdir().unwrap();
    let alone = frame(&gpu, spec(dir.path(), &[0], &[]), None);
    let hidden = frame(&gpu, spec(dir.path(), &[5], &[]), None);
    let shown = frame(&gpu, spec(dir.path(), &[], &[]), None);
    let of = |id: u8| -> Vec<usize> {
        (0..alone.composite.len())
            .filter(|&i| ball_of(alone.composite[i]) == Some(id))
            .collect()
    };
    let five = of(5);
    assert!(five.len() > 500, "ball 5 covers {} pixels", five.len());
    let lit = five
        .iter()
        .filter(|&&i| hidden.composite[i][3] > 0.02)
        .count();
    assert_eq!(lit, 0, "{lit} of ball 5's {} pixels are lit", five.len());
    for i in of(2).into_iter().chain(of(9)) {
        let (a, b) = (hidden.composite[i], shown.composite[i]);
        assert!(
            (0..4).all(|c| (a[c] - b[c]).abs() < 1e-3),
            "pixel {i}: {a:?} with ball 5 hidden, {b:?} with nothing hidden"
        );
    }
}
