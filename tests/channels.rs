//! Several channels of a store mixed in one ray (issue 42), on a two-channel store written by
//! Python's ome-zarr package with NGFF omero colours (red, blue) and windows: along x, a third
//! holds channel 0 only, a third both, a third channel 1 only. Seen along z, `add` and `max` must
//! show red, magenta and blue in those thirds, whatever the channels' order; `over` puts the
//! first listed on top; and one visible channel under `over` draws what the single-channel
//! renderer draws.

mod common;

use std::path::{Path, PathBuf};

/// The store, written by tests/support/write_ome_zarr_channels.py (NGFF `version`).
fn store(dir: &Path, version: &str) -> Option<PathBuf> {
    written(dir, &format!("channels-{version}.zarr"), &[version])
}

/// The store `name` in `dir` as tests/support/write_ome_zarr_channels.py writes it with `args`,
/// or None where Python lacks its packages (outside CI).
fn written(dir: &Path, name: &str, args: &[&str]) -> Option<PathBuf> {
    if !common::python_with("ome_zarr, zarr, numpy") {
        return None;
    }
    let store = dir.join(name);
    let mut all = vec![store.as_os_str()];
    all.extend(args.iter().map(std::ffi::OsStr::new));
    common::support_script("write_ome_zarr_channels.py", &all);
    Some(store)
}

/// The eight-channel store: channel k lights only the band 4k <= x < 4k + 4, in the colour
/// `EIGHT[k]`.
fn eight_channel_store(dir: &Path) -> Option<PathBuf> {
    written(dir, "eight.zarr", &["0.5", "8"])
}

/// The omero colours of the eight-channel store's channels.
const EIGHT: [[u8; 3]; 8] = [
    [255, 0, 0],
    [0, 255, 0],
    [0, 0, 255],
    [255, 255, 0],
    [255, 0, 255],
    [0, 255, 255],
    [255, 255, 255],
    [255, 128, 0],
];

/// `vellum render STORE` seen along z, 96², with `flags`: the RGB pixels.
fn render(store: &Path, flags: &[&str]) -> Vec<[u8; 3]> {
    let png = store.with_extension(format!("{}.png", flags.join("_").replace(['/', '='], "-")));
    let mut args = vec![
        "render",
        store.to_str().unwrap(),
        "--camera",
        "0,90",
        "--ortho",
    ];
    args.extend(["--size", "96x96", "--out", png.to_str().unwrap()]);
    args.extend(flags);
    let o = common::vellum(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    rgb(&png)
}

/// The RGB pixels of the PNG `png`.
fn rgb(png: &Path) -> Vec<[u8; 3]> {
    image::open(png)
        .unwrap()
        .to_rgb8()
        .pixels()
        .map(|p| p.0)
        .collect()
}

/// Pixels within 2/255 of each of `colours`, and the pixels with any light.
fn counts(pixels: &[[u8; 3]], colours: &[[u8; 3]]) -> (Vec<usize>, usize) {
    let near = |p: &[u8; 3], c: &[u8; 3]| (0..3).all(|i| (p[i] as i32 - c[i] as i32).abs() <= 2);
    let each = colours
        .iter()
        .map(|c| pixels.iter().filter(|p| near(p, c)).count())
        .collect();
    (
        each,
        pixels.iter().filter(|p| p.iter().any(|&v| v > 8)).count(),
    )
}

fn max_difference(a: &[[u8; 3]], b: &[[u8; 3]]) -> u8 {
    a.iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |i| p[i].abs_diff(q[i])))
        .max()
        .unwrap_or(0)
}

#[test]
fn add_and_max_show_each_channel_in_its_omero_colour_in_any_order() {
    let dir = tempfile::tempdir().unwrap();
    for version in ["0.4", "0.5"] {
        let Some(store) = store(dir.path(), version) else {
            return;
        };
        let (red, magenta, blue) = ([255, 0, 0], [255, 0, 255], [0, 0, 255]);
        for mix in ["add", "max"] {
            let ab = render(&store, &["--channels", "0,1", "--mix", mix]);
            let ba = render(&store, &["--channels", "1,0", "--mix", mix]);
            assert!(
                max_difference(&ab, &ba) <= 1,
                "{mix}: swapping the channels changed a pixel"
            );
            // The thirds are 11, 11 and 10 voxels wide: channel 0 alone, both, channel 1 alone.
            let (each, lit) = counts(&ab, &[red, magenta, blue]);
            let total: usize = each.iter().sum();
            assert!(
                total as f64 >= 0.95 * lit as f64,
                "{mix} {version}: {each:?} of {lit}"
            );
            for (k, want) in [11.0 / 32.0, 11.0 / 32.0, 10.0 / 32.0]
                .into_iter()
                .enumerate()
            {
                let got = each[k] as f64 / total as f64;
                assert!(
                    (got - want).abs() < 0.03,
                    "{mix} {version}: third {k} {got:.3}, want {want:.3}"
                );
            }
        }
    }
}

#[test]
fn over_puts_the_first_channel_on_top_and_one_channel_draws_as_alone() {
    let dir = tempfile::tempdir().unwrap();
    let Some(store) = store(dir.path(), "0.5") else {
        return;
    };
    // The middle third holds both: red over blue, or blue over red.
    let hue = |px: &[[u8; 3]]| {
        let mid = px[48 * 96 + 48];
        mid[0] as i32 - mid[2] as i32
    };
    assert!(hue(&render(&store, &["--channels", "0,1"])) > 60);
    assert!(hue(&render(&store, &["--channels", "1,0"])) < -60);
    // Channel 1 transparent: channel 0 under the grey preset, as the one-channel renderer draws
    // channel 0 with --tf grey.
    let clear = dir.path().join("clear.json");
    std::fs::write(
        &clear,
        r#"{"points": [{"x": 0, "rgba": [0, 0, 0, 0]}, {"x": 1, "rgba": [0, 0, 0, 0]}]}"#,
    )
    .unwrap();
    let tf1 = format!("1={}", clear.display());
    let mixed = render(
        &store,
        &[
            "--channels",
            "0,1",
            "--channel-tf",
            "0=grey",
            "--channel-tf",
            &tf1,
        ],
    );
    let alone = render(
        &store,
        &[
            "--channels",
            "0",
            "--tf",
            "grey",
            "--renderer",
            "raycast",
            "--no-skip-empty",
        ],
    );
    let d = max_difference(&mixed, &alone);
    assert!(
        d <= 1,
        "one visible channel differs from the channel alone by {d}/255"
    );
    assert!(alone.iter().any(|p| p[0] > 100));
}

/// Five to eight channels take a second texture, and each texture holds one, two or four
/// components: each of the eight bands along x must show its own channel's colour (channels 4-7
/// from the second texture), whatever the channels' order; with the first 3 or 6 channels only
/// (a padded texture, a two-component second one), the other bands stay dark.
#[test]
fn eight_channels_mix_in_one_ray_each_in_its_own_colour() {
    let dir = tempfile::tempdir().unwrap();
    let Some(store) = eight_channel_store(dir.path()) else {
        return;
    };
    let mut seen = None;
    for mix in ["add", "max"] {
        let all = render(&store, &["--channels", "0,1,2,3,4,5,6,7", "--mix", mix]);
        let back = render(&store, &["--channels", "7,6,5,4,3,2,1,0", "--mix", mix]);
        assert!(
            max_difference(&all, &back) <= 1,
            "{mix}: reversing the channels changed a pixel"
        );
        // The middle row crosses the bands; the centre of each eighth of its lit span shows one
        // channel (the image may run along x either way).
        let row = &all[48 * 96..49 * 96];
        let lit: Vec<usize> = (0..96).filter(|&x| row[x].iter().any(|&v| v > 8)).collect();
        let (x0, span) = (lit[0], lit[lit.len() - 1] + 1 - lit[0]);
        assert!(span > 64, "{mix}: the volume spans {span} of 96 columns");
        let columns: Vec<usize> = (0..8).map(|k| x0 + (2 * k + 1) * span / 16).collect();
        let centres: Vec<[u8; 3]> = columns.iter().map(|&x| row[x]).collect();
        let matches = |order: &[[u8; 3]]| {
            centres
                .iter()
                .zip(order)
                .all(|(p, c)| (0..3).all(|i| p[i].abs_diff(c[i]) <= 2))
        };
        let mut reversed = EIGHT;
        reversed.reverse();
        assert!(
            matches(&EIGHT) || matches(&reversed),
            "{mix}: the bands show {centres:?}, want {EIGHT:?} either way"
        );
        // Channel k's band, in image order.
        let forward = matches(&EIGHT);
        seen = Some(move |k: usize| columns[if forward { k } else { 7 - k }]);
    }
    let band = seen.unwrap();
    for count in [3usize, 6] {
        let list: Vec<String> = (0..count).map(|k| k.to_string()).collect();
        let some = render(&store, &["--channels", &list.join(","), "--mix", "add"]);
        for (k, want) in EIGHT.iter().enumerate() {
            let p = some[48 * 96 + band(k)];
            let ok = match k < count {
                true => (0..3).all(|i| p[i].abs_diff(want[i]) <= 2),
                false => p.iter().all(|&v| v <= 8),
            };
            assert!(ok, "{count} channels: band {k} shows {p:?}");
        }
    }
}

#[test]
fn channel_mistakes_are_one_sentence() {
    let dir = tempfile::tempdir().unwrap();
    let Some(store) = store(dir.path(), "0.5") else {
        return;
    };
    let s = store.to_str().unwrap();
    let out = dir.path().join("o.png");
    let o = out.to_str().unwrap();
    let cases: [(Vec<&str>, &[&str]); 7] = [
        (
            vec![s, "--channels", "0", "--mix", "add"],
            &["--mix", "add --channels 0,1"],
        ),
        (
            vec![s, "--channels", "0,1,0,1,0,1,0,1,0"],
            &["9 channels", "at most 8"],
        ),
        (
            vec![s, "--channels", "0,1", "--focus-channel", "3"],
            &["--focus-channel 3", "not among"],
        ),
        (
            vec![s, "--channels", "0,1", "--mix", "max", "--iso", "300"],
            &["--mix max", "one level"],
        ),
        (
            vec![s, "--channels", "0,1", "--mix", "screen"],
            &["screen", "over, add or max"],
        ),
        (
            vec![s, "--channels", "0,1", "--channel-tf", "1"],
            &["C=PRESET|FILE"],
        ),
        (vec![s, "--channels", "0,5"], &["channel"]),
    ];
    for (flags, phrases) in cases {
        let mut args = vec!["render"];
        args.extend(flags);
        args.extend(["--size", "32x32", "--out", o]);
        common::fails_with_all(&common::vellum(&args), phrases);
        assert!(!out.exists());
    }
}

/// A channel's function set once the channels are on the GPU (the viewer's channel list does
/// so): the next frame draws with it. Under `add`, channel 0 made transparent leaves no red and
/// the blue third as it was.
#[test]
fn a_function_set_later_draws_in_the_next_frame() {
    use vellum::render::overrides::{CameraAngles, SceneOverrides};
    use vellum::render::scene::{InputSpec, Scene};
    use vellum::render::session::{Session, SessionOptions};
    let dir = tempfile::tempdir().unwrap();
    let Some(store) = store(dir.path(), "0.4") else {
        return;
    };
    let gpu = common::Gpu::new();
    let overrides = SceneOverrides {
        channels: Some(vec![0, 1]),
        mix: Some("add".into()),
        camera: Some(CameraAngles {
            azimuth: 0.0,
            elevation: 90.0,
            distance: None,
        }),
        ortho: true,
        size: Some([96, 96]),
        ..Default::default()
    };
    let path = store.to_string_lossy().into_owned();
    let scene = overrides.apply(Scene::new(InputSpec::new(path))).unwrap();
    let mut session = Session::open(&gpu.ctx, &scene, None, &SessionOptions::default()).unwrap();
    let (view, _) = session.view(scene.view(false).unwrap());
    let frame = |s: &mut Session| -> Vec<[u8; 3]> {
        let opts = vellum::render::bricked::StillOptions {
            max_wait: None,
            ..Default::default()
        };
        let f = s.still(&view, opts).unwrap().0;
        vellum::render::targets::to_rgb8(&f.composite, [0.0; 3])
            .chunks_exact(3)
            .map(|p| [p[0], p[1], p[2]])
            .collect()
    };
    let (red, blue) = ([255, 0, 0], [0, 0, 255]);
    let before = counts(&frame(&mut session), &[red, blue]).0;
    let channels = session.prepared.classify().channels.as_mut().unwrap();
    let clear = |x| vellum::classify::transfer::ControlPoint {
        x,
        rgba: [1.0, 0.0, 0.0, 0.0],
    };
    let hidden =
        vellum::classify::transfer::TransferFunction::new("h", vec![clear(0.0), clear(1.0)])
            .unwrap();
    let blue_tf = channels.info[1].tf.clone();
    channels.set_tfs(&[hidden, blue_tf]).unwrap();
    let after = counts(&frame(&mut session), &[red, blue]).0;
    assert!(
        before[0] > 500 && after[0] == 0,
        "red {} then {}",
        before[0],
        after[0]
    );
    assert!(
        after[1] >= before[1],
        "blue {} then {}",
        before[1],
        after[1]
    );
}

/// Channels through the brick cache (issue 42): the shipped chest CT and five volumes made from
/// it (each the CT within its own band along x, so that every channel differs), written as one
/// six-channel store by `convert --add-channel`, mixed by `over`, `add` and `max` through a pool
/// of 40 MiB at level 0 (a third of the textures in core, so that bricks wait, arrive and are
/// evicted over many passes): each frame is the frame in core within a mean of 0.5/255 and
/// 3/255 at any pixel. Two channels use the first pool only, six both.
#[test]
fn channels_through_the_brick_cache_draw_what_the_channels_in_core_draw() {
    use vellum::volume::{Volume, VoxelData};
    let dir = tempfile::tempdir().unwrap();
    let ct_path = "data/ct_chest/ct_chest.nhdr";
    let ct = vellum::input::load(ct_path, None).unwrap();
    let mut args = vec![
        "convert".to_string(),
        ct_path.to_string(),
        dir.path().join("six.ome.zarr").display().to_string(),
    ];
    for k in 1..6usize {
        let band: Vec<u8> = (0..ct.len())
            .map(|i| {
                let x = i % ct.dims[0];
                let inside = (40 * (k - 1)..40 * k + 40).contains(&x);
                if inside {
                    ct.data.get_f64(i) as u8
                } else {
                    0
                }
            })
            .collect();
        let v = Volume::new(ct.dims, ct.spacing, VoxelData::U8(band))
            .unwrap()
            .with_geometry(ct.geometry)
            .unwrap();
        let path = dir.path().join(format!("band{k}.nrrd"));
        vellum::volume::io::write(&path, &v).unwrap();
        args.extend(["--add-channel".to_string(), path.display().to_string()]);
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = common::vellum(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let store = dir.path().join("six.ome.zarr");
    // Through the brick cache, the channels share the chunks' memory, each its part.
    let mut scene = vellum::render::scene::Scene::new(vellum::render::scene::InputSpec::new(
        store.to_str().unwrap(),
    ));
    scene.input.channel = Some(0);
    scene.channels = Some(vellum::classify::channels::ChannelSpec {
        channels: vec![0, 1, 2],
        ..Default::default()
    });
    let opened = vellum::render::session::Opened::open(&scene, None, 1 << 20, Some(30 << 20));
    match opened.unwrap() {
        vellum::render::session::Opened::Bricked(levels) => {
            assert_eq!(levels.chunks().budget(), 10 << 20, "a third each");
            assert_eq!(levels.mixed_count(), 3);
        }
        _ => panic!("a store beyond 1 MiB opens bricked"),
    }
    let frame = |channels: &str, mix: &str, budget: &str| -> Vec<[u8; 3]> {
        let png = dir.path().join(format!("{channels}-{mix}-{budget}.png"));
        let o = common::vellum(&[
            "render",
            store.to_str().unwrap(),
            "--channels",
            channels,
            "--mix",
            mix,
            "--gpu-budget",
            budget,
            "--lod",
            "finest",
            "--size",
            "128x128",
            "--out",
            png.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{err}");
        let paged = err.contains("larger than the GPU budget");
        assert_eq!(paged, budget != "4000", "{budget} MiB: {err}");
        rgb(&png)
    };
    for channels in ["0,1", "0,1,2,3,4,5"] {
        for mix in ["over", "add", "max"] {
            let core = frame(channels, mix, "4000");
            let paged = frame(channels, mix, "40");
            let diffs: Vec<u8> = core
                .iter()
                .zip(&paged)
                .flat_map(|(p, q)| (0..3).map(move |i| p[i].abs_diff(q[i])))
                .collect();
            let mean = diffs.iter().map(|&d| d as f64).sum::<f64>() / diffs.len() as f64;
            let lit = core.iter().filter(|p| p.iter().any(|&v| v > 8)).count();
            assert!(lit > 2000, "{channels} {mix}: {lit} lit pixels in core");
            // (In core the channels keep stored gradients; the pool's are made at each sample:
            // single pixels differ where a gradient is nearly flat, tests/gradients.rs.)
            assert!(
                mean <= 0.5 && max_difference(&core, &paged) <= 64,
                "{channels} {mix}: through the cache differs from in core by a mean of {mean:.3}/255, {} at most",
                max_difference(&core, &paged)
            );
        }
    }
}
