//! The session driven without a window or a device.

use super::*;

/// A session on `input` (a phantom), as the shell makes one, without a window or device.
fn session(input: &str) -> Session {
    let loaded = load(Scene::new(InputSpec::new(input)), &Budget::gpu(1 << 30)).unwrap();
    session_of(loaded, std::env::temp_dir())
}

/// The session of `loaded`, as the shell makes one, writing its files in `dir`.
fn session_of(loaded: Loaded, dir: std::path::PathBuf) -> Session {
    let dims = loaded.volume.dims;
    Session::new(
        loaded,
        None,
        dims,
        SessionSetup {
            device: None,
            device_name: "no device".into(),
            screenshot_dir: dir,
            bench: None,
            budget: Budget::gpu(1 << 30),
            play: false,
            step: crate::timeline::STEP,
        },
    )
}

/// The load started last, once the worker has answered.
fn wait_for_load(s: &mut Session) -> (String, Result<Loaded>) {
    let deadline = Instant::now() + std::time::Duration::from_secs(60);
    loop {
        if let Some(done) = s.take_load() {
            return done;
        }
        assert!(Instant::now() < deadline, "the loader did not answer");
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
}

fn camera(azimuth: f32, elevation: f32, distance: f32) -> Camera {
    Camera {
        azimuth_deg: azimuth,
        elevation_deg: elevation,
        distance,
        ..Default::default()
    }
}

#[test]
fn the_first_apply_sets_focus_and_modulation_and_an_edit_is_applied_once() {
    let mut s = session("phantom:sphere:16");
    let range = s.model.range;
    let edits = s.apply(range, false);
    assert_eq!(
        edits,
        vec![
            Edit::Focus(Focus::None),
            Edit::Modulation(Default::default())
        ]
    );
    s.model.tf = TransferFunction::preset("ct-bone").unwrap();
    let edits = s.apply(range, false);
    assert!(
        edits.contains(&Edit::Transfer(s.model.tf.clone())),
        "{edits:?}"
    );
    assert!(!s.edited());
    let again = s.apply(range, false);
    assert!(
        !again.iter().any(|e| matches!(e, Edit::Transfer(_))),
        "{again:?}"
    );
}

#[test]
fn a_focus_outside_the_volume_is_refused_and_set_back() {
    let mut s = session("phantom:sphere:16");
    let range = s.model.range;
    s.model.scene.focus = Focus::Iso(range[1] + 1000.0);
    let edits = s.apply(range, false);
    assert_eq!(s.model.scene.focus, Focus::None);
    assert!(edits.contains(&Edit::Focus(Focus::None)));
    assert!(!s.model.message.is_empty());
    // A focus inside the values stands.
    let mid = 0.5 * (range[0] + range[1]);
    s.model.scene.focus = Focus::Iso(mid);
    assert!(s
        .apply(range, false)
        .contains(&Edit::Focus(Focus::Iso(mid))));
}

#[test]
fn a_new_input_is_loaded_again_and_replaces_the_volume() {
    let mut s = session("phantom:sphere:16");
    s.model.scene.input.path = "phantom:torus:24".into();
    let range = s.model.range;
    assert!(
        s.apply(range, false).is_empty(),
        "nothing to edit: it loads"
    );
    assert!(s.loading());
    let (what, got) = wait_for_load(&mut s);
    let l = got.unwrap();
    assert_eq!(what, "phantom:torus:24");
    assert_eq!(l.volume.dims, [24, 24, 24]);
    let dims = l.volume.dims;
    s.opened(l, &what, None, dims);
    assert_eq!(s.model.dims, [24, 24, 24]);
    assert_eq!(s.volume.dims, [24, 24, 24]);
    assert_eq!(s.model.message, "opened phantom:torus:24");
    assert!(!s.edited() && !s.loading());
}

#[test]
fn a_failed_load_says_why_and_keeps_the_volume() {
    let mut s = session("phantom:sphere:16");
    s.start_load_input("/nonexistent/volume.nrrd".into());
    let (what, got) = wait_for_load(&mut s);
    assert_eq!(what, "/nonexistent/volume.nrrd");
    let e = got.err().expect("a missing file is refused");
    assert!(e.to_string().contains("/nonexistent/volume.nrrd"), "{e}");
    assert_eq!(s.volume.dims, [16, 16, 16]);
}

#[test]
fn gestures_turn_pan_and_zoom_the_camera_within_bounds_and_reset_goes_home() {
    let mut s = session("phantom:sphere:16");
    let home = s.model.scene.camera.clone();
    let cam = camera(10.0, 20.0, 3.0);
    s.drag(&cam, Drag::Orbit, [10.0, 25.0], 400);
    let c = &s.model.scene.camera;
    assert_eq!(
        (c.azimuth, c.elevation, c.distance),
        (Some(6.0), Some(30.0), Some(3.0))
    );
    assert_eq!(c.view, None);
    s.drag(&cam, Drag::Orbit, [-50.0, 1000.0], 400);
    assert_eq!(s.model.scene.camera.azimuth, Some(30.0));
    assert_eq!(
        s.model.scene.camera.elevation,
        Some(90.0),
        "held at the pole"
    );
    s.drag(&cam, Drag::Pan, [40.0, 0.0], 400);
    assert!(s.model.scene.camera.pan[0] < 0.0 && s.model.scene.camera.pan[1] == 0.0);
    s.zoom(&cam, 1.0);
    assert!((s.model.scene.camera.distance.unwrap() - 2.7).abs() < 1e-5);
    s.zoom(&cam, 100.0);
    assert_eq!(
        s.model.scene.camera.distance,
        Some(1.05),
        "outside the bounding sphere"
    );
    s.reset_camera();
    assert_eq!(s.model.scene.camera, home);
}

#[test]
fn keys_quit_shoot_save_and_pick_views_and_the_panel_key_is_the_shells() {
    let mut s = session("phantom:sphere:16");
    let key = |c: &str| KeyPress::Char(c.into());
    assert!(!s.key(&key("o"), false));
    assert!(s.model.scene.camera.ortho);
    assert!(!s.key(&key("3"), false));
    assert_eq!(s.model.scene.camera.view, Some(NamedView::Left));
    assert!(!s.key(&key("s"), false));
    assert!(s.model.requests.screenshot && s.model.requests.save_scene.is_none());
    assert!(!s.key(&key("S"), true));
    assert_eq!(
        s.model.requests.save_scene,
        Some(s.model.scene_path.clone())
    );
    assert!(s.key(&key("h"), false), "the panel is the shell's");
    assert!(!s.model.requests.quit);
    s.key(&KeyPress::Escape, false);
    assert!(s.model.requests.quit);
}

#[test]
fn the_bench_orbit_steps_three_degrees_and_counts_down() {
    let mut s = session("phantom:sphere:16");
    s.bench = Some(BenchLog::new(2, false));
    s.bench_step();
    s.bench_step();
    s.bench_step();
    assert_eq!(s.model.scene.camera.azimuth, Some(9.0));
    assert_eq!(s.bench.as_ref().map(|b| b.left), Some(0));
}

#[test]
fn a_saved_scene_names_the_edited_transfer_function_beside_it() {
    let mut s = session("phantom:sphere:16");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("view.json");
    s.model.tf = TransferFunction::preset("ct-bone").unwrap();
    s.model.tf_edited = true;
    s.save_scene(&path, [300, 200]).unwrap();
    let saved = Scene::load(&path).unwrap();
    assert_eq!(saved.size, [300, 200]);
    let tf_path = path.with_extension("tf.json");
    assert_eq!(
        saved.classification,
        ClassificationSpec::Transfer(tf_path.to_string_lossy().into_owned())
    );
    assert!(tf_path.is_file());
    // A refused setting goes back to what rendered.
    s.model.scene.slices = Some(3);
    s.refused(&Error::Invalid("too few slices".into()));
    assert_eq!(s.model.scene, s.applied);
    assert_eq!(s.model.message, "too few slices");
}

/// A (t, z, y, x) Zarr v2 store of `times` time points of 12³ u8, one chunk each: time point t
/// is a ball of radius 2 + t.
fn time_series(root: &std::path::Path, times: usize) {
    let put = |p: &str, bytes: &[u8]| {
        let path = root.join(p);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, bytes).unwrap();
    };
    put(".zgroup", br#"{"zarr_format": 2}"#);
    put(
        ".zattrs",
        br#"{"multiscales": [{"version": "0.4", "axes": ["t", "z", "y", "x"],
            "datasets": [{"path": "0", "coordinateTransformations": [
                {"type": "scale", "scale": [1.0, 1.0, 1.0, 1.0]}]}]}]}"#,
    );
    let zarray = format!(
        r#"{{"zarr_format": 2, "shape": [{times}, 12, 12, 12], "chunks": [1, 12, 12, 12],
        "dtype": "|u1", "compressor": null, "fill_value": 0, "order": "C", "filters": null,
        "dimension_separator": "/"}}"#
    );
    put("0/.zarray", zarray.as_bytes());
    for t in 0..times {
        let r2 = ((2 + t) * (2 + t)) as f64;
        let voxels: Vec<u8> = (0..12 * 12 * 12)
            .map(|i: usize| {
                let d = |v: usize| v as f64 - 5.5;
                u8::from(d(i % 12).powi(2) + d((i / 12) % 12).powi(2) + d(i / 144).powi(2) <= r2)
            })
            .collect();
        put(&format!("0/{t}/0/0/0"), &voxels);
    }
}

#[test]
fn time_points_play_through_the_loader_with_the_next_one_read_ahead() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("series.ome.zarr");
    time_series(&store, 3);
    let path = store.to_str().unwrap();
    // The store has three time points: it opens only at one.
    let refused = load(Scene::new(InputSpec::new(path)), &Budget::gpu(1 << 30))
        .err()
        .unwrap();
    assert!(refused.to_string().contains("3 time points"), "{refused}");
    let mut first = Scene::new(InputSpec::new(path));
    first.input.time = Some(0);
    first.focus = Focus::Iso(0.5);
    let loaded = load(first, &Budget::gpu(1 << 30)).unwrap();
    assert_eq!(loaded.times, 3);
    let dims = loaded.volume.dims;
    let mut s = session_of(loaded, dir.path().to_path_buf());
    let voxels = |s: &Session| {
        (0..s.volume.len())
            .map(|i| s.volume.data.get_f64(i))
            .sum::<f64>()
    };
    let at_0 = voxels(&s);
    // The series is drawn on the scale of the first time point shown, kept with the edited
    // transfer function from one time point to the next.
    let scale = s.model.range;
    assert_eq!(s.model.scene.input.range, Some(scale));
    let smooth = vellum_volume::lines::auto_smooth_radius(&s.volume);
    assert_eq!(
        s.model.scene.input.line_smooth,
        Some(smooth),
        "and its line smoothing"
    );
    let edited = TransferFunction::preset("ct-bone").unwrap();
    s.model.tf = edited.clone();
    s.model.tf_edited = true;
    // The slider asks for time point 2: loaded with the scene kept (its focus).
    s.model.requests.time = Some(2);
    s.handle_requests([64, 64]);
    assert!(s.loading());
    let (what, got) = wait_for_load(&mut s);
    s.opened(got.unwrap(), &what, None, dims);
    assert_eq!((s.model.time, s.model.scene.input.time), (2, Some(2)));
    assert_eq!(s.model.scene.focus, Focus::Iso(0.5), "the scene is kept");
    assert_eq!(
        (s.model.range, &s.model.tf),
        (scale, &edited),
        "the look is kept"
    );
    // The time point was read with the kept function, which its GPU state is prepared with
    // (`prepare_gpu`): nothing is windowed on the worker, nor applied again after.
    assert_eq!(
        s.applied_tf, edited,
        "loaded with the kept transfer function"
    );
    assert!(
        !s.apply(scale, false)
            .iter()
            .any(|e| matches!(e, Edit::Transfer(_))),
        "nothing to apply again"
    );
    assert!(voxels(&s) > at_0, "the ball grew");
    // Playing: the next time point (0, wrapping) is read ahead at once, and taken over when
    // the current one has been shown for a step.
    s.model.playing = true;
    s.tick_playback(Instant::now());
    assert!(
        !s.loading() && s.prefetch.is_some(),
        "read ahead, not yet shown"
    );
    s.tick_playback(s.due_at);
    assert!(
        s.loading() && s.prefetch.is_none(),
        "the read-ahead became the load"
    );
    let (what, got) = wait_for_load(&mut s);
    assert_eq!(what, "time point 0");
    s.opened(got.unwrap(), &what, None, dims);
    assert_eq!(s.model.time, 0);
    assert_eq!(voxels(&s), at_0);
    assert!(s.playing(), "still playing");
    // The shell puts the read-ahead on the GPU as soon as it is read; its turn then swaps it in
    // without loading, and nothing is read twice.
    s.tick_playback(Instant::now());
    let deadline = Instant::now() + std::time::Duration::from_secs(60);
    let (t, got) = loop {
        if let Some(done) = s.take_prefetched() {
            break done;
        }
        assert!(Instant::now() < deadline, "the read-ahead did not answer");
        std::thread::sleep(std::time::Duration::from_millis(5));
    };
    assert!(t == 1 && got.is_ok());
    s.ready = Some(1);
    s.tick_playback(Instant::now());
    assert_eq!(
        s.prefetch.as_ref().map(|p| p.time),
        Some(2),
        "time point 1 is not read again; the one after it is"
    );
    s.tick_playback(s.due_at);
    assert!(s.swap && !s.loading(), "its turn swaps it in");
}

/// The segments panel's edits (issue 42): visibility, colour and focus of a label volume's ids
/// become one `Edit::Labels` with the new spec, applied once; another label volume loads the
/// scene again instead.
#[test]
fn a_segment_edit_is_a_new_label_table_and_another_label_volume_a_load() {
    use crate::ui::segments::{colour_in, set_colour, set_focus, set_shown};
    use vellum_render::classify::labels::LabelSpec;
    let mut s = session("phantom:sphere:16");
    let range = s.model.range;
    let spec = LabelSpec {
        path: "labels.nrrd".into(),
        ..Default::default()
    };
    s.model.scene.labels = Some(spec.clone());
    s.applied.labels = Some(spec.clone());
    assert!(!s
        .apply(range, false)
        .iter()
        .any(|e| matches!(e, Edit::Labels(_))));

    let edited = s.model.scene.labels.as_mut().unwrap();
    set_shown(edited, 7, false);
    set_shown(edited, 3, false);
    set_shown(edited, 7, true);
    set_focus(edited, 5, true);
    set_colour(edited, 5, [1, 2, 3], [9, 9, 9]);
    set_colour(edited, 3, [9, 9, 9], [9, 9, 9]);
    assert_eq!(colour_in(edited, 5, [9, 9, 9]), [1, 2, 3]);
    assert_eq!(colour_in(edited, 3, [9, 9, 9]), [9, 9, 9]);
    let want = LabelSpec {
        hide: vec![3],
        focus: vec![5],
        colours: vec![(5, [1, 2, 3])],
        ..spec.clone()
    };
    let edits = s.apply(range, false);
    assert!(edits.contains(&Edit::Labels(want)), "{edits:?}");
    assert!(!s
        .apply(range, false)
        .iter()
        .any(|e| matches!(e, Edit::Labels(_))));

    s.model.scene.labels.as_mut().unwrap().path = "other.nrrd".into();
    assert_eq!(s.apply(range, false), Vec::new());
    assert!(s.loading(), "another label volume is loaded with the scene");
}

/// The channels panel's edits (issue 42): a row starts with the function the GPU state holds;
/// hiding it makes its function transparent and a colour or window edit makes it a ramp in that
/// colour across that window, sent once as `Edit::Channels`.
#[test]
fn a_channel_edit_is_a_new_function_for_that_channel_only() {
    use crate::ui::ChannelRow;
    use vellum_render::classify::channels::{ramp, ChannelInfo};
    let mut s = session("phantom:sphere:16");
    let range = s.model.range;
    let info = |index, colour| ChannelInfo {
        index,
        name: None,
        range: [0.0, 1000.0],
        histogram: vec![1; 256],
        tf: ramp(colour, [0.25, 0.5]).unwrap(),
    };
    let rows: Vec<ChannelRow> = [info(0, [1.0, 0.0, 0.0]), info(2, [0.0, 0.0, 1.0])]
        .iter()
        .map(ChannelRow::of)
        .collect();
    assert_eq!(rows[0].window, [0.25, 0.5], "the loaded function's window");
    assert_eq!(rows[1].colour, [0.0, 0.0, 1.0]);
    assert_eq!(rows[0].tf().unwrap(), info(0, [1.0, 0.0, 0.0]).tf);
    s.model.channels = Some(rows.clone());
    s.applied_channels = Some(rows);
    let channel_edits = |s: &mut Session| -> Vec<Vec<TransferFunction>> {
        s.apply(range, false)
            .into_iter()
            .filter_map(|e| match e {
                Edit::Channels(t) => Some(t),
                _ => None,
            })
            .collect()
    };
    assert!(channel_edits(&mut s).is_empty());
    let rows = s.model.channels.as_mut().unwrap();
    rows[0].visible = false;
    rows[1].colour = [0.0, 1.0, 0.0];
    rows[1].window = [0.1, 0.2];
    rows[1].edited = true;
    let sent = channel_edits(&mut s);
    assert_eq!(sent.len(), 1);
    assert!(sent[0][0].table(256).iter().all(|t| t[3] == 0.0), "hidden");
    assert_eq!(sent[0][1], ramp([0.0, 1.0, 0.0], [0.1, 0.2]).unwrap());
    assert!(channel_edits(&mut s).is_empty(), "applied once");
}

/// A series' mixed channels keep the scales of the first time point shown: its rows' ranges
/// and loaded functions become the scene's `channels.scales` (model and applied alike, so no
/// load follows), kept once set; a store of one time point keeps none.
#[test]
fn a_series_keeps_its_first_time_points_channel_scales() {
    use crate::ui::ChannelRow;
    use vellum_render::classify::channels::{ramp, ChannelInfo, ChannelSpec};
    let mut s = session("phantom:sphere:16");
    let info = |index, top: f64| ChannelInfo {
        index,
        name: None,
        range: [0.0, top],
        histogram: vec![1; 256],
        tf: ramp([1.0, 0.0, 0.0], [0.25, 0.5]).unwrap(),
    };
    let rows = |top| -> Vec<ChannelRow> {
        [info(0, top), info(2, 2.0 * top)]
            .iter()
            .map(ChannelRow::of)
            .collect()
    };
    let spec = ChannelSpec {
        channels: vec![0, 2],
        ..Default::default()
    };
    s.model.scene.channels = Some(spec.clone());
    s.applied.channels = Some(spec);
    s.model.channels = Some(rows(100.0));
    s.fix_channel_scales();
    assert!(
        s.model.scene.channels.as_ref().unwrap().scales.is_empty(),
        "one time point keeps no scales"
    );
    s.model.times = 3;
    s.fix_channel_scales();
    let scales = s.model.scene.channels.as_ref().unwrap().scales.clone();
    let got: Vec<(usize, [f64; 2])> = scales.iter().map(|c| (c.channel, c.range)).collect();
    assert_eq!(got, vec![(0, [0.0, 100.0]), (2, [0.0, 200.0])]);
    assert_eq!(scales[1].tf, info(2, 1.0).tf);
    assert_eq!(
        s.applied.channels, s.model.scene.channels,
        "no load follows"
    );
    // A later time point's rows (their own ranges) leave the scales as they were.
    s.model.channels = Some(rows(300.0));
    s.fix_channel_scales();
    assert_eq!(s.model.scene.channels.as_ref().unwrap().scales, scales);
}
